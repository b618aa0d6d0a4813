"""Source ``rosbag``: ROS 1 (.bag) and ROS 2 (folder with metadata.yaml) bags, read with the
``rosbags`` library (no ROS install).

RGB-D: depth (``sensor_msgs/Image``, 16UC1 in millimetres or 32FC1 in metres), color
(rgb8, bgr8, rgba8, bgra8, mono8), or both as image_transport's ``sensor_msgs/CompressedImage``
(colour JPEG or PNG; depth ``compressedDepth`` PNG, 16UC1 or 32FC1's quantized inverse depth),
paired by nearest stamp, intrinsics from ``CameraInfo``, and
camera poses from ``/tf`` (+ ``/tf_static``): the chain from ``world_frame`` to the image's
frame at the image's stamp (image frames are optical frames, as ROS defines them).
LiDAR: ``sensor_msgs/PointCloud2`` sweeps (x, y, z fields), posed from ``/tf`` when available.
Topics are found by message type when not named.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import hookimpl
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.rgbd import associate, check_depth_scale, intrinsics_from
from stratamap.core.lazy import lazy_module
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import LidarSweeps, SensorStream
from stratamap.plugins.sources._sequence import PosedFrames, SequenceConfig, SequenceSource, example_sequence, select

rotations = lazy_module("scipy.spatial.transform")

IMAGE = {"sensor_msgs/msg/Image", "sensor_msgs/Image"}
#: image_transport's compressed images: colour as JPEG or PNG (``.../compressed``), depth as PNG after
#: compressed_depth_image_transport's 12-byte header (``.../compressedDepth``).
COMPRESSED = {"sensor_msgs/msg/CompressedImage", "sensor_msgs/CompressedImage"}
INFO = {"sensor_msgs/msg/CameraInfo", "sensor_msgs/CameraInfo"}
CLOUD = {"sensor_msgs/msg/PointCloud2", "sensor_msgs/PointCloud2"}
TF = {"tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage"}
DEPTH_ENCODINGS = {"16UC1", "mono16", "32FC1"}
COLOR_ENCODINGS = {"rgb8", "bgr8", "rgba8", "bgra8", "mono8"}
PC2_TYPES = {
    1: np.int8,
    2: np.uint8,
    3: np.int16,
    4: np.uint16,
    5: np.int32,
    6: np.uint32,
    7: np.float32,
    8: np.float64,
}


class RosbagConfig(SequenceConfig):
    depth_topic: str | None = Field(
        default=None, description="Depth image topic (default: the first 16UC1/32FC1 image topic)."
    )
    color_topic: str | None = Field(
        default=None, description="Color image topic (default: the first rgb8/bgr8 image topic)."
    )
    camera_info_topic: str | None = Field(default=None, description="CameraInfo topic (default: the first one).")
    pointcloud_topic: str | None = Field(
        default=None, description="PointCloud2 topic for LiDAR input (default: the first one, if no depth images)."
    )
    world_frame: str = Field(
        default="map", description="The tf frame poses are expressed in (falls back to the root of the tf tree)."
    )
    sync_tolerance: float = Field(
        default=0.02, gt=0, description="Max stamp difference between a depth and a color image, seconds."
    )


def stamp_of(msg: Any) -> float:
    st = msg.header.stamp
    return float(st.sec) + float(getattr(st, "nanosec", getattr(st, "nsec", 0))) * 1e-9


def _where(topic: str, msg: Any) -> str:
    try:
        return f"{topic} at t={stamp_of(msg):.6f}"
    except Exception:  # a message without a usable header
        return topic


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(len(magic)) == magic
    except OSError:  # unreadable: the reader says why
        return False


def image_encoding(msg: Any) -> str:
    """A ``sensor_msgs/Image``'s encoding; for a ``CompressedImage``, the encoding its ``format`` names
    ("16UC1; compressedDepth png", "rgb8; jpeg compressed bgr8"), else 16UC1 for compressed depth and
    rgb8 for a bare "jpeg" or "png"."""
    if not hasattr(msg, "format"):
        return msg.encoding
    fmt = str(msg.format)
    first = fmt.split(";")[0].strip()
    if first in DEPTH_ENCODINGS or first in COLOR_ENCODINGS:
        return first
    return "16UC1" if "compresseddepth" in fmt.lower() else "rgb8"


def compressed_array(msg: Any, topic: str) -> np.ndarray:
    """The image of a ``sensor_msgs/CompressedImage``: depth in metres from compressedDepth's PNG (16UC1
    millimetres, or 32FC1 as quantized inverse depth, ``depth = a / (v - b)`` with a and b from its
    header), colour as 8-bit RGB; what cannot be decoded is a DataError naming the topic and stamp."""
    import io
    import struct

    from PIL import Image

    fmt = str(msg.format)
    enc = image_encoding(msg)
    data = bytes(msg.data)
    depth_codec = "compresseddepth" in fmt.lower()
    if depth_codec:
        if "rvl" in fmt.lower():
            raise DataError(f"{_where(topic, msg)}: compressedDepth {fmt!r}: the RVL codec is not read (PNG is)")
        if len(data) < 12:
            raise DataError(f"{_where(topic, msg)}: compressedDepth of {len(data)} bytes; its 12-byte header is cut")
        _, quant_a, quant_b = struct.unpack("<iff", data[:12])
        data = data[12:]
    try:
        image = Image.open(io.BytesIO(data))
        image.load()
    except Exception as exc:  # Pillow raises many types for a damaged image
        raise DataError(f"{_where(topic, msg)}: its {fmt!r} image cannot be decoded ({brief(exc, True)})") from exc
    if enc in DEPTH_ENCODINGS:
        raw = np.asarray(image)
        if raw.ndim != 2 or raw.dtype.kind not in "ui" or raw.dtype.itemsize < 2:
            raise DataError(f"{_where(topic, msg)}: depth {fmt!r} decodes to {raw.dtype} {raw.shape}; expected 16-bit")
        if enc == "32FC1" and depth_codec:
            inverse = raw.astype(np.float64)
            depth = np.zeros(raw.shape, np.float32)
            seen = inverse != 0
            with np.errstate(divide="ignore", invalid="ignore"):
                depth[seen] = quant_a / (inverse[seen] - quant_b)
            depth[~np.isfinite(depth) | (depth < 0)] = 0.0
            return depth
        return raw.astype(np.float32) / 1000.0
    return np.asarray(image.convert("RGB"))


def image_array(msg: Any, topic: str) -> np.ndarray:
    """The image of a ``sensor_msgs/Image``: depth in metres (16UC1 millimetres or 32FC1 metres), color as
    8-bit RGB; a size, step or data length that disagree is a DataError naming the topic and stamp. A
    ``CompressedImage`` is decoded (:func:`compressed_array`)."""
    if hasattr(msg, "format"):
        return compressed_array(msg, topic)
    enc = msg.encoding
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "16UC1": 2, "mono16": 2, "32FC1": 4}.get(enc)
    if channels is None:
        raise DataError(
            f"{_where(topic, msg)}: unsupported image encoding {enc!r} (depth: 16UC1, 32FC1; color: "
            f"{', '.join(sorted(COLOR_ENCODINGS))})"
        )
    row = w * channels  # bytes of pixels per row
    if h <= 0 or w <= 0 or step < row or len(data) != h * step:
        raise DataError(
            f"{_where(topic, msg)}: a {w}x{h} {enc} image with step {step} needs {h * max(step, row)} bytes and a step "
            f"of at least {row}; the message holds {len(data)} bytes"
        )
    rows = data.reshape(h, step)[:, :row]
    if enc in ("16UC1", "mono16"):
        arr = np.ascontiguousarray(rows).view(">u2" if msg.is_bigendian else "<u2")
        return arr.astype(np.float32) / 1000.0
    if enc == "32FC1":
        arr = np.ascontiguousarray(rows).view(">f4" if msg.is_bigendian else "<f4").astype(np.float32)
        arr[~np.isfinite(arr) | (arr < 0)] = 0.0
        valid = arr[arr > 0]
        if valid.size and np.median(valid) > 100:
            raise DataError(
                f"{_where(topic, msg)}: 32FC1 depth with median {np.median(valid):.0f}: looks like millimetres; 32FC1 "
                "depth is in metres (16UC1 is millimetres)"
            )
        return arr
    arr = rows.reshape(h, w, channels)
    if enc.startswith("bgr"):
        arr = arr[..., [2, 1, 0]]
    elif enc == "mono8":
        arr = np.repeat(arr, 3, axis=2)
    return np.ascontiguousarray(arr[..., :3])


def cloud_array(msg: Any, topic: str) -> np.ndarray:
    """Finite x, y, z of a ``sensor_msgs/PointCloud2`` (NaN marks no return); fields, offsets and the data
    length are checked against ``point_step``, ``width`` and ``height``."""
    fields = {f.name: f for f in msg.fields}
    where = _where(topic, msg)
    if not {"x", "y", "z"} <= set(fields):
        raise DataError(f"{where}: PointCloud2 without x, y, z fields (has {sorted(fields)})")
    step, n = int(msg.point_step), int(msg.width) * int(msg.height)
    for k in "xyz":
        f = fields[k]
        if f.datatype not in PC2_TYPES:
            raise DataError(f"{where}: field {k!r} has datatype {f.datatype}; expected 1..8 (INT8 .. FLOAT64)")
        if f.offset < 0 or f.offset + np.dtype(PC2_TYPES[f.datatype]).itemsize > step:
            raise DataError(f"{where}: field {k!r} at offset {f.offset} does not fit in point_step {step}")
    if n < 0 or len(msg.data) < n * step:
        raise DataError(
            f"{where}: {msg.width}x{msg.height} points of {step} bytes need {n * step} bytes; the message holds "
            f"{len(msg.data)}"
        )
    endian = ">" if msg.is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": ["x", "y", "z"],
            "formats": [np.dtype(PC2_TYPES[fields[k].datatype]).newbyteorder(endian) for k in "xyz"],
            "offsets": [fields[k].offset for k in "xyz"],
            "itemsize": step,
        }
    )
    raw = np.frombuffer(bytes(msg.data), dtype=dtype, count=n)
    pts = np.stack([raw["x"], raw["y"], raw["z"]], 1).astype(np.float64)
    return pts[np.all(np.isfinite(pts), axis=1)]


def transform_matrix(tf: Any) -> np.ndarray:
    t, q = tf.transform.translation, tf.transform.rotation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    trans = np.array([t.x, t.y, t.z], dtype=np.float64)
    if not np.all(np.isfinite(quat)) or not np.all(np.isfinite(trans)) or np.linalg.norm(quat) < 1e-6:
        raise DataError(
            f"tf {tf.header.frame_id!r} -> {tf.child_frame_id!r}: not a valid transform (translation {trans.tolist()}, "
            f"quaternion {quat.tolist()})"
        )
    pose = np.eye(4)
    pose[:3, :3] = rotations.Rotation.from_quat(quat / np.linalg.norm(quat)).as_matrix()
    pose[:3, 3] = trans
    return pose


@dataclass
class TfBuffer:
    """Transforms parent -> child over time; lookups take the latest at or before a stamp."""

    edges: dict[str, list[tuple[float, str, np.ndarray]]]  # child -> [(stamp, parent, T_parent_child)]

    def parent_at(self, child: str, t: float) -> tuple[str, np.ndarray] | None:
        entries = self.edges.get(child)
        if not entries:
            return None
        best = None
        for stamp, parent, T in entries:
            if stamp <= t + 1e-9 or stamp == 0.0:  # stamp 0: static transforms
                best = (parent, T)
        if best is None:
            best = (entries[0][1], entries[0][2])
        return best

    def lookup(self, world: str, frame: str, t: float) -> np.ndarray | None:
        pose = np.eye(4)
        node = frame
        for _ in range(64):
            if node == world:
                return pose
            step = self.parent_at(node, t)
            if step is None:
                return pose if world == "" else None
            parent, T = step
            pose = T @ pose
            node = parent
        return None

    def roots(self) -> set[str]:
        children = set(self.edges)
        parents = {p for entries in self.edges.values() for _, p, _ in entries}
        return parents - children


@dataclass(frozen=True)
class MessageRef:
    """Where an image or a sweep lies in its bag, so that it is read when needed rather than held: a long
    recording's images do not fit in memory (2,500 raw 640 x 480 RGB-D pairs are 3.8 GB)."""

    connection: int  # index in the reader's connections
    bag_time: int  # the bag's record time, ns
    nth: int  # among the connection's messages recorded at that time
    frame_id: str
    encoding: str = ""  # images: as image_encoding() reads it


