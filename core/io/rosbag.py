"""Writing ROS 1 / ROS 2 bags with ``rosbags`` (no ROS install): RGB-D streams with camera_info
and tf, or PointCloud2 LiDAR sweeps. Used to export sequences for ROS users and by the tests
that check the ``rosbag`` source reads back what was written."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.sensors import LidarScan, SensorStream

rotations = lazy_module("scipy.spatial.transform")


def _typestore(ros_version: int) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE if ros_version == 2 else Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in ts.types:  # ROS 1's store ships tf/tfMessage only
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return ts


def _writer(path: Path, ros_version: int) -> Any:
    if ros_version == 2:
        from rosbags.rosbag2 import Writer

        return Writer(path, version=8)
    from rosbags.rosbag1 import Writer

    return Writer(path)


def _stamp(ts: Any, t: float, ros_version: int) -> Any:
    Time = ts.types["builtin_interfaces/msg/Time"]
    sec = int(np.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))


def _header(ts: Any, t: float, frame: str, ros_version: int, seq: int = 0) -> Any:
    Header = ts.types["std_msgs/msg/Header"]
    stamp = _stamp(ts, t, ros_version)
    if ros_version == 1:
        return Header(seq=seq, stamp=stamp, frame_id=frame)
    return Header(stamp=stamp, frame_id=frame)


def _serialize(ts: Any, msg: Any, msgtype: str, ros_version: int) -> bytes:
    return ts.serialize_cdr(msg, msgtype) if ros_version == 2 else ts.serialize_ros1(msg, msgtype)


def _tf(ts: Any, t: float, parent: str, child: str, pose: np.ndarray, ros_version: int) -> Any:
    T = ts.types
    q = rotations.Rotation.from_matrix(pose[:3, :3]).as_quat()
    transform = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3])),
        rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
    )
    stamped = T["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, t, parent, ros_version), child_frame_id=child, transform=transform
    )
    return T["tf2_msgs/msg/TFMessage"](transforms=[stamped])


def write_rgbd_bag(
    path: str | Path,
    stream: SensorStream,
    ros_version: int = 2,
    world_frame: str = "map",
    camera_frame: str = "camera_color_optical_frame",
    depth_encoding: str = "16UC1",
    compressed: bool = False,
) -> Path:
    """Depth (``16UC1`` in mm, or ``32FC1`` in metres), color (rgb8), camera_info and tf (world -> camera)
    per frame. ``compressed``: as image_transport records them, ``sensor_msgs/CompressedImage`` on
    ``.../compressed`` (colour as JPEG) and ``.../compressedDepth`` (16UC1 depth as PNG after
    compressed_depth_image_transport's 12-byte header) topics."""
    if depth_encoding not in ("16UC1", "32FC1"):
        raise ValueError(f"depth_encoding must be 16UC1 or 32FC1, got {depth_encoding!r}")
    if compressed and depth_encoding != "16UC1":
        raise ValueError("compressed depth is written as 16UC1")
    path = Path(path)
    ts = _typestore(ros_version)
    T = ts.types
    intr = stream.intrinsics
    assert intr is not None
    with _writer(path, ros_version) as w:
        kw = {"typestore": ts}
        image_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
        depth_topic, color_topic = "/camera/depth/image_raw", "/camera/color/image_raw"
        if compressed:
            depth_topic, color_topic = f"{depth_topic}/compressedDepth", f"{color_topic}/compressed"
        c_depth = w.add_connection(depth_topic, image_type, **kw)
        c_color = w.add_connection(color_topic, image_type, **kw)
        c_info = w.add_connection("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo", **kw)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", **kw)
        for k, frame in enumerate(stream.frames):
            t = float(frame.timestamp) + 1.0
            ns = int(round(t * 1e9))
            header = _header(ts, t, camera_frame, ros_version, k)
            if depth_encoding == "16UC1":
                depth = np.clip(np.round(frame.depth * 1000.0), 0, 65535).astype("<u2")
            else:
                depth = np.asarray(frame.depth, dtype="<f4")
            d_msg = T["sensor_msgs/msg/Image"](
                header=header,
                height=intr.height,
                width=intr.width,
                encoding=depth_encoding,
                is_bigendian=0,
                step=intr.width * depth.dtype.itemsize,
                data=np.frombuffer(depth.tobytes(), np.uint8),
            )
            c_msg = T["sensor_msgs/msg/Image"](
                header=header,
                height=intr.height,
                width=intr.width,
                encoding="rgb8",
                is_bigendian=0,
                step=intr.width * 3,
                data=np.frombuffer(np.ascontiguousarray(frame.rgb).tobytes(), np.uint8),
            )
            if compressed:
                d_msg, c_msg = _compressed_pair(T, header, depth, frame.rgb)
            K = intr.matrix.reshape(-1)
            P = np.c_[intr.matrix, np.zeros(3)].reshape(-1)
            roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            info_kw = (
                {"d": np.zeros(5), "k": K, "r": np.eye(3).reshape(-1), "p": P}
                if ros_version == 2
                else {"D": np.zeros(5), "K": K, "R": np.eye(3).reshape(-1), "P": P}
            )
            i_msg = T["sensor_msgs/msg/CameraInfo"](
                header=header,
                height=intr.height,
                width=intr.width,
                distortion_model="plumb_bob",
                binning_x=0,
                binning_y=0,
                roi=roi,
                **info_kw,
            )
            for conn, msg, mtype in (
                (c_depth, d_msg, image_type),
                (c_color, c_msg, image_type),
                (c_info, i_msg, "sensor_msgs/msg/CameraInfo"),
            ):
                w.write(conn, ns, _serialize(ts, msg, mtype, ros_version))
            if frame.pose is not None:
                w.write(
                    c_tf,
                    ns,
                    _serialize(
                        ts,
                        _tf(ts, t, world_frame, camera_frame, frame.pose, ros_version),
                        "tf2_msgs/msg/TFMessage",
                        ros_version,
                    ),
                )
    return path


def _compressed_pair(T: Any, header: Any, depth_mm: np.ndarray, rgb: np.ndarray) -> tuple[Any, Any]:
    """A depth image (``uint16`` mm) and a colour image as image_transport's compressed messages."""
    import io
    import struct

    from PIL import Image

    png, jpeg = io.BytesIO(), io.BytesIO()
    Image.fromarray(np.asarray(depth_mm, np.uint16)).save(png, format="PNG")
    Image.fromarray(np.ascontiguousarray(rgb)).save(jpeg, format="JPEG", quality=95)
    config = struct.pack("<iff", 0, 0.0, 0.0)  # compressed_depth_image_transport's ConfigHeader (unused for 16UC1)
    Compressed = T["sensor_msgs/msg/CompressedImage"]
    return (
        Compressed(
            header=header, format="16UC1; compressedDepth png", data=np.frombuffer(config + png.getvalue(), np.uint8)
        ),
        Compressed(header=header, format="rgb8; jpeg compressed bgr8", data=np.frombuffer(jpeg.getvalue(), np.uint8)),
    )


def write_lidar_bag(
    path: str | Path,
    scans: list[LidarScan],
    ros_version: int = 1,
    world_frame: str = "map",
    sensor_frame: str = "lidar",
    with_tf: bool = True,
) -> Path:
    """PointCloud2 sweeps (float32 x, y, z) and, optionally, tf poses of the sensor."""
    path = Path(path)
    ts = _typestore(ros_version)
    T = ts.types
    with _writer(path, ros_version) as w:
        kw = {"typestore": ts}
        c_pc = w.add_connection("/lidar/points", "sensor_msgs/msg/PointCloud2", **kw)
        c_tf = w.add_connection("/tf", "tf2_msgs/msg/TFMessage", **kw) if with_tf else None
        fields = [
            T["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")
        ]
        for k, scan in enumerate(scans):
            t = float(scan.timestamp) + 1.0
            ns = int(round(t * 1e9))
            data = np.ascontiguousarray(scan.points.astype("<f4"))
            msg = T["sensor_msgs/msg/PointCloud2"](
                header=_header(ts, t, sensor_frame, ros_version, k),
                height=1,
                width=len(data),
                fields=fields,
                is_bigendian=False,
                point_step=12,
                row_step=12 * len(data),
                data=np.frombuffer(data.tobytes(), np.uint8),
                is_dense=True,
            )
            w.write(c_pc, ns, _serialize(ts, msg, "sensor_msgs/msg/PointCloud2", ros_version))
            if c_tf is not None and scan.pose is not None:
                w.write(
                    c_tf,
                    ns,
                    _serialize(
                        ts,
                        _tf(ts, t, world_frame, sensor_frame, scan.pose, ros_version),
                        "tf2_msgs/msg/TFMessage",
                        ros_version,
                    ),
                )
    return path
