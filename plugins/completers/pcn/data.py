"""The ``pcn`` completer's object frame and its training data (numpy and Open3D only, no torch).

The network sees an object in its *gravity-aligned frame*: the observed points minus the object's
base (its box's footprint centre at its support height), rotated by minus the box's yaw, divided
by the observed box's largest extent. Training examples are made exactly as the pipeline makes an
instance: partial views ray-cast from sampled viewpoints with the scenes' Kinect noise
(:func:`stratamap.core.synthetic.render.apply_kinect_noise`), self-occlusion, segmentation spill
onto the floor around the object, the same box fit and the same frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.geometry.transforms import invert, look_at, make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.synthetic.render import RenderedView, apply_kinect_noise

spatial = lazy_module("scipy.spatial")
o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")
trimesh = lazy_module("trimesh")

#: The one-hot slots of the network, in order. ``other`` is the class-agnostic slot.
CLASSES: tuple[str, ...] = ("chair", "table", "desk", "cabinet", "shelf", "sofa", "bench", "counter", "other")
INPUT_POINTS = 512
COARSE_POINTS = 512
FOLD_GRID = 2  # each coarse point unfolds into FOLD_GRID^2 dense points
DENSE_POINTS = COARSE_POINTS * FOLD_GRID**2
#: Observed points are thinned to one per voxel of this size (the TSDF maps' 2 cm voxels, halved).
THIN_VOXEL = 0.01
MIN_EXTENT = 0.05
SPILL_DISTANCE = 0.06


@dataclass(frozen=True)
class ObjectFrame:
    """Where an object's normalized frame sits in the world: ``world = base + R(yaw) (scale * local)``."""

    base: np.ndarray
    yaw: float
    scale: float

    def to_local(self, points: np.ndarray) -> np.ndarray:
        q = np.asarray(points, dtype=np.float64) - self.base
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        xy = q[:, :2] @ np.array([[c, -s], [s, c]])  # rotate by -yaw
        return np.c_[xy, q[:, 2]] / self.scale

    def pose(self) -> np.ndarray:
        """Object frame (metres, unrotated) into the world."""
        return make_pose(self.base, self.yaw)


def frame_for(base: np.ndarray, yaw: float, size: np.ndarray) -> ObjectFrame:
    """The frame of an object standing at ``base`` whose observed box has ``yaw`` and ``size``."""
    return ObjectFrame(np.asarray(base, dtype=np.float64), float(yaw), float(max(np.max(size), MIN_EXTENT)))


def fixed_count(points: np.ndarray, count: int) -> np.ndarray:
    """Exactly ``count`` points, evenly spaced through the array (repeating when there are fewer)."""
    idx = np.linspace(0, len(points) - 1, count).round().astype(int) if len(points) >= count else None
    if idx is None:
        idx = np.arange(count) % len(points)
    return points[idx]


def class_onehot(class_name: str) -> np.ndarray:
    onehot = np.zeros(len(CLASSES), dtype=np.float32)
    onehot[CLASSES.index(class_name if class_name in CLASSES else "other")] = 1.0
    return onehot


# ------------------------------------------------------------------------------------------ training views

INTRINSICS = CameraIntrinsics(160, 120, 145.0, 145.0, 79.5, 59.5)  # a Kinect's 58 deg field of view


@dataclass
class Example:
    points: np.ndarray  # (INPUT_POINTS, 3) float32, normalized frame
    truth: np.ndarray  # (DENSE_POINTS, 3) float32, normalized frame
    onehot: np.ndarray  # (len(CLASSES),) float32
    scale: float
    visibility: float  # observed share of the true surface (points within 2 cm)


