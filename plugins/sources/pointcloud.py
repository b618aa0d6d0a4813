"""Source ``pointcloud``: a static point cloud (PLY, PCD, XYZ, NPY) with optional colors and labels, a
laser scanner's E57 or LAS/LAZ file (:mod:`stratamap.core.io.scans`), or a scanned mesh (OBJ,
GLB/glTF, STL, OFF, a PLY with faces) sampled evenly on its surface, with its colours (a room mesh's
walls may be two triangles each: its vertices are no sampling of it).

An E57 file's scans are merged in its common frame and its scanners' positions kept
(``metadata['sensor_positions']``: where `clusters` looks from and the floor search's sensors). A
LAS file, or any cloud farther than ``FAR_COORDINATES`` from its origin (a georeferenced frame), has
no scanner position; a georeferenced cloud is moved next to the origin (``metadata['origin_offset']``),
since maps and exports keep coordinates in 32-bit floats.

Invalid points (NaN or inf coordinates) are dropped, and so, with a warning, are points far from the
rest (:func:`~stratamap.core.geometry.points.far_from_bulk`: one glitch at 1e9 m would otherwise set
every bound taken from the cloud). A cloud whose bulk spans hundreds of units along every axis is named
as one in millimetres or centimetres (:func:`~stratamap.core.geometry.points.unit_hint`): in the error
when no floor is found (a room 1000 times too large has none at 2 cm), else in a warning.
Per-point labels become ground truth:
``label_scheme: raw`` keeps each label as an instance of class ``object`` (0 = unlabelled);
``label_scheme: mosd`` reads the Object Segmentation Database convention (0 invalid, 1-9 parts
of the supporting table, 10k..10k+9 parts of object k-1: label // 10 is the object).

Which way is up (``up_axis``) cannot always be read from the geometry: a room's floor, ceiling and
walls all bound it, and any of them may hold the most points. ``auto`` follows the conventions (an
organized cloud is a camera's, y down; any other is z up, else y down) and, on an unorganized cloud,
looks along the other conventions too: a larger plane there (unless the map is much flatter along the
floor's normal: rooms are wider than tall), a plane half the floor's size along which the map is much
flatter, or a plane opposite the floor half its size, is a warning that names the ``up_axis`` to set
(``rival_floors``, ``axis_spans``, ``up_doubt``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import FAR_FROM_BULK, bulk_box, far_from_bulk, unit_hint
from stratamap.core.io.mesh import is_mesh_file, read_mesh, read_vertices_only, sample_surface
from stratamap.core.io.pointcloud import read_point_cloud
from stratamap.core.io.scans import LAS_NOISE_CLASSES
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.sources._depth_smoothing import smooth_depth, smooth_unorganized_depth
from stratamap.plugins.sources._gravity import ScenePlanes, estimate_alignment, stream_planes, transform_stream

#: Farther than this from the origin (metres, x or y), a cloud is moved next to it (a georeferenced frame).
FAR_COORDINATES = 10_000.0
UP_AXES = {"z": (0.0, 0.0, 1.0), "-y": (0.0, -1.0, 0.0), "y": (0.0, 1.0, 0.0), "-z": (0.0, 0.0, -1.0)}


def intensity_grey(intensity: np.ndarray) -> tuple[np.ndarray | None, dict[str, float]]:
    """(N, 3) grey levels in [0, 1] from a scanner's per-point intensity, its 1st to 99th percentile
    (of the finite values) stretched to black to white, or None when it does not vary; and the stretch.
    Percentiles, not the extremes: a few specular returns would leave the rest of the scan dark."""
    values = np.asarray(intensity, np.float64).reshape(len(intensity), -1)[:, 0]
    finite = np.isfinite(values)
    if not finite.any():
        return None, {}
    low, high = (float(v) for v in np.percentile(values[finite], [1.0, 99.0]))
    if high <= low:
        return None, {}
    grey = np.clip((np.where(finite, values, low) - low) / (high - low), 0.0, 1.0)
    return np.repeat(grey[:, None], 3, axis=1), {"low": round(low, 6), "high": round(high, 6)}


class PointCloudConfig(StageConfig):
    path_fields = ("path",)

    path: str = Field(
        description=(
            "A .ply, .pcd, .xyz/.xyzrgb/.pts or .npy file (N x 3, 6 or 7 columns: xyz, rgb, label), a laser "
            "scanner's .e57 (every scan, seen from its scanner's pose) or .las/.laz (the `scans` extra), or a "
            "scanned mesh (.obj, .glb/.gltf, .stl, .off, or a .ply with faces), sampled on its surface."
        )
    )
    label_field: str = Field(default="label", description="Name of the per-point label attribute (PLY/PCD).")
    label_scheme: Literal["none", "raw", "mosd"] = Field(
        default="raw", description="How labels map to classes and instances (see module doc)."
    )
    up_axis: Literal["auto", "z", "-y", "y", "-z"] = Field(
        default="auto",
        description=(
            "Up direction of the input: -y for a cloud in a camera's optical frame (Kinect and stereo scans), z for "
            "a scan or map in a z-up frame; auto: -y for an organized cloud (a PCD with one point per pixel of an "
            "image, so in its camera's frame), else z, then -y if no floor is found along z; on such a cloud a plane "
            "along z, y or -y larger than the floor taken (unless the map is much flatter along the floor's normal), "
            "one at least half its size along which the map is much flatter (rooms are wider than tall), or one "
            "opposite it half its size or more, is a warning: which of a room's bounding planes is its floor is then "
            "a guess (y: glTF and phone scans)."
        ),
    )
    gravity: Literal["auto", "off"] = Field(
        default="auto",
        description=(
            "auto: find the lowest large plane perpendicular to up_axis (the floor, or the table of a tabletop scan) "
            "and make it z = 0."
        ),
    )
    up_tolerance_deg: float | None = Field(
        default=None,
        gt=0,
        le=89,
        description=(
            "Max angle between up_axis and the support plane's normal; default: 60 for a camera's frame (-y or y: "
            "a camera looks down steeply at a tabletop), 35 for a z-up input."
        ),
    )
    scale: float = Field(default=1.0, gt=0, description="Multiply coordinates by this (e.g. 0.001 for millimetres).")
    intensity_as_color: bool = Field(
        default=True,
        description=(
            "A cloud with no colours but an `intensity` field (a laser scanner's E57, LAS or PCD) is shown in grey "
            "levels of its intensity (1st to 99th percentile stretched to black to white), so views, meshes and "
            "GLB exports show its surfaces' reflectance instead of one flat grey; false: no colours."
        ),
    )
    drop_noise: bool = Field(
        default=True,
        description=(
            "Leave out the points a scanner's software marked as noise in a LAS/LAZ file (ASPRS classification 7, "
            "low point, and 18, high noise) or flagged withheld; false: keep them. The classes found are noted "
            "(las_classes)."
        ),
    )
    smooth_depth: Literal["auto", "off"] = Field(
        default="auto",
        description=(
            "auto: a cloud in its camera's frame (organized, or stored without its image grid) whose depths come "
            "in a structured-light or stereo camera's disparity steps is bilaterally filtered in inverse depth "
            "(KinectFusion's smoothing), so far surfaces are not staircases of slivers; off: the points as read."
        ),
    )
    # A scanned room's mesh has few vertices where it is flat (a wall may be two triangles): its points are
    # taken on the surface, evenly by area, not at the vertices.
    mesh_spacing: float = Field(
        default=0.02, gt=0, description="A mesh is sampled with one point per mesh_spacing^2 of surface, metres."
    )
    mesh_max_points: int = Field(
        default=4_000_000,
        ge=1000,
        description="At most this many points from a mesh (a larger surface is sampled more sparsely, with a warning).",
    )


def read_cloud(path: Path, label_field: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(points, colors in [0, 1] or None, labels or None) from a supported file, verified against its header
    (see :mod:`stratamap.core.io.pointcloud`): a cut or malformed file is a ``DataError``, never zeros."""
    cloud = read_point_cloud(path, label_field)
    return cloud.points, cloud.colors, _labels(cloud, path, label_field)


