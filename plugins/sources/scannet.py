"""Source ``scannet``: ScanNet's raw ``.sens`` streams, or exported ScanNet-style frames (color/, depth/,
pose/, intrinsic/).

A ``.sens`` file (``path`` names it, or a folder holding one and no color/) is read as distributed
(:mod:`stratamap.core.io.sens`): depth at the file's depth shift, colour resampled to the depth size,
the depth intrinsics, camera-to-world poses (``-inf`` where tracking was lost: missing poses), the
depth timestamps when the file has them (else frame number / ``frame_rate``).

An export: ``color/N.jpg`` (resampled to the depth size), ``depth/N.png`` (16-bit millimetres),
``pose/N.txt`` (4x4 camera-to-world; rows of -inf mark lost tracking and become missing poses),
``intrinsic/intrinsic_depth.txt`` (4x4). Frames sort by their number.

Ground truth, for the public benchmarks (docs/public-benchmarks.md), in the scan's frame and
carried through the source's gravity re-alignment by ``world_transform``:

* ``scan2cad``: Scan2CAD's ``full_annotations.json``; the scan's aligned CAD models are read
  (:mod:`stratamap.core.io.scan2cad`) and the ``scan2cad`` metric family scores the completed
  objects against them (:mod:`stratamap.core.evaluation.scan2cad`);
* ``labels``: the scan's per-vertex NYU40 classes and instances (:mod:`stratamap.core.io.scannet_labels`),
  from ``scan_folder`` (default: the folder of the ``.sens`` file; of an export, its folder, then
  its parent); the ``panoptic`` and ``instances`` families are then measured against them
  (:mod:`stratamap.core.evaluation.scannet_panoptic`).

The scan's id (``scan_id``, default: the ``.sens`` file's stem or the export folder's name) names
its record in both.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np
from PIL import Image
from pydantic import Field

from stratamap.core import hookimpl
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.rgbd import (
    check_depth_scale,
    intrinsics_from,
    read_depth,
    read_image,
    read_rgb,
    rigid_pose,
    write_scannet,
)
from stratamap.core.io.scan2cad import AlignedModel, read_scan2cad
from stratamap.core.io.scannet_labels import read_scan_labels
from stratamap.core.io.sens import read_sens, read_sens_frame
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import SensorStream
from stratamap.plugins.sources._sequence import PosedFrames, SequenceConfig, SequenceSource, example_sequence, select


class ScanNetConfig(SequenceConfig):
    path: str = Field(description="A ScanNet .sens file, or a folder of an export (or holding one .sens file).")
    depth_scale: float = Field(
        default=1000.0, gt=0, description="Depth units per metre (ScanNet: millimetres; a .sens file's own when unset)."
    )
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps are frame number / frame_rate, seconds.")
    scan_id: str | None = Field(
        default=None,
        description="The ScanNet scan id (e.g. scene0011_00) the annotations name; default: the .sens file's stem, "
        "or the export folder's name.",
    )
    scan2cad: str | None = Field(
        default=None,
        description="Scan2CAD's full_annotations.json: its CAD alignments of this scan become ground truth (the "
        "scan2cad metric family).",
    )
    labels: bool = Field(
        default=False,
        description="Read the scan's per-vertex NYU40 labels and instances (_vh_clean_2.labels.ply, "
        "_vh_clean_2.0.010000.segs.json, .aggregation.json) as ground truth: panoptic quality of the map.",
    )
    label_set: Literal["nyu40", "scannet20"] = Field(
        default="nyu40",
        description="With labels: every NYU40 class the vocabulary has (nyu40), or ScanNet's 20 benchmark classes "
        "only (scannet20).",
    )
    scan_folder: str | None = Field(
        default=None,
        description="With labels: the folder of the scan's annotation files; default: the .sens file's folder (an "
        "export's folder, then its parent).",
    )

    path_fields = ("scan2cad", "scan_folder")


def _number(p: Path) -> int:
    try:
        return int(p.stem)
    except ValueError:
        raise DataError(f"{p}: ScanNet frame files are named by their number (e.g. 42.png)") from None


def read_matrix(path: Path) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"{path}: file missing")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file: the shape check below says so
            mat = np.loadtxt(path, dtype=float, ndmin=2)
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not a whitespace-separated matrix ({brief(exc)})") from exc
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({brief(exc)})") from exc
    if mat.shape != (4, 4):
        raise DataError(f"{path}: expected a 4x4 matrix, got shape {mat.shape}")
    return mat


class ScanNetSource(SequenceSource[ScanNetConfig]):
    """ScanNet-style exports: color/, depth/ (mm), pose/ (camera-to-world), intrinsic/."""

    name = "scannet"
    Config = ScanNetConfig

    @classmethod
    def example_params(cls) -> dict:
        folder = example_sequence(lambda stream, root: write_scannet(stream, root, color_size=(256, 192)), "scannet")
        return {"path": str(folder)}

    def load(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        sens = self._sens_file(Path(self.config.path).expanduser())
        if sens is not None:
            stream, frames, _ = self._load_sens(sens)
            return stream, frames, self._ground_truth(sens.stem, [sens.parent])
        stream, frames, _ = self._load_export()
        root = Path(str(stream.metadata["path"]))
        return stream, frames, self._ground_truth(root.name, [root, root.parent])

    def _ground_truth(self, default_id: str, folders: list[Path]) -> GroundTruth | None:
        """The benchmark annotations asked for, in the scan's frame (None when none is)."""
        cfg = self.config
        if cfg.scan2cad is None and not cfg.labels:
            return None
        scan_id = cfg.scan_id or default_id
        layout: dict[str, Any] = {"world_transform": np.eye(4).tolist(), "scannet_scan": scan_id}
        if cfg.scan2cad is not None:
            models = read_scan2cad(Path(cfg.scan2cad).expanduser(), scan_id)
            layout["scan2cad"] = [m.to_dict() for m in models]
            self.note("scan2cad", {"scan": scan_id, "aligned_models": len(models)})
        if cfg.labels:
            if cfg.scan_folder is not None:
                folders = [Path(cfg.scan_folder).expanduser()]
            found = next((f for f in folders if (f / f"{scan_id}_vh_clean_2.labels.ply").is_file()), folders[0])
            labels = read_scan_labels(found, scan_id)
            layout["scannet_labels"] = labels
            layout["scannet_label_set"] = cfg.label_set
            self.note("scannet_labels", {"scan": scan_id, "vertices": len(labels.points), "folder": str(found)})
        return GroundTruth(layout=layout)

    @staticmethod
    def _sens_file(path: Path) -> Path | None:
        """The .sens file ``path`` names or its folder holds (with no export beside it), else None."""
        if path.is_file():
            if path.suffix.lower() != ".sens":
                raise DataError(f"{path}: a file that is no .sens stream; give a .sens file or an export's folder")
            return path
        if not path.is_dir() or (path / "color").is_dir():
            return None
        found = sorted(path.glob("*.sens"))
        if len(found) > 1:
            raise DataError(f"{path}: holds {len(found)} .sens files ({found[0].name}, ...); give one as the path")
        return found[0] if found else None

    def _load_sens(self, path: Path) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        sens = read_sens(path)
        K = sens.intrinsic_depth
        width, height = sens.depth_size
        intr = intrinsics_from(
            {"width": width, "height": height, "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]},
            f"{path} (depth intrinsics)",
        )
        scale = cfg.depth_scale if "depth_scale" in cfg.model_fields_set else sens.depth_shift
        idx = select(list(range(len(sens))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)

        def read(k: int) -> tuple[np.ndarray, np.ndarray]:
            rgb, raw = read_sens_frame(sens, idx[k])
            if rgb.shape[:2] != (height, width):  # ScanNet's colour is larger than its depth
                rgb = np.asarray(Image.fromarray(rgb).resize((width, height), Image.BILINEAR))
            return rgb, raw.astype(np.float32) / np.float32(scale)

        check_depth_scale(read(0)[1], path, scale)
        poses: list = []
        for i in idx:
            pose = sens.poses[i]
            poses.append(rigid_pose(pose, f"{path}: frame {i}'s pose") if np.all(np.isfinite(pose)) else None)
        lost = sum(p is None for p in poses)
        if lost:
            self.warn(f"{path}: {lost} frames have invalid (-inf) poses (tracking lost); they use odometry")
        stamps = np.asarray(sens.timestamps, np.float64)[idx]
        recorded = len(stamps) > 0 and stamps[0] > 0 and np.all(np.diff(stamps) > 0)
        times = (stamps / 1e6).tolist() if recorded else [i / cfg.frame_rate for i in idx]
        frames = PosedFrames(times, read, poses)
        stream = SensorStream(
            name=path.stem,
            intrinsics=intr,
            frames=frames,
            metadata={"path": str(path), "format": "scannet_sens", "sensor_name": sens.sensor_name},
        )
        self.note("sens", {"frames": len(sens), "read": len(idx), "depth_shift": sens.depth_shift, "lost_poses": lost})
        return stream, frames, None

    def _load_export(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        root = self.sequence_folder(
            ("color", "depth", "intrinsic"), "ScanNet exports have color/, depth/, pose/, intrinsic/"
        )
        depths = sorted((root / "depth").glob("*.png"), key=_number)
        if not depths:
            raise DataError(f"{root}/depth: no .png depth images")
        numbers = [_number(p) for p in depths]
        repeated = sorted({n for a, n in zip(numbers, numbers[1:]) if a == n})
        if repeated:
            raise DataError(f"{root}/depth: frame number {repeated[0]} names two depth images (e.g. 7.png and 07.png)")
        first = read_image(depths[0])
        K_file = root / "intrinsic" / "intrinsic_depth.txt"
        K = read_matrix(K_file)
        intr = intrinsics_from(
            {
                "width": first.shape[1],
                "height": first.shape[0],
                "fx": K[0, 0],
                "fy": K[1, 1],
                "cx": K[0, 2],
                "cy": K[1, 2],
            },
            str(K_file),
        )
        idx = select(list(range(len(depths))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)
        shape = (intr.height, intr.width)
        check_depth_scale(read_depth(depths[idx[0]], cfg.depth_scale, shape), depths[idx[0]], cfg.depth_scale)
        poses: list = []
        lost = 0
        for i in idx:
            pose_file = root / "pose" / f"{numbers[i]}.txt"
            if not pose_file.is_file():
                poses.append(None)
                continue
            mat = read_matrix(pose_file)
            if not np.all(np.isfinite(mat)):
                poses.append(None)  # ScanNet writes -inf when tracking was lost
                lost += 1
            else:
                poses.append(rigid_pose(mat, str(pose_file)))
        if lost:
            self.warn(f"{lost} frames have invalid (-inf) poses in pose/; they use odometry")

        def read(k: int):
            n = numbers[idx[k]]
            color = root / "color" / f"{n}.jpg"
            if not color.is_file():
                color = root / "color" / f"{n}.png"
            return read_rgb(color, shape, resample=True), read_depth(depths[idx[k]], cfg.depth_scale, shape)

        frames = PosedFrames([numbers[i] / cfg.frame_rate for i in idx], read, poses)
        stream = SensorStream(
            name=root.name, intrinsics=intr, frames=frames, metadata={"path": str(root), "format": "scannet"}
        )
        return stream, frames, None


@hookimpl
def stratamap_register_sources():
    return [ScanNetSource]


@hookimpl
def stratamap_evaluate(data: Any, details: bool) -> dict[str, Any] | None:
    """The public benchmarks' families for the annotations this source read: ``scan2cad``, and
    ``panoptic``/``instances`` against ScanNet's vertex labels (replacing the built-in ones, which
    have no surface of this ground truth to label points by)."""
    gt = getattr(data, "ground_truth", None)
    layout = gt.layout if gt is not None and isinstance(gt.layout, dict) else {}
    if "scannet_scan" not in layout:
        return None
    world = np.asarray(layout.get("world_transform", np.eye(4)), float)
    out: dict[str, Any] = {}
    m = data.map
    if "scan2cad" in layout:
        from stratamap.core.evaluation.scan2cad import evaluate_scan2cad

        annotations = [AlignedModel.from_dict(d) for d in layout["scan2cad"]]
        out["scan2cad"] = evaluate_scan2cad(m.instances, annotations, world)
        if not details:
            out["scan2cad"].pop("objects")
    labels = layout.get("scannet_labels")
    if labels is not None and m.semantics is not None and m.geometry is not None:
        if len(m.geometry) == len(m.semantics):
            from stratamap.core.evaluation.scannet_panoptic import evaluate_scannet_panoptic

            out.update(
                evaluate_scannet_panoptic(
                    m.geometry.points,
                    m.semantics,
                    m.instances,
                    labels,
                    world,
                    layout.get("scannet_label_set", "nyu40"),
                )
            )
    return out
