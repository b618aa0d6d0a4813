"""Source ``pointcloud``: a static point cloud (PLY, PCD, XYZ, NPY) with optional colors and labels.

Invalid points (NaN or inf coordinates) are dropped. Per-point labels become ground truth:
``label_scheme: raw`` keeps each label as an instance of class ``object`` (0 = unlabelled);
``label_scheme: mosd`` reads the Object Segmentation Database convention (0 invalid, 1-9 parts
of the supporting table, 10k..10k+9 parts of object k-1: label // 10 is the object).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.sources._gravity import estimate_alignment, transform_stream

UP_AXES = {"z": (0.0, 0.0, 1.0), "-y": (0.0, -1.0, 0.0), "y": (0.0, 1.0, 0.0), "-z": (0.0, 0.0, -1.0)}


class PointCloudConfig(StageConfig):
    path: str = Field(
        description="A .ply, .pcd, .xyz/.xyzrgb/.pts or .npy file (N x 3, 6 or 7 columns: xyz, rgb, label)."
    )
    label_field: str = Field(default="label", description="Name of the per-point label attribute (PLY/PCD).")
    label_scheme: Literal["none", "raw", "mosd"] = Field(
        default="raw", description="How labels map to classes and instances (see module doc)."
    )
    up_axis: Literal["z", "-y", "y", "-z"] = Field(
        default="z",
        description="Up direction of the input (-y for clouds in a camera's optical frame, e.g. Kinect scans).",
    )
    gravity: Literal["auto", "off"] = Field(
        default="auto",
        description=(
            "auto: find the lowest large plane perpendicular to up_axis (the floor, or the table of a tabletop scan) "
            "and make it z = 0."
        ),
    )
    up_tolerance_deg: float = Field(
        default=35.0,
        gt=0,
        le=89,
        description="Max angle between up_axis and the support plane's normal (steep tabletop views need ~60).",
    )
    scale: float = Field(default=1.0, gt=0, description="Multiply coordinates by this (e.g. 0.001 for millimetres).")


def read_cloud(path: Path, label_field: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(points, colors in [0, 1] or None, labels or None) from a supported file."""
    if not path.is_file():
        raise DataError(f"{path}: point cloud file not found")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise DataError(f"{path}: not a plain .npy array ({exc})") from exc
        if arr.ndim != 2 or arr.shape[1] not in (3, 4, 6, 7):
            raise DataError(
                f"{path}: expected an (N, 3|4|6|7) array (xyz[, label] or xyz rgb[, label]), got {arr.shape}"
            )
        pts = arr[:, :3].astype(np.float64)
        colors = arr[:, 3:6].astype(np.float64) if arr.shape[1] >= 6 else None
        if colors is not None and colors.max() > 1.0:
            colors = colors / 255.0
        labels = arr[:, -1].astype(np.int64) if arr.shape[1] in (4, 7) else None
        return pts, colors, labels
    if suffix in (".ply", ".pcd", ".xyz", ".xyzrgb", ".xyzn", ".pts"):
        import open3d as o3d

        try:
            cloud = o3d.t.io.read_point_cloud(str(path))
        except RuntimeError as exc:
            raise DataError(f"{path}: cannot be read as a point cloud ({exc})") from exc
        if "positions" not in cloud.point or len(cloud.point.positions) == 0:
            raise DataError(f"{path}: contains no points (corrupt or empty file?)")
        pts = cloud.point.positions.numpy().astype(np.float64)
        colors = None
        if "colors" in cloud.point:
            c = cloud.point.colors.numpy().astype(np.float64)
            colors = c / 255.0 if c.max() > 1.0 else c
        labels = cloud.point[label_field].numpy().reshape(-1).astype(np.int64) if label_field in cloud.point else None
        return pts, colors, labels
    raise DataError(f"{path}: unsupported point cloud format {suffix!r} (use .ply, .pcd, .xyz or .npy)")


class PointCloudSource(Source[PointCloudConfig]):
    """Static point clouds (PLY, PCD, XYZ, NPY) with optional colors and per-point labels as ground truth."""

    name = "pointcloud"
    Config = PointCloudConfig
    provides = frozenset({"frames", "ground_truth"})

    @classmethod
    def example_params(cls) -> dict:
        import tempfile

        rng = np.random.default_rng(0)
        floor = np.c_[rng.uniform(0, 2, (3000, 2)), np.zeros(3000)]
        box = rng.uniform([0.8, 0.8, 0.0], [1.2, 1.2, 0.4], (800, 3))
        arr = np.vstack([np.c_[floor, np.full(3000, 1)], np.c_[box, np.full(800, 20)]])
        path = Path(tempfile.mkdtemp(prefix="stratamap-cloud-")) / "cloud.npy"
        np.save(path, arr)
        return {"path": str(path), "label_scheme": "mosd"}

    def read(self) -> dict[str, Any]:
        cfg = self.config
        path = Path(cfg.path).expanduser()
        pts, colors, labels = read_cloud(path, cfg.label_field)
        valid = np.all(np.isfinite(pts), axis=1)
        dropped = int((~valid).sum())
        pts = pts[valid] * cfg.scale
        colors = None if colors is None else np.clip(colors[valid], 0, 1)
        labels = None if labels is None else labels[valid]
        if len(pts) == 0:
            raise DataError(f"{path}: no valid (finite) points")
        stream = SensorStream(
            name=path.stem, points=pts, point_colors=colors, metadata={"path": str(path), "dropped_invalid": dropped}
        )
        self.note("points", {"valid": len(pts), "dropped_invalid": dropped})
        out: dict[str, Any] = {"frames": stream}
        if labels is not None and cfg.label_scheme != "none":
            out["ground_truth"] = self._ground_truth(labels, cfg.label_scheme)
        if cfg.gravity == "auto":
            alignment = estimate_alignment(
                stream, up_hint=np.array(UP_AXES[cfg.up_axis]), max_angle_deg=cfg.up_tolerance_deg
            )
            self.note("gravity_alignment", alignment.report())
            if alignment.realigned:
                transform_stream(stream, alignment.transform)
                self.warn(
                    f"input was not z-up: re-aligned by {alignment.rotation_deg:.1f} deg (support plane moved to z = 0)"
                )
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