def _labels(cloud: Any, path: Path, label_field: str) -> np.ndarray | None:
    labels = cloud.fields.get(label_field)
    if labels is not None:
        labels = np.asarray(labels)
        if labels.ndim != 1:
            raise DataError(f"{path}: label field {label_field!r} has {labels.shape[1]} values per point, expected 1")
    return labels


def up_settings(up_axis: str, tolerance: float | None, organized: bool) -> list[tuple[str, float]]:
    """The (up axis, tolerance in degrees) to look for the floor with, in order: ``auto`` is -y for an
    organized cloud (a camera's frame), else z and then -y (a camera's cloud stored unorganized); the
    tolerance defaults to 60 in a camera's frame (-y or y) and to 35 for a z-up input."""
    axes = [up_axis] if up_axis != "auto" else ["-y"] if organized else ["z", "-y"]
    return [(axis, tolerance if tolerance is not None else (60.0 if axis in ("-y", "y") else 35.0)) for axis in axes]


#: The up axes of the common conventions of unorganized clouds: z (ROS, PCL, LAS, Blender), y (glTF,
#: phone scanners such as ARKit-based apps), -y (a camera's optical frame).
CONVENTIONS = ("z", "y", "-y")


def rival_floors(stream: Any, chosen: str, planes: ScenePlanes) -> dict[str, int]:
    """For ``up_axis: auto`` on an unorganized cloud: the points of the floor each other convention's
    up axis finds among the stream's ``planes`` (0: none), to tell whether the chosen one was a guess."""
    rivals = {}
    for axis in CONVENTIONS:
        if axis == chosen:
            continue
        try:
            tolerance = up_settings(axis, None, organized=False)[0][1]
            hint = np.array(UP_AXES[axis])
            rivals[axis] = estimate_alignment(stream, hint, max_angle_deg=tolerance, planes=planes).floor_inliers
        except DataError:
            rivals[axis] = 0
    return rivals