class BagMessages:
    """One bag's reader, opened on first use and kept open (the source indexes the bag with it, then
    reads each message again by its :class:`MessageRef`), closed when no longer referenced."""

    def __init__(self, path: Path):
        self.path = path
        self._reader: Any = None
        self._finalizer: Any = None

    def get(self, ref: MessageRef) -> Any:
        reader = self.reader()
        conn = reader.connections[ref.connection]
        records = reader.messages(connections=[conn], start=ref.bag_time, stop=ref.bag_time + 1)
        try:
            for k, (_, _, raw) in enumerate(records):
                if k == ref.nth:
                    return reader.deserialize(raw, conn.msgtype)
        except Exception as exc:  # corrupt chunk or record: rosbags raises many types
            raise DataError(f"{self.path}: corrupt bag: cannot read {conn.topic} again ({brief(exc, True)})") from exc
        raise DataError(f"{self.path}: a message on {conn.topic} has gone from the bag since it was indexed")

    def reader(self) -> Any:
        """The open ``rosbags`` reader; a file it cannot open is a DataError."""
        if self._reader is None:
            import weakref

            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore

            try:  # the constructor reads a ROS 2 bag's metadata.yaml: a folder without one fails there
                reader = AnyReader([self.path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
                reader.open()
            except Exception as exc:  # rosbags raises several reader errors
                raise DataError(f"{self.path}: cannot open as a ROS 1 or ROS 2 bag ({brief(exc, True)})") from exc
            self._reader = reader
            self._finalizer = weakref.finalize(self, reader.close)
        return self._reader

    def close(self) -> None:
        if self._finalizer is not None:
            try:
                self._finalizer()
            except Exception:  # closing a half-read corrupt bag may fail again; the first error is the one to report
                pass
            self._reader = self._finalizer = None


class RosbagSource(SequenceSource[RosbagConfig]):
    """ROS 1 and ROS 2 bags without ROS: depth + color + camera_info + tf, or PointCloud2 for LiDAR."""

    name = "rosbag"
    Config = RosbagConfig

    @classmethod
    def example_params(cls) -> dict:
        from stratamap.core.io.rosbag import write_rgbd_bag

        folder = example_sequence(
            lambda stream, root: write_rgbd_bag(root / "bag", stream, ros_version=2), "bag", 96, 72
        )
        return {"path": str(folder / "bag"), "world_frame": "map"}

    def _read_bag(self, path: Path) -> dict[str, Any]:
        cfg = self.config
        if not path.exists():
            raise DataError(f"{path}: bag not found")
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            raise DataError(f"{path}: a folder without metadata.yaml, so no ROS 2 bag (a ROS 1 bag is one .bag file)")
        if path.is_file() and path.suffix != ".bag" and _starts_with(path, b"#ROSBAG V2.0\n"):
            # rosbags tells a ROS 1 bag by its name: this one would be "Unrecognized storage format ''"
            raise DataError(f"{path}: a ROS 1 bag, whose file name must end in .bag to be read: rename it")
        messages = BagMessages(path)
        reader = messages.reader()
        indexed = False
        by_type: dict[str, list[str]] = {}
        images, infos, clouds = [], [], []
        edges: dict[str, list[tuple[float, str, np.ndarray]]] = {}
        try:
            for c in reader.connections:
                by_type.setdefault(c.msgtype, []).append(c.topic)
            wanted = {c.topic for c in reader.connections if c.msgtype in IMAGE | COMPRESSED | INFO | CLOUD | TF}
            conns = [c for c in reader.connections if c.topic in wanted]
            index = {id(c): k for k, c in enumerate(reader.connections)}
            last_time = -1
            seen_at_time: dict[int, int] = {}  # messages so far per connection at one record time
            for conn, bag_time, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if bag_time != last_time:
                    last_time, seen_at_time = bag_time, {}
                number = index[id(conn)]
                nth = seen_at_time[number] = seen_at_time.get(number, -1) + 1
                if conn.msgtype in TF:
                    static = conn.topic.endswith("tf_static")
                    for tf in msg.transforms:
                        child = tf.child_frame_id.lstrip("/")
                        edges.setdefault(child, []).append(
                            (0.0 if static else stamp_of(tf), tf.header.frame_id.lstrip("/"), transform_matrix(tf))
                        )
                elif conn.msgtype in IMAGE | COMPRESSED:
                    ref = MessageRef(number, bag_time, nth, msg.header.frame_id, image_encoding(msg))
                    images.append((conn.topic, stamp_of(msg), ref))
                elif conn.msgtype in INFO:
                    infos.append((conn.topic, msg))
                elif conn.msgtype in CLOUD:
                    clouds.append((conn.topic, stamp_of(msg), MessageRef(number, bag_time, nth, msg.header.frame_id)))
        except DataError as exc:
            raise DataError(f"{path}: {brief(exc)}") from exc
        except Exception as exc:  # corrupt chunks, records or messages: rosbags and its deserializers raise many types
            raise DataError(f"{path}: corrupt bag: cannot read its messages ({brief(exc, True)})") from exc
        else:
            indexed = True
        finally:
            if not indexed:
                messages.close()
        for v in edges.values():
            v.sort(key=lambda e: e[0])
        topics = {t: m for m, ts in by_type.items() for t in ts}
        for param, kinds in (
            ("depth_topic", IMAGE | COMPRESSED),
            ("color_topic", IMAGE | COMPRESSED),
            ("camera_info_topic", INFO),
            ("pointcloud_topic", CLOUD),
        ):
            topic = getattr(cfg, param)
            if topic is None:
                continue
            if topic not in topics:
                raise DataError(f"{path}: no topic {topic!r} (asked for by {param}); the bag has {sorted(topics)}")
            if topics[topic] not in kinds:
                raise DataError(
                    f"{path}: topic {topic!r} ({param}) carries {topics[topic]}, expected "
                    f"{' or '.join(sorted(k for k in kinds if '/msg/' in k))}"
                )
        return {
            "types": by_type,
            "images": images,
            "infos": infos,
            "clouds": clouds,
            "tf": TfBuffer(edges),
            "messages": messages,
        }

    @staticmethod
    def _by_stamp(path: Path, topic: str, msgs: list[tuple[float, Any]]) -> list[tuple[float, Any]]:
        """Messages of one topic in stamp order; two messages with one stamp are an error, not a silent pick."""
        msgs = sorted(msgs, key=lambda m: m[0])
        for (a, _), (b, _) in zip(msgs, msgs[1:]):
            if a == b:
                raise DataError(
                    f"{path}: two messages on {topic!r} have the same header stamp {a:.9f} (duplicated messages, or a "
                    "driver that does not stamp its images?)"
                )
        return msgs

    def load(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        path = Path(cfg.path).expanduser()
        bag = self._read_bag(path)
        images = bag["images"]
        encodings: dict[str, str] = {}
        for topic, _, ref in images:
            encodings.setdefault(topic, ref.encoding)
        depth_topic = cfg.depth_topic or next((t for t, e in encodings.items() if e in DEPTH_ENCODINGS), None)
        color_topic = cfg.color_topic or next((t for t, e in encodings.items() if e in COLOR_ENCODINGS), None)
        tf: TfBuffer = bag["tf"]
        world = (
            cfg.world_frame
            if cfg.world_frame in tf.roots() or cfg.world_frame in tf.edges
            else (sorted(tf.roots()) or [""])[0]
        )
        if depth_topic is None:
            return self._load_lidar(path, bag, tf, world)
        if depth_topic not in encodings:
            raise DataError(f"{path}: no messages on depth topic {depth_topic!r}; image topics: {sorted(encodings)}")
        if encodings[depth_topic] not in DEPTH_ENCODINGS:
            raise DataError(
                f"{path}: depth topic {depth_topic!r} has encoding {encodings[depth_topic]!r}; expected "
                f"{', '.join(sorted(DEPTH_ENCODINGS))}"
            )
        if color_topic is None:
            raise DataError(f"{path}: no color image topic (rgb8/bgr8/...) to pair with {depth_topic!r}")
        if color_topic not in encodings:
            raise DataError(f"{path}: no messages on color topic {color_topic!r}; image topics: {sorted(encodings)}")
        infos = bag["infos"]
        info_topic = cfg.camera_info_topic or (infos[0][0] if infos else None)
        info = next((m for t, m in infos if t == info_topic), None)
        if info is None:
            raise DataError(
                f"{path}: no CameraInfo message{f' on {info_topic!r}' if info_topic else ''} (topics: "
                f"{sorted(t for ts in bag['types'].values() for t in ts)}); intrinsics are needed"
            )
        try:
            k = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=float).reshape(3, 3)  # ROS 2 / ROS 1 names
        except ValueError:
            raise DataError(f"{path}: CameraInfo on {info_topic!r} has no 3x3 K matrix") from None
        intr = intrinsics_from(
            {"width": info.width, "height": info.height, "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2]},
            f"{path}: CameraInfo on {info_topic!r}",
        )
        depth_msgs = self._by_stamp(path, depth_topic, [(t, m) for tp, t, m in images if tp == depth_topic])
        color_msgs = self._by_stamp(path, color_topic, [(t, m) for tp, t, m in images if tp == color_topic])
        pairs = associate(
            np.array([t for t, _ in depth_msgs]), np.array([t for t, _ in color_msgs]), cfg.sync_tolerance
        )
        if not pairs:
            raise DataError(f"{path}: no depth/color pair within {cfg.sync_tolerance} s")
        if len(pairs) < 0.5 * len(depth_msgs):
            self.warn(
                f"only {len(pairs)} of {len(depth_msgs)} depth images have a color image within {cfg.sync_tolerance} s"
            )
        pairs = [
            pairs[i] for i in select(list(range(len(pairs))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)
        ]
        times = [depth_msgs[d][0] for d, _ in pairs]
        shape = (intr.height, intr.width)

        messages: BagMessages = bag["messages"]

        def read(k: int):
            d_msg, c_msg = messages.get(depth_msgs[pairs[k][0]][1]), messages.get(color_msgs[pairs[k][1]][1])
            try:
                depth = image_array(d_msg, depth_topic)
                rgb = image_array(c_msg, color_topic)
            except DataError as exc:
                raise DataError(f"{path}: {exc}") from exc
            if depth.shape != shape or rgb.shape[:2] != shape:
                raise DataError(
                    f"{path}: image size {depth.shape[1]}x{depth.shape[0]} (depth) / {rgb.shape[1]}x{rgb.shape[0]} "
                    f"(color) differs from CameraInfo's {shape[1]}x{shape[0]} (image size mismatch)"
                )
            return rgb, depth

        first_depth = read(0)[1]
        check_depth_scale(
            first_depth, Path(f"{path}:{depth_topic}"), 1000.0 if encodings[depth_topic] != "32FC1" else 1.0
        )
        frame_id = depth_msgs[0][1].frame_id.lstrip("/")
        poses = [tf.lookup(world, frame_id, t) for t in times] if tf.edges else [None] * len(times)
        frames = PosedFrames(times, read, poses)
        stream = SensorStream(
            name=path.stem,
            intrinsics=intr,
            frames=frames,
            metadata={
                "path": str(path),
                "format": "rosbag",
                "world_frame": world,
                "depth_topic": depth_topic,
                "color_topic": color_topic,
            },
        )
        return stream, frames, None

    def _load_lidar(
        self, path: Path, bag: dict, tf: TfBuffer, world: str
    ) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        cfg = self.config
        clouds = bag["clouds"]
        topic = cfg.pointcloud_topic or (clouds[0][0] if clouds else None)
        sweeps = [(t, m) for tp, t, m in clouds if tp == topic]
        if not sweeps:
            topics = sorted(t for ts in bag["types"].values() for t in ts)
            raise DataError(f"{path}: no depth images and no PointCloud2 messages (topics: {topics})")
        sweeps = self._by_stamp(path, topic, sweeps)  # type: ignore[arg-type]
        sweeps = [
            sweeps[i] for i in select(list(range(len(sweeps))), cfg.stride, cfg.max_frames, cfg.first_frame, cfg.path)
        ]
        messages: BagMessages = bag["messages"]

        def read(k: int) -> np.ndarray:
            try:
                return cloud_array(messages.get(sweeps[k][1]), topic)  # type: ignore[arg-type]
            except DataError as exc:
                raise DataError(f"{path}: {exc}") from exc

        poses = [tf.lookup(world, ref.frame_id.lstrip("/"), t) if tf.edges else None for t, ref in sweeps]
        scans = LidarSweeps([t for t, _ in sweeps], read, poses)
        empty = sum(len(read(k)) == 0 for k in range(len(scans)))  # every sweep read once here: bad data fails now
        if empty == len(scans):
            raise DataError(f"{path}: the PointCloud2 messages on {topic!r} hold no finite points")
        if empty:
            self.warn(f"{path}: {empty} of {len(scans)} sweeps on {topic!r} hold no finite points")
        if any(pose is None for pose in poses):
            if cfg.odometry == "never":
                raise DataError(f"{path}: LiDAR sweeps without tf poses and odometry is 'never'")
            from stratamap.plugins.sources._odometry import lidar_odometry

            scans.poses[:] = lidar_odometry((read(k) for k in range(len(scans))), scans.timestamps)
            self.note("odometry", {"method": "kiss-icp", "sweeps": len(scans)})
        stream = SensorStream(
            name=path.stem,
            lidar_scans=scans,
            metadata={"path": str(path), "format": "rosbag", "pointcloud_topic": topic},
        )
        return stream, PosedFrames([], lambda k: (np.zeros(0), np.zeros(0)), []), None

    def read(self) -> dict[str, Any]:
        cfg = self.config
        stream, frames, gt = self.load()
        if len(frames) == 0:  # LiDAR input: poses settled in load, gravity from the sweeps
            if cfg.gravity == "auto" and stream.lidar_scans:
                from stratamap.core.geometry.transforms import apply
                from stratamap.plugins.sources._gravity import estimate_alignment, transform_stream

                probe = SensorStream(
                    name=stream.name,
                    points=np.vstack([apply(s.pose, s.points) for s in stream.lidar_scans[:10]]),
                    metadata={"path": stream.metadata["path"]},  # errors name the bag
                )
                alignment = estimate_alignment(probe, up_hint=np.array([0.0, 0.0, 1.0]))
                self.note("gravity_alignment", alignment.report())
                if alignment.realigned:
                    transform_stream(stream, alignment.transform)
            return {"frames": stream}
        return self.finish(stream, frames, gt)


@hookimpl
def stratamap_register_sources():
    return [RosbagSource]
