"""Source ``tum``: TUM RGB-D folders (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt).

RGB and depth are associated by nearest timestamp within ``association_tolerance``; poses come
from ``groundtruth.txt`` (interpolated to the depth timestamps) when it exists, else from
odometry. Intrinsics: ``camera.json`` beside the sequence (keys width, height, fx, fy, cx, cy,
depth_scale) when present, else ``intrinsics`` in the params, else the TUM benchmark camera its folder
name says (``freiburg1``, ``2`` or ``3``), else the TUM defaults (Freiburg 1, with a warning).
A ``gt/`` folder written by ``stratamap synth`` is loaded as ground truth (labels, meshes, graph).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from pydantic import Field

from stratamap.core import hookimpl
from stratamap.core.errors import DataError
from stratamap.core.io.groundtruth import load_ground_truth
from stratamap.core.io.rgbd import (
    DepthEncoding,
    associate,
    check_depth_scale,
    interpolate_poses,
    intrinsics_from,
    parse_tum_poses,
    read_depth,
    read_image,
    read_json,
    read_laser_file,
    read_rgb,
    read_timestamped_list,
)
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import CameraIntrinsics, SensorStream
from stratamap.plugins.sources._sequence import PosedFrames, SequenceConfig, SequenceSource, select

TUM_DEFAULT = {"width": 640, "height": 480, "fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3, "depth_scale": 5000.0}
#: The colour cameras of the TUM RGB-D benchmark (its published calibration), by the "freiburgN" its
#: sequences' folder names carry (rgbd_dataset_freiburg3_long_office_household).
TUM_CAMERAS = {
    "1": {"fx": 517.3, "fy": 516.5, "cx": 318.6, "cy": 255.3},
    "2": {"fx": 520.9, "fy": 521.0, "cx": 325.1, "cy": 249.7},
    "3": {"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6},
}


class TUMConfig(SequenceConfig):
    depth_scale: float | None = Field(
        default=None, gt=0, description="Depth units per metre; default: camera.json, else 5000 (TUM)."
    )
    depth_encoding: DepthEncoding = Field(
        default="linear",
        description=(
            "How the depth images store depth: linear (depth_scale units per metre), kinect_disparity (a Kinect v1's "
            "raw disparity, as NYU Depth V2's raw dumps), sun_rgbd (SUN RGB-D's bit-rotated millimetres); the last "
            "two ignore depth_scale."
        ),
    )
    intrinsics: dict[str, float] | None = Field(
        default=None, description="width, height, fx, fy, cx, cy when there is no camera.json."
    )
    association_tolerance: float = Field(
        default=0.02, gt=0, description="Max time between an rgb and a depth image to pair them, seconds."
    )
    pose_tolerance: float = Field(
        default=0.02, gt=0, description="Max time to the nearest ground-truth pose outside interpolation, seconds."
    )
    path_fields = ("path", "ground_truth_path")

    load_ground_truth: bool = Field(default=True, description="Load a gt/ folder beside the sequence when present.")
    ground_truth_path: str | None = Field(
        default=None,
        description=(
            "A gt/ folder to load instead of the one beside the sequence: labels made for a recording that is kept "
            "elsewhere or read-only (benchmarks/real_rooms/<name>/gt); its poses are in the recording's world frame."
        ),
    )


class TUMSource(SequenceSource[TUMConfig]):
    """TUM RGB-D folders: timestamp association, groundtruth.txt poses, camera.json intrinsics, gt/ ground truth."""

    name = "tum"
    Config = TUMConfig

    @classmethod
    def example_params(cls) -> dict:
        """For the conformance kit: a tiny synthetic sequence written in the TUM layout."""
        from stratamap.core.paths import scratch_dir
        from stratamap.core.synthetic import SceneSpec, SyntheticWorld
        from stratamap.core.synthetic.writer import write_sequence

        folder = scratch_dir("stratamap-tum-example-") / "seq"
        spec = SceneSpec.model_validate(
            {
                "type": "room",
                "seed": 1,
                "camera": {"width": 160, "height": 120},
                "trajectory": {"type": "orbit", "frames": 6},
            }
        )
        write_sequence(SyntheticWorld(spec), folder)
        return {"path": str(folder)}

    def _intrinsics(self, root: Path) -> tuple[CameraIntrinsics, float]:
        cfg = self.config
        cam_file = root / "camera.json"
        if cam_file.is_file():
            cam = read_json(cam_file)
            intr = intrinsics_from(cam, str(cam_file))
            scale = cfg.depth_scale or cam.get("depth_scale", TUM_DEFAULT["depth_scale"])
            if isinstance(scale, bool) or not isinstance(scale, int | float) or not 0 < scale < float("inf"):
                raise DataError(f"{cam_file}: depth_scale must be a positive number (units per metre), got {scale!r}")
            return intr, float(scale)
        if cfg.intrinsics is not None:
            return intrinsics_from(cfg.intrinsics, "intrinsics"), cfg.depth_scale or TUM_DEFAULT["depth_scale"]
        scale = cfg.depth_scale or TUM_DEFAULT["depth_scale"]
        named = re.search(r"freiburg([123])", root.resolve().name)
        if named:
            camera = named.group(1)
            self.note("intrinsics", {"from": f"TUM Freiburg {camera} (the folder's name)", **TUM_CAMERAS[camera]})
            return CameraIntrinsics.from_dict({**TUM_DEFAULT, **TUM_CAMERAS[camera]}), scale
        self.warn(f"{root}: no camera.json and no intrinsics given; using the TUM Freiburg-1 defaults")
        return CameraIntrinsics.from_dict(TUM_DEFAULT), scale

    def load(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        root = self.sequence_folder()
        if not (root / "rgb.txt").is_file() and (root / "color").is_dir() and (root / "depth").is_dir():
            plugin, layout = ("scannet", "ScanNet") if (root / "pose").is_dir() else ("redwood", "Redwood/Open3D")
            raise DataError(
                f"{root / 'rgb.txt'}: file missing; the folder holds color/ and depth/ as a {layout} sequence "
                f"does: read it with source.plugin={plugin}"
            )
        intr, scale = self._intrinsics(root)
        rgb_rows = read_timestamped_list(root / "rgb.txt", 1, "an image file name")
        depth_rows = read_timestamped_list(root / "depth.txt", 1, "an image file name")
        rgb_t = np.array([t for t, _ in rgb_rows])
        depth_t = np.array([t for t, _ in depth_rows])
        pairs = associate(depth_t, rgb_t, cfg.association_tolerance)
        if not pairs:
            raise DataError(
                f"{root}: no rgb/depth pair within {cfg.association_tolerance} s (rgb.txt "
                f"{rgb_t[0]:.3f}..{rgb_t[-1]:.3f}, "
                f"depth.txt {depth_t[0]:.3f}..{depth_t[-1]:.3f})"
            )
        if len(pairs) < 0.5 * len(depth_rows):
            self.warn(
                f"only {len(pairs)} of {len(depth_rows)} depth images have an rgb image within "
                f"{cfg.association_tolerance} s"
            )
        chosen = select(list(range(len(pairs))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)
        pairs = [pairs[i] for i in chosen]
        times = [float(depth_t[d]) for d, _ in pairs]
        rgb_files = [root / rgb_rows[r][1][0] for _, r in pairs]
        depth_files = [root / depth_rows[d][1][0] for d, _ in pairs]
        shape = (intr.height, intr.width)

        first = read_depth(depth_files[0], scale, shape, cfg.depth_encoding)
        check_depth_scale(first, depth_files[0], scale, encoding=cfg.depth_encoding)
        # A colour camera of more pixels than the depth's (registered to it: the same view) is read
        # at the depth's size, as ScanNet's; another view (another aspect ratio) is an error when read.
        colour = read_image(rgb_files[0]).shape[:2]
        if colour != shape:
            self.note("colour_resampled", {"from": [colour[1], colour[0]], "to": [intr.width, intr.height]})

        def read(k: int):
            depth = read_depth(depth_files[k], scale, shape, cfg.depth_encoding)
            rgb = read_rgb(rgb_files[k], shape, resample=True)
            return rgb, depth

        poses: list = [None] * len(times)
        gt_file = root / "groundtruth.txt"
        if gt_file.is_file():
            gt_times, gt_poses = parse_tum_poses(gt_file)
            poses = interpolate_poses(gt_times, gt_poses, np.array(times), cfg.pose_tolerance)
            missing = sum(p is None for p in poses)
            if missing:
                self.warn(f"{gt_file}: no pose within {cfg.pose_tolerance} s for {missing} of {len(poses)} frames")
        frames = PosedFrames(times, read, poses)
        stream = SensorStream(
            name=root.name,
            intrinsics=intr,
            frames=frames,
            metadata={
                "path": str(root),
                "depth_scale": scale,
                "depth_encoding": cfg.depth_encoding,
                "format": "tum",
            },
        )
        if (root / "laser.txt").is_file():
            stream.laser_scans = read_laser_file(root / "laser.txt")
        gt = None
        gt_dir = root / "gt"
        if cfg.ground_truth_path is not None:
            gt_dir = Path(cfg.ground_truth_path)
            if not gt_dir.is_dir():
                raise DataError(f"{gt_dir}: ground_truth_path is not a folder (expected a gt/ folder with scene.json)")
        if cfg.load_ground_truth and gt_dir.is_dir():
            stamps = [Path(f).stem for f in rgb_files]
            gt = load_ground_truth(gt_dir, stamps, shape)
            traj = gt_dir / "trajectory.txt"
            if traj.is_file():
                tt, tp = parse_tum_poses(traj)
                true = interpolate_poses(tt, tp, np.array(times), cfg.pose_tolerance)
                if all(p is not None for p in true):
                    gt.layout["true_poses"] = [p.tolist() for p in true]
        return stream, frames, gt


@hookimpl
def stratamap_register_sources():
    return [TUMSource]