#: A plane along another axis larger than the floor is no doubt when the map spans less than this
#: share of its extent along the floor's normal than along the plane's: a room is wider than it is tall
#: (a fused walk's room, 5 x 4.2 m seen to 1.6 m: 0.38; the same room stored on its side: 2.6).
FLAT_SPAN = 0.75
#: Which software writes which up axis, for the warnings that name one to set.
CONVENTION_AXES = "(y for glTF and phone scans, z for ROS and PCL, -y for a camera's frame)"


def axis_spans(points: np.ndarray) -> dict[str, float]:
    """The extent of ``points`` along each convention's up axis, metres (1st to 99th percentile)."""
    lo, hi = np.percentile(np.asarray(points), [1, 99], axis=0)
    column = {axis: int(np.abs(UP_AXES[axis]).argmax()) for axis in CONVENTIONS}
    return {axis: float(hi[column[axis]] - lo[column[axis]]) for axis in CONVENTIONS}


def up_doubt(chosen: str, inliers: int, rivals: dict[str, int], spans: dict[str, float] | None = None) -> str | None:
    """Why the floor ``up_axis: auto`` chose may be a wall or the ceiling, or None. Geometry alone cannot
    tell them apart: a room's floor, ceiling and walls all bound it, and any of them may be the largest.
    The choice is a guess the user must confirm when a plane along another axis is larger than the floor
    found, unless the map is much flatter along the floor's normal than along that plane's (``spans``,
    ``FLAT_SPAN``: rooms are wider than tall); when such a plane holds half the floor's points or more
    and the map is much flatter along it; or when the plane opposite the floor is half its size or more
    (a floor and a ceiling)."""
    opposite = chosen[1:] if chosen.startswith("-") else f"-{chosen}"

    def flatter(a: str, b: str) -> bool:
        return spans is not None and spans[a] < FLAT_SPAN * spans[b]

    larger = [axis for axis, count in rivals.items() if count > inliers and not flatter(chosen, axis)]
    if larger:
        axis = max(larger, key=lambda a: rivals[a])
        return (
            f"up_axis auto took {chosen} (a floor of {inliers} sampled points), but a plane along {axis} holds "
            f"{rivals[axis]}: if the map lies on its side or upside down, set up_axis {axis} {CONVENTION_AXES}"
        )
    flat = [axis for axis, count in rivals.items() if count >= 0.5 * inliers and flatter(axis, chosen)]
    if flat and spans is not None:
        axis = max(flat, key=lambda a: rivals[a])
        return (
            f"up_axis auto took {chosen} (a floor of {inliers} sampled points), but a plane along {axis} holds "
            f"{rivals[axis]} and the map spans {spans[axis]:.1f} m along {axis} against {spans[chosen]:.1f} m along "
            f"{chosen} (rooms are wider than tall): if the map lies on its side, set up_axis {axis} {CONVENTION_AXES}"
        )
    if rivals.get(opposite, 0) >= 0.5 * inliers:
        return (
            f"up_axis auto took {chosen}, but the plane opposite the floor ({rivals[opposite]} sampled points "
            f"against its {inliers}) may be the floor instead: if the map is upside down, set up_axis {opposite}"
        )
    return None


