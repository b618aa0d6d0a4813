"""Source ``scannet``: exported ScanNet-style frames (color/, depth/, pose/, intrinsic/).

``color/N.jpg`` (resampled to the depth size), ``depth/N.png`` (16-bit millimetres),
``pose/N.txt`` (4x4 camera-to-world; rows of -inf mark lost tracking and become missing poses),
``intrinsic/intrinsic_depth.txt`` (4x4). Frames sort by their number.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
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
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import SensorStream
from stratamap.plugins.sources._sequence import PosedFrames, SequenceConfig, SequenceSource, example_sequence, select


class ScanNetConfig(SequenceConfig):
    depth_scale: float = Field(default=1000.0, gt=0, description="Depth units per metre (ScanNet: millimetres).")
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps are frame number / frame_rate, seconds.")


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
        idx = select(list(range(len(depths))), cfg.stride, cfg.max_frames)
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
