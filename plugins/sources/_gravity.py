"""Find the floor and the up axis of an input, and the transform that makes it z-up with the floor at z = 0.

Stages assume a gravity-aligned world. Sources call :func:`align_stream` on load: it samples
points from a few frames (or the static cloud), finds planes by iterative RANSAC (inliers
removed after each plane), keeps large planes roughly perpendicular
to an *up hint* (for cameras: the mean of their -y optical axes, since handheld and robot
cameras are held roughly level), takes the lowest of them as the floor, refines it by least
squares on its inliers, and rotates its normal onto +z with the floor at z = 0. RANSAC is seeded
numpy (:func:`stratamap.core.geometry.boxes.ransac_plane`), so alignment is the same on every run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.geometry.points import far_from_bulk, ransac_plane
from stratamap.core.geometry.transforms import apply
from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import SensorStream

o3d = lazy_module("open3d")


@dataclass
class GravityAlignment:
    transform: np.ndarray  # old world -> new (z-up, floor at 0) world
    realigned: bool
    rotation_deg: float
    floor_offset_m: float
    floor_inliers: int = 0
    details: dict[str, Any] = field(default_factory=dict)

    def report(self) -> dict[str, Any]:
        return {
            "realigned": self.realigned,
            "rotation_deg": round(self.rotation_deg, 3),
            "floor_offset_m": round(self.floor_offset_m, 4),
            "floor_inliers": self.floor_inliers,
            "transform": np.round(self.transform, 9).tolist(),
            **self.details,
        }


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1 / (1 + c))


def sample_points(stream: SensorStream, max_frames: int = 8, stride: int = 4) -> np.ndarray:
    if stream.points is not None and len(stream.points):
        return np.asarray(stream.points)
    if stream.intrinsics is None or len(stream.frames) == 0:
        return np.zeros((0, 3))
    picks = np.unique(np.linspace(0, len(stream.frames) - 1, min(max_frames, len(stream.frames))).astype(int))
    pts = []
    for k in picks:
        f = stream.frames[int(k)]
        if f.pose is None:
            continue
        cam, _ = stream.intrinsics.backproject(np.where(f.depth < 6.0, f.depth, 0), stride=stride)
        pts.append(apply(f.pose, cam))
    return np.vstack(pts) if pts else np.zeros((0, 3))


def sensor_positions(stream: SensorStream) -> np.ndarray:
    """Where the sensor stood: the cameras of posed frames, a scanner file's positions (E57's scan
    poses, ``metadata['sensor_positions']``), else the origin of a static cloud (a scanner's or
    camera's own frame; a map frame's origin usually lies on its floor), unless the cloud says its
    origin is none (``metadata['sensor_origin']`` False: a mesh's surface samples, a LAS file)."""
    posed = [f.pose[:3, 3] for f in _some_frames(stream) if f.pose is not None]
    if posed:
        return np.asarray(posed)
    if stream.metadata.get("sensor_positions"):  # a scanner file's own (E57), in the stream's frame
        return np.asarray(stream.metadata["sensor_positions"], float).reshape(-1, 3)
    if not stream.metadata.get("sensor_origin", True):
        return np.zeros((0, 3))
    return np.zeros((1, 3))


def camera_up_hint(stream: SensorStream, axis: tuple[float, float, float] = (0.0, -1.0, 0.0)) -> np.ndarray | None:
    """The cameras' mean ``axis`` (camera frame: x right, y down) in the world: up when the camera is
    held level (image up, -y, by default); None without poses."""
    ups = [f.pose[:3, :3] @ np.asarray(axis) for f in _some_frames(stream) if f.pose is not None]
    if not ups:
        return None
    up = np.mean(ups, axis=0)
    return up / np.linalg.norm(up)


def _some_frames(stream: SensorStream, n: int = 16):
    if len(stream.frames) == 0:
        return []
    picks = np.unique(np.linspace(0, len(stream.frames) - 1, min(n, len(stream.frames))).astype(int))
    return [stream.frames[int(k)] for k in picks]


#: Open3D indexes voxels by 32-bit integers ("voxel_size is too small" past them); far fewer are
#: anything a floor search needs (a 30 km bulk in 3 cm voxels).
MAX_VOXELS_PER_AXIS = 1e6
#: Planes within this angle (degrees) are parallel (a floor and a table top); walls are this close to
#: perpendicular to up.
PARALLEL_DEG = 10.0
#: A plane the sensor was more than this (m) under is no floor (a map whose origin lies on its floor
#: is within it).
SENSOR_BELOW = 0.1


@dataclass
class ScenePlanes:
    """The planes iterative RANSAC finds in a cloud's voxel sample, which do not depend on any up
    hint (so several hints can be tried on one search): the sample, in a fixed order, and each
    plane's unit normal, offset (n.x + d = 0) and inlier indices, in the order found."""

    sampled: np.ndarray
    planes: list[tuple[np.ndarray, float, np.ndarray]]


def find_planes(
    points: np.ndarray,
    voxel: float = 0.03,
    distance: float = 0.02,
    max_planes: int = 8,
    min_share: float = 0.03,
    seed: int = 0,
) -> ScenePlanes:
    """Up to ``max_planes`` planes, one after another (seeded RANSAC, inliers removed after each), in
    the ``voxel`` sample of ``points``; none when the sample has fewer than 100 points. Points far from
    the rest (:func:`far_from_bulk`) are left out: one stray return would stretch the voxel grid past
    what Open3D can index. A bulk that still spans more than ``MAX_VOXELS_PER_AXIS`` voxels is a DataError."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[~far_from_bulk(points)]
    if len(points):
        span = float(np.max(points.max(0) - points.min(0)))
        if span / voxel > MAX_VOXELS_PER_AXIS:
            raise DataError(
                f"its points span {span:.3g} m without their strays, more than {MAX_VOXELS_PER_AXIS:.0e} of the "
                f"floor search's {voxel:g} m voxels along one axis"
            )
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    sampled = np.asarray(pcd.voxel_down_sample(voxel).points)
    sampled = sampled[np.lexsort(sampled.T[::-1])]  # a fixed order, whatever the downsampler's
    total = len(sampled)
    planes: list[tuple[np.ndarray, float, np.ndarray]] = []
    if total < 100:
        return ScenePlanes(sampled, planes)
    rest = np.arange(total)  # indices of the points no plane has taken yet
    for k in range(max_planes):
        if len(rest) < max(50, min_share * total):
            break
        n, d, inliers = ransac_plane(sampled[rest], distance, iterations=400, seed=seed + k)
        planes.append((n, d, rest[inliers]))
        rest = np.delete(rest, inliers)
    return ScenePlanes(sampled, planes)


def find_floor(
    points: np.ndarray | None,
    up_hint: np.ndarray,
    max_angle_deg: float = 35.0,
    min_share: float = 0.03,
    viewpoints: np.ndarray | None = None,
    planes: ScenePlanes | None = None,
) -> tuple[np.ndarray, float, int] | None:
    """(unit normal pointing up, offset d with n.x + d = 0, inlier count) of the floor, or None.

    The planes of ``points`` (:func:`find_planes`, or ``planes`` already found) within
    ``max_angle_deg`` of ``up_hint`` are candidates, less those the sensor (``viewpoints``: where it
    stood) was under: a floor or a table is seen from above, and a wall the hint's tolerance admits
    (a steep view of a tabletop) is not. Up is the normal that the most candidate points agree on (a
    floor, a table top and a seat are parallel; a slanted patch is not), and the floor is the lowest
    candidate parallel to it with (almost) nothing below it but the walls (a wall reaches below a
    table top whose floor the scan never saw: a tabletop scan's floor is its table)."""
    found = planes if planes is not None else find_planes(points, min_share=min_share)
    sampled = found.sampled
    total = len(sampled)
    if total < 100:
        return None
    planes_up = [(n, d, idx) if np.dot(n, up_hint) >= 0 else (-n, -d, idx) for n, d, idx in found.planes]
    max_cos = np.cos(np.radians(max_angle_deg))
    candidates = [
        (n, d, idx) for n, d, idx in planes_up if len(idx) >= min_share * total and np.dot(n, up_hint) >= max_cos
    ]
    if viewpoints is not None and len(viewpoints):
        seen_from_above = [
            c for c in candidates if float(np.mean(np.asarray(viewpoints) @ c[0] + c[1])) > -SENSOR_BELOW
        ]
        candidates = seen_from_above or candidates  # a cloud whose origin is no sensor position: no say
    if not candidates:
        return None
    parallel = np.cos(np.radians(PARALLEL_DEG))
    # Up: the candidate normal with the most candidate points parallel to it.
    agreement = [sum(len(idx) for m, _, idx in candidates if np.dot(n, m) >= parallel) for n, _, _ in candidates]
    up = candidates[int(np.argmax(agreement))][0]
    on_wall = np.zeros(total, bool)
    for n, _, idx in planes_up:
        if abs(np.dot(n, up)) <= np.sin(np.radians(PARALLEL_DEG)):
            on_wall[idx] = True
    others = sampled[~on_wall]
    best = None
    for n, d, idx in candidates:
        if np.dot(n, up) < parallel:
            continue
        height = float(-d)
        below = float(np.sum(others @ n + d < -0.05)) / total
        if below > 0.1:
            continue
        if best is None or height < best[0]:
            best = (height, n, sampled[idx])
    if best is None:
        return None
    _, n, pts = best
    # Least-squares refinement on the inliers.
    centroid = pts.mean(0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    normal = vt[2] if np.dot(vt[2], n) > 0 else -vt[2]
    return normal, float(-np.dot(normal, centroid)), len(pts)


def _where(stream: SensorStream) -> str:
    """What an error names: the file or folder the stream was read from, else its name."""
    return str(stream.metadata.get("path") or stream.name)


def stream_planes(stream: SensorStream) -> ScenePlanes:
    """The planes of a stream's sampled points (:func:`find_planes`), to try up hints on."""
    pts = sample_points(stream)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < 100:
        raise DataError(f"{_where(stream)}: too few valid points to find the floor ({len(pts)})")
    try:
        return find_planes(pts)
    except DataError as err:
        raise DataError(f"{_where(stream)}: {err}") from None


def estimate_alignment(
    stream: SensorStream,
    up_hint: np.ndarray | None = None,
    max_angle_deg: float = 35.0,
    advice: str = "if the input is already z-up set `gravity: off`",
    planes: ScenePlanes | None = None,
) -> GravityAlignment:
    """The transform that levels the stream on its floor; ``planes``: the stream's planes, when
    several hints are tried on one search (:func:`stream_planes`)."""
    planes = planes if planes is not None else stream_planes(stream)
    hint = up_hint if up_hint is not None else camera_up_hint(stream)
    if hint is None:
        hint = np.array([0.0, 0.0, 1.0])
    floor = find_floor(None, hint, max_angle_deg=max_angle_deg, viewpoints=sensor_positions(stream), planes=planes)
    if floor is None:
        raise DataError(
            f"{_where(stream)}: no floor plane found (no large plane within {max_angle_deg:g} deg of the up hint "
            f"{np.round(hint, 2).tolist()}); {advice}"
        )
    normal, d, inliers = floor
    rot = rotation_between(normal, np.array([0.0, 0.0, 1.0]))
    transform = np.eye(4)
    transform[:3, :3] = rot
    transform[2, 3] = d  # after rotation the floor is z = -d
    angle = float(np.degrees(np.arccos(np.clip(normal[2], -1, 1))))
    realigned = angle > 0.5 or abs(d) > 0.005
    if not realigned:
        transform = np.eye(4)
    return GravityAlignment(
        transform,
        realigned,
        angle,
        float(-d),
        inliers,
        {"up_hint": np.round(hint, 4).tolist(), "floor_normal_input": np.round(normal, 6).tolist()},
    )


def transform_stream(stream: SensorStream, transform: np.ndarray) -> None:
    """Apply a world transform to every pose (and static points) of a stream, in place."""
    for scan in [*stream.laser_scans, *stream.lidar_scans]:
        if scan.pose is not None:
            scan.pose = transform @ scan.pose
    if stream.points is not None:
        stream.points = apply(transform, np.asarray(stream.points))
    if stream.metadata.get("sensor_positions"):
        stream.metadata["sensor_positions"] = apply(transform, np.asarray(stream.metadata["sensor_positions"])).tolist()
    stream.metadata["world_transform"] = (
        transform @ np.asarray(stream.metadata.get("world_transform", np.eye(4)))
    ).tolist()