def render_partial(
    mesh: trimesh.Trimesh,
    rng: np.random.Generator,
    views: int,
    spill_pixels: int = 2,
    spill_probability: float = 0.5,
) -> np.ndarray:
    """World points of ``mesh`` (standing on the floor at z = 0) seen from ``views`` sampled
    viewpoints through a Kinect-like sensor, with segmentation spill onto the floor around it."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3c.Tensor(np.asarray(mesh.vertices, np.float32)), o3c.Tensor(np.asarray(mesh.faces, np.uint32))
    )
    floor = trimesh.creation.box(extents=(12.0, 12.0, 0.02), transform=make_pose((0, 0, -0.01)))
    scene.add_triangles(
        o3c.Tensor(np.asarray(floor.vertices, np.float32)), o3c.Tensor(np.asarray(floor.faces, np.uint32))
    )
    size = mesh.extents
    out = []
    for _ in range(views):
        azimuth = rng.uniform(0, 2 * np.pi)
        distance = max(0.9, 1.1 * float(np.max(size[:2]))) + rng.uniform(0.3, 1.8)
        eye = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), rng.uniform(0.9, 1.6)])
        target = np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), size[2] * rng.uniform(0.2, 0.6)])
        cam = look_at(eye, target)
        rays = scene.create_rays_pinhole(
            o3c.Tensor(INTRINSICS.matrix), o3c.Tensor(invert(cam)), INTRINSICS.width, INTRINSICS.height
        )
        hit = scene.cast_rays(rays)
        depth = hit["t_hit"].numpy().astype(np.float32)
        gid = hit["geometry_ids"].numpy().astype(np.int64)
        valid = np.isfinite(depth) & (gid < 2)
        depth = np.where(valid, depth, 0.0).astype(np.float32)
        dirs = rays.numpy()[..., 3:]
        dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
        facing = np.abs(np.einsum("hwc,hwc->hw", hit["primitive_normals"].numpy(), -dirs)).astype(np.float32)
        view = RenderedView(
            np.zeros((*depth.shape, 3), np.uint8),
            depth,
            np.zeros(depth.shape, np.uint16),
            np.where(valid, gid, -1).astype(np.int32),
            np.where(valid, facing, 0).astype(np.float32),
        )
        noisy = apply_kinect_noise(view, rng, min_range=0.4, max_range=6.0, grazing_angle_deg=84.0, edge_dropout=0.5)
        obj = (gid == 0) & (noisy > 0)
        grown = obj.copy()
        for _ in range(spill_pixels):  # segmentation spill: masks bleed a pixel or two onto what is behind
            g = np.pad(grown, 1)
            grown = grown | g[:-2, 1:-1] | g[2:, 1:-1] | g[1:-1, :-2] | g[1:-1, 2:]
        spill = grown & ~obj & (noisy > 0) & (rng.random(obj.shape) < spill_probability)
        points = backproject(noisy, obj, cam)
        spilled = backproject(noisy, spill, cam)
        if len(points) and len(spilled):
            # Only what lies right behind the object joins it (a mask edge over the far floor does not fuse).
            spilled = spilled[spatial.cKDTree(points).query(spilled)[0] < SPILL_DISTANCE]
        out += [points, spilled]
    return np.vstack(out) if out else np.zeros((0, 3))


def backproject(depth: np.ndarray, mask: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    cam_pts = np.c_[(u - INTRINSICS.cx) * z / INTRINSICS.fx, (v - INTRINSICS.cy) * z / INTRINSICS.fy, z]
    return cam_pts @ camera_to_world[:3, :3].T + camera_to_world[:3, 3]


def make_example(
    mesh: trimesh.Trimesh, class_name: str, rng: np.random.Generator, max_views: int = 3
) -> Example | None:
    """One training example: ``mesh`` (canonical frame) turned by a random yaw, seen partially, put in
    the object frame the completer uses; None when too little of it was seen."""
    world = mesh.copy()
    world.apply_transform(make_pose((0, 0, 0), rng.uniform(-np.pi, np.pi)))
    observed = render_partial(world, rng, int(rng.integers(1, max_views + 1)))
    if len(observed) < 50:
        return None
    observed = voxel_downsample(observed, THIN_VOXEL)[0]
    if len(observed) < 50:
        return None
    box = gravity_aligned_box(observed)
    frame = frame_for(np.array([box.center[0], box.center[1], 0.0]), box.yaw, box.size)
    truth_world = np.asarray(trimesh.sample.sample_surface(world, DENSE_POINTS, seed=int(rng.integers(2**31)))[0])
    seen = spatial.cKDTree(observed).query(truth_world)[0] < 0.02
    points = fixed_count(observed[rng.permutation(len(observed))], INPUT_POINTS)
    return Example(
        frame.to_local(points).astype(np.float32),
        frame.to_local(truth_world).astype(np.float32),
        class_onehot(class_name),
        frame.scale,
        float(seen.mean()),
    )