def _check_values(path: Path, valid: np.ndarray, colors: np.ndarray | None, labels: np.ndarray | None) -> None:
    """Colors and labels of the valid points must be finite (and labels whole numbers)."""
    if colors is not None:
        bad = ~np.all(np.isfinite(colors[valid]), axis=1)
        if bad.any():
            raise DataError(f"{path}: {int(bad.sum())} points with valid coordinates have NaN or infinite colors")
    if labels is None:
        return
    lab = labels[valid]
    if lab.dtype.kind not in "iuf":
        raise DataError(f"{path}: labels of type {lab.dtype}; expected integers")
    if lab.dtype.kind == "f":
        bad = ~np.isfinite(lab) | (lab != np.round(lab))
        if bad.any():
            raise DataError(f"{path}: {int(bad.sum())} labels are not whole numbers (first: {lab[bad][0].item()!r})")
    if lab.size and (lab.min() < -(2**31) or lab.max() >= 2**31):
        raise DataError(f"{path}: labels range {lab.min()}..{lab.max()}; expected 32-bit integers")


class PointCloudSource(Source[PointCloudConfig]):
    """Static point clouds (PLY, PCD, XYZ, NPY) with optional colors and per-point labels as ground truth,
    laser scanners' files (E57, LAS/LAZ), or scanned meshes (OBJ, GLB, STL, OFF, PLY with faces) sampled on
    their surface."""

    name = "pointcloud"
    Config = PointCloudConfig
    provides = frozenset({"frames", "ground_truth"})

    @classmethod
    def example_params(cls) -> dict:
        from stratamap.core.paths import scratch_dir

        rng = np.random.default_rng(0)
        floor = np.c_[rng.uniform(0, 2, (3000, 2)), np.zeros(3000)]
        box = rng.uniform([0.8, 0.8, 0.0], [1.2, 1.2, 0.4], (800, 3))
        arr = np.vstack([np.c_[floor, np.full(3000, 1)], np.c_[box, np.full(800, 20)]])
        path = scratch_dir("stratamap-cloud-") / "cloud.npy"
        np.save(path, arr)
        return {"path": str(path), "label_scheme": "mosd"}

    def _sample_mesh(self, path: Path) -> tuple[np.ndarray, np.ndarray | None]:
        cfg = self.config
        try:
            mesh = read_mesh(path, "scanned mesh")
        except DataError:
            vertices = read_vertices_only(path)  # read again only when it holds no triangle mesh
            if vertices is None:
                raise
            # A cloud stored in a mesh format: its vertices are the points.
            self.note("mesh", {"triangles": 0, "vertices_as_points": len(vertices[0])})
            return vertices
        try:  # spacing in the file's units (scale turns them into metres afterwards)
            pts, colors, used = sample_surface(mesh, cfg.mesh_spacing / cfg.scale, cfg.mesh_max_points)
        except DataError as err:
            raise DataError(f"{path}: {err}") from None
        area, used = float(mesh.area) * cfg.scale**2, used * cfg.scale
        if used > cfg.mesh_spacing * (1 + 1e-9):
            self.warn(
                f"{path}: {area:.1f} m^2 of surface at mesh_spacing {cfg.mesh_spacing:g} m would be over "
                f"mesh_max_points ({cfg.mesh_max_points}): sampled every {used:.3f} m instead"
            )
        self.note("mesh", {"triangles": len(mesh.faces), "area_m2": round(area, 3), "spacing_m": round(used, 4)})
        return pts, colors

    def _marked_noise(self, fields: dict[str, np.ndarray]) -> np.ndarray | None:
        """Which points the file marked as noise (LAS classification 7 or 18, or withheld), with
        ``drop_noise`` on; None where it marks none. Notes the classes the file holds."""
        classes, withheld = fields.get("classification"), fields.get("withheld")
        if classes is not None:
            codes, counts = np.unique(classes, return_counts=True)
            self.note("las_classes", {str(int(c)): int(n) for c, n in zip(codes, counts, strict=True)})
        if not self.config.drop_noise or (classes is None and withheld is None):
            return None
        noise = np.isin(classes, list(LAS_NOISE_CLASSES)) if classes is not None else np.zeros(len(withheld), bool)
        if withheld is not None:
            noise |= withheld
        return noise if noise.any() else None

    def _with_unit_hint(self, err: DataError, points: np.ndarray) -> DataError:
        """``err`` (no floor found), with why the cloud looks written in millimetres or centimetres when its
        bulk says so and no scale was given: a room read 1000 times too large has no floor at 2 cm."""
        hint = unit_hint(points) if self.config.scale == 1.0 else None
        return DataError(f"{err}; {hint}") if hint else err

    def _strays(self, path: Path, pts: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """Which of the ``valid`` points lie far from the rest (:func:`far_from_bulk`: a glitch at 1e9 m
        would stretch every bound taken from the cloud, a floor search's voxels and the map's grid), with a
        warning saying how many."""
        far = np.zeros(len(pts), bool)
        if not valid.any():
            return far
        far[valid] = far_from_bulk(pts[valid])
        if far.any():
            low, high = bulk_box(pts[valid & ~far])
            reach = float(np.max(np.abs(pts[far]))) * self.config.scale
            self.warn(
                f"{path}: {int(far.sum())} of {int(valid.sum())} points lie far from the rest (more than "
                f"{FAR_FROM_BULK:g} times the {float(np.max(high - low)) * self.config.scale:.3g} m its bulk spans, "
                f"up to {reach:.3g} m from the origin): left out"
            )
        return far

    def _near_origin(self, path: Path, pts: np.ndarray, metadata: dict[str, Any]) -> np.ndarray:
        """A cloud in a georeferenced frame (UTM eastings of 500 km) moved next to the origin: maps and
        exports keep coordinates in 32-bit floats, which hold centimetres only within a few kilometres."""
        if np.abs(pts[:, :2]).max() <= FAR_COORDINATES:
            return pts
        offset = np.r_[np.floor(pts[:, :2].min(axis=0)), 0.0]
        metadata["origin_offset"] = offset.tolist()
        self.note("origin_offset", offset.tolist())  # the report's notes: map + offset = the file's coordinates
        if "sensor_positions" in metadata:
            metadata["sensor_positions"] = (np.asarray(metadata["sensor_positions"]) - offset).tolist()
        else:
            metadata["sensor_origin"] = False  # a georeferenced frame's origin is no scanner's position
        self.warn(
            f"{path}: coordinates reach {np.abs(pts[:, :2]).max():.0f} m from the origin (a georeferenced frame): "
            f"the map is moved by ({-offset[0]:.0f}, {-offset[1]:.0f}) m to keep centimetres "
            "(add the stream's origin_offset to map coordinates to get the file's)"
        )
        return pts - offset

    def read(self) -> dict[str, Any]:
        cfg = self.config
        path = Path(cfg.path).expanduser()
        gltf = path.suffix.lower() in (".glb", ".gltf")
        mesh = is_mesh_file(path)
        positions = None  # where scanners stood, when the file says (E57), in its frame
        seen_from = None  # per point, which of them saw it
        noise = None  # per point, whether the file marked it noise (LAS classification, withheld)
        if mesh:
            pts, colors = self._sample_mesh(path)
            labels, organized = None, False
        else:
            cloud = read_point_cloud(path, cfg.label_field)
            pts, colors, labels = cloud.points, cloud.colors, _labels(cloud, path, cfg.label_field)
            if colors is None and cfg.intensity_as_color and "intensity" in cloud.fields:
                colors, stretch = intensity_grey(cloud.fields["intensity"])
                if colors is not None:
                    self.note("colors_from_intensity", stretch)
            noise = self._marked_noise(cloud.fields)
            organized = cloud.image_size is not None
            positions = cloud.sensor_positions
            if positions is None and cfg.smooth_depth == "auto":
                # Only in the camera's own frame (no VIEWPOINT away from the origin) is z each pixel's depth.
                if organized:
                    pts, smoothing = smooth_depth(pts, cloud.image_size)
                else:
                    pts, smoothing = smooth_unorganized_depth(pts)
                self.note("depth_smoothing", smoothing.report())
            seen_from = cloud.sensor_ids
            if seen_from is None and positions is not None and len(positions) == 1:
                seen_from = np.zeros(len(pts), np.int64)  # one scanner saw every point (a PCD's viewpoint)
        # glTF is y up by its specification: turned z up as read, no guess (an up_axis given is the file's).
        from_gltf = gltf and cfg.up_axis == "auto"
        if from_gltf:
            pts = np.c_[pts[:, 0], -pts[:, 2], pts[:, 1]]
        wanted = "z" if from_gltf else cfg.up_axis
        tries = up_settings(wanted, cfg.up_tolerance_deg, organized)
        valid = np.all(np.isfinite(pts), axis=1)
        dropped = int((~valid).sum())
        if not valid.any():
            raise DataError(f"{path}: none of its {len(pts)} points has finite coordinates (all NaN or infinite)")
        if noise is not None:
            if noise[valid].all():
                codes = " or ".join(map(str, LAS_NOISE_CLASSES))
                raise DataError(
                    f"{path}: every point is marked noise or withheld (LAS classification {codes}, or the withheld "
                    "flag); set source.params.drop_noise=false to keep them"
                )
            valid &= ~noise
        _check_values(path, valid, colors, labels)
        far = self._strays(path, pts, valid)
        valid &= ~far
        pts = pts[valid] * cfg.scale
        colors = None if colors is None else np.clip(colors[valid], 0, 1)
        labels = None if labels is None else labels[valid].astype(np.int64)
        seen_from = None if seen_from is None else seen_from[valid]
        if not np.all(np.isfinite(pts)):
            raise DataError(f"{path}: coordinates overflow when multiplied by scale {cfg.scale:g}")
        metadata: dict[str, Any] = {"path": str(path), "dropped_invalid": dropped}
        if mesh or (positions is not None and len(positions) == 0):
            # A mesh's origin is where the modeller put it; a LAS file's is a map's: no scanner stood there.
            metadata["sensor_origin"] = False
        elif positions is not None:
            metadata["sensor_positions"] = (np.asarray(positions) * cfg.scale).tolist()
        pts = self._near_origin(path, pts, metadata)
        stream = SensorStream(
            name=path.stem, points=pts, point_colors=colors, point_sensor_ids=seen_from, metadata=metadata
        )
        points_note = {"valid": len(pts), "dropped_invalid": dropped}
        if noise is not None:
            points_note["dropped_noise"] = int(noise.sum())
        if far.any():
            points_note["dropped_far"] = int(far.sum())
        self.note("points", points_note)
        out: dict[str, Any] = {"frames": stream}
        if labels is not None and cfg.label_scheme != "none":
            out["ground_truth"] = self._ground_truth(labels, cfg.label_scheme)
        if cfg.gravity == "auto":
            looked = " then ".join(axis for axis, _ in tries)
            try:
                planes = stream_planes(stream)  # one plane search for every up axis tried
            except DataError as err:
                raise self._with_unit_hint(err, stream.points) from None
            for k, (up_axis, up_tolerance) in enumerate(tries):
                try:
                    alignment = estimate_alignment(
                        stream,
                        up_hint=np.array(UP_AXES[up_axis]),
                        max_angle_deg=up_tolerance,
                        planes=planes,
                        advice=(
                            "looked along glTF's up, y (its specification): if the file was written z up, as some "
                            "exporters do, set up_axis z"
                            if from_gltf
                            else f"looked along up_axis {looked}: if the input is already z-up set `gravity: off`, "
                            "else give its up_axis (-y for a camera's optical frame, as Kinect and stereo scans) or a "
                            "larger up_tolerance_deg (a steep view of a tabletop needs about 60)"
                        ),
                    )
                    break
                except DataError as err:
                    if k == len(tries) - 1:
                        raise self._with_unit_hint(err, stream.points) from None
            report = {"up_axis": up_axis, "up_tolerance_deg": up_tolerance, **alignment.report()}
            if from_gltf:
                report["converted_from"] = "glTF y up"
            if from_gltf or (wanted == "auto" and not organized):
                rivals = rival_floors(stream, up_axis, planes)
                spans = axis_spans(stream.points)
                report["other_axes"] = rivals
                report["spans_m"] = {axis: round(span, 3) for axis, span in spans.items()}
                doubt = up_doubt(up_axis, alignment.floor_inliers, rivals, spans)
                if doubt and from_gltf:  # some exporters write glTF z up, against the specification
                    doubt = (
                        f"taken y up, as glTF specifies, but another way up fits as well ({rivals} sampled points "
                        f"against the floor's {alignment.floor_inliers}, as turned z up): if the map lies on its "
                        "side, the file was written z up: set up_axis z"
                    )
                if doubt:
                    self.warn(f"{path}: {doubt}")
            self.note("gravity_alignment", report)
            if alignment.realigned:
                transform_stream(stream, alignment.transform)
                self.warn(
                    f"input was not z-up: re-aligned by {alignment.rotation_deg:.1f} deg (support plane moved to z = 0)"
                )
        hint = unit_hint(stream.points) if cfg.scale == 1.0 else None
        if hint:  # mapped all the same (a floor found, or none looked for), 1000 times too large
            self.warn(f"{path}: {hint}")
        return out

    @staticmethod
    def _ground_truth(labels: np.ndarray, scheme: str) -> GroundTruth:
        vocab = Vocabulary.default()
        cls = np.zeros(len(labels), np.int32)
        inst = np.zeros(len(labels), np.int32)
        if scheme == "mosd":
            table = (labels >= 1) & (labels <= 9)
            obj = labels >= 10
            cls[table] = vocab.id("table")
            inst[table] = 1
            cls[obj] = vocab.id("object")
            inst[obj] = (labels[obj] // 10).astype(np.int32)
        else:
            cls[labels > 0] = vocab.id("object")
            inst[labels > 0] = labels[labels > 0].astype(np.int32)
        return GroundTruth(vocabulary=vocab, point_class_ids=cls, point_instance_ids=inst)


@hookimpl
def stratamap_register_sources():
    return [PointCloudSource]
