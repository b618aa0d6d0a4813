"""Odometry for inputs without poses.

* RGB-D: Open3D's dense RGB-D SLAM model, tracking each frame against a ray cast of the TSDF
  built so far (frame to model), as KinectFusion does.
* LiDAR and point-cloud sequences: KISS-ICP.

Both are deterministic: the same input gives byte-identical poses on every run, so they run on
one thread. With more, results depend on thread scheduling: Open3D's tracking sums its normal
equations in a parallel (TBB) reduction whose order varies; its integration lists the frustum's
blocks in a varying order, and its ray casting, whenever the range-map fragment buffer overflows
(it grows to fit only after a frame that needed more), keeps a varying subset of fragments;
KISS-ICP's registration reduces in parallel too.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Sequence

import numpy as np

from stratamap.core.errors import DataError
from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame
from stratamap.core.parallel import open3d_threads

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")


def open3d_message(exc: Exception) -> str:
    """An Open3D error's own words, without its terminal colours and the C++ function and file
    it came from."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc)).strip()
    return re.sub(r"^\[Open3D Error\] \(.*?\) \S+:\d+: ", "", text).strip().rstrip(".")


def rgbd_frame_to_model(
    frames: Iterable[RGBDFrame],
    intrinsics: CameraIntrinsics,
    voxel_size: float = 0.01,
    depth_max: float = 4.0,
    depth_min: float = 0.2,
    trunc_multiplier: float = 8.0,
    progress: Callable[[int], None] | None = None,
    fitness: list[float] | None = None,
) -> list[np.ndarray]:
    """Camera-to-world poses (the first camera is the world) by frame-to-model tracking. The frames
    are read once, in order, and not kept. Each tracked frame's fitness (the share of its pixels
    that found a match in the model) is appended to ``fitness`` when given."""
    device = o3c.Device("CPU:0")
    K = o3c.Tensor(intrinsics.matrix, o3c.float64)
    model = o3d.t.pipelines.slam.Model(voxel_size, 16, 40000, o3c.Tensor(np.eye(4)), device)
    h, w = intrinsics.height, intrinsics.width
    input_frame = o3d.t.pipelines.slam.Frame(h, w, K, device)
    raycast_frame = o3d.t.pipelines.slam.Frame(h, w, K, device)
    pose = np.eye(4)
    poses = []
    scale = 1000.0
    # Open3D's SLAM model warns that the first raycast frame has no colour yet: nothing the user can act on.
    with open3d_threads(1), o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        for i, frame in enumerate(frames):
            depth = np.clip(np.round(np.nan_to_num(frame.depth) * scale), 0, 65535).astype(np.uint16)
            if not np.any(depth):
                raise DataError(f"odometry: frame {frame.index} has no valid depth; cannot track it")
            input_frame.set_data_from_image("depth", o3d.t.geometry.Image(o3c.Tensor(depth)))
            input_frame.set_data_from_image("color", o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(frame.rgb))))
            if i > 0:
                try:
                    result = model.track_frame_to_model(input_frame, raycast_frame, scale, depth_max, 0.07)
                    pose = pose @ result.transformation.numpy()
                    if fitness is not None:
                        fitness.append(float(result.fitness))
                except RuntimeError as exc:  # Open3D raises when the system is degenerate
                    raise DataError(
                        f"odometry: tracking lost at frame {frame.index} ({open3d_message(exc)}): the camera moved "
                        "far between frames or saw too little structure; read more frames (a smaller `stride`) "
                        "or give poses"
                    ) from None
            poses.append(pose.copy())
            model.update_frame_pose(i, o3c.Tensor(pose))
            model.integrate(input_frame, scale, depth_max, trunc_multiplier)
            model.synthesize_model_frame(raycast_frame, scale, depth_min, depth_max, trunc_multiplier, False)
            if progress is not None:
                progress(i + 1)
    return poses


def lidar_odometry(
    scans: Iterable[np.ndarray], timestamps: Sequence[float] | None = None, max_range: float = 30.0
) -> list[np.ndarray]:
    """Sensor-to-world poses (the first scan is the world) with KISS-ICP."""
    try:
        from kiss_icp.config import KISSConfig
        from kiss_icp.kiss_icp import KissICP
    except ImportError as exc:  # pragma: no cover - kiss-icp is a dependency
        raise DataError("LiDAR odometry needs kiss-icp (pip install kiss-icp)") from exc
    config = KISSConfig()
    config.data.max_range = max_range
    config.data.min_range = 0.3
    config.data.deskew = False
    config.mapping.voxel_size = max_range / 100.0 if max_range > 10 else 0.1
    config.registration.max_num_threads = 1  # its parallel reduction is not deterministic
    odom = KissICP(config=config)
    poses = []
    for k, pts in enumerate(scans):
        pts = np.asarray(pts, dtype=np.float64)
        stamps = np.zeros(len(pts)) if timestamps is None else np.full(len(pts), float(timestamps[k]))
        odom.register_frame(pts, stamps)
        poses.append(np.asarray(odom.last_pose).copy())
    return poses
