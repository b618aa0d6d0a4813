"""Source ``redwood``: Open3D / Redwood RGB-D folders (color/, depth/ in millimetres, a .log trajectory).

Images pair by sorted file order (or by an ``rgbd.match`` file when present); poses come from
``trajectory.log`` (blocks of ``id id frame`` and a 4x4 camera-to-world matrix); intrinsics
from an Open3D ``camera*.json`` (column-major ``intrinsic_matrix``), else the PrimeSense defaults.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import Field

from stratamap.core import hookimpl
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.rgbd import (
    check_depth_scale,
    read_depth,
    read_open3d_camera,
    read_rgb,
    read_text_lines,
    rigid_pose,
    write_redwood,
)
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import CameraIntrinsics, SensorStream
from stratamap.plugins.sources._sequence import PosedFrames, SequenceConfig, SequenceSource, example_sequence, select

PRIMESENSE = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".ppm", ".pgm")


class RedwoodConfig(SequenceConfig):
    depth_scale: float = Field(default=1000.0, gt=0, description="Depth units per metre (Redwood: millimetres).")
    trajectory: str = Field(
        default="trajectory.log", description="Trajectory file in the folder (Redwood .log format)."
    )
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps are frame index / frame_rate, seconds.")


def read_log(path: Path) -> dict[int, np.ndarray]:
    """Redwood/Open3D .log: per frame a line 'id id frame_number' then four matrix rows; poses in file order,
    keyed by frame id, which must increase (a repeated or decreasing id is an error, not a silent overwrite)."""
    lines = [ln.split() for ln in read_text_lines(path) if ln.strip()]
    if not lines:
        raise DataError(f"{path}: empty; a .log file has 5 lines per pose (an 'id id frame' line and 4 matrix rows)")
    if len(lines) % 5:
        raise DataError(f"{path}: {len(lines)} non-empty lines; a .log file has 5 lines per pose (cut short?)")
    poses: dict[int, np.ndarray] = {}
    last = None
    for k in range(0, len(lines), 5):
        entry = k // 5 + 1
        try:
            frame = int(lines[k][0])
            rows = [[float(v) for v in row] for row in lines[k + 1 : k + 5]]
        except ValueError as exc:
            raise DataError(f"{path}: entry {entry} is malformed ({brief(exc)})") from exc
        if len(lines[k]) != 3 or any(len(r) != 4 for r in rows):
            raise DataError(f"{path}: entry {entry}: expected an 'id id frame' line and four rows of 4 numbers")
        if last is not None and frame <= last:
            kind = "repeats" if frame == last else "goes back"
            raise DataError(f"{path}: entry {entry}: frame id {frame} {kind} after {last}; frame ids must increase")
        poses[frame] = rigid_pose(rows, f"{path}: entry {entry}")
        last = frame
    return poses


class RedwoodSource(SequenceSource[RedwoodConfig]):
    """Open3D / Redwood RGB-D folders: color/, depth/ (mm), trajectory.log, camera json."""

    name = "redwood"
    Config = RedwoodConfig

    @classmethod
    def example_params(cls) -> dict:
        return {"path": str(example_sequence(write_redwood, "redwood"))}

    def load(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        root = self.sequence_folder(("color", "depth"), "a Redwood sequence has color/ and depth/")
        colors = sorted(p for p in (root / "color").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        depths = sorted(p for p in (root / "depth").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if len(colors) != len(depths):
            raise DataError(f"{root}: {len(colors)} color images but {len(depths)} depth images")
        if not colors:
            raise DataError(f"{root}: no images")
        intr = PRIMESENSE
        cams = sorted(root.glob("camera*.json"))
        if cams:
            intr = read_open3d_camera(cams[0])
        else:
            self.warn(f"{root}: no camera*.json; using PrimeSense intrinsics (fx = fy = 525)")
        idx = select(list(range(len(colors))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)
        shape = (intr.height, intr.width)
        check_depth_scale(read_depth(depths[idx[0]], cfg.depth_scale, shape), depths[idx[0]], cfg.depth_scale)
        poses: list = [None] * len(idx)
        traj = root / cfg.trajectory
        if traj.is_file():
            table = read_log(traj)
            ordered = [table[f] for f in sorted(table)]
            if len(ordered) < len(colors):
                self.warn(f"{traj}: {len(ordered)} poses for {len(colors)} frames; frames without a pose use odometry")
            poses = [ordered[i].copy() if i < len(ordered) else None for i in idx]

        def read(k: int):
            i = idx[k]
            return read_rgb(colors[i], shape), read_depth(depths[i], cfg.depth_scale, shape)

        frames = PosedFrames([i / cfg.frame_rate for i in idx], read, poses)
        stream = SensorStream(
            name=root.name, intrinsics=intr, frames=frames, metadata={"path": str(root), "format": "redwood"}
        )
        return stream, frames, None


@hookimpl
def stratamap_register_sources():
    return [RedwoodSource]
