"""Sensor data types. All poses are camera-to-world (or sensor-to-world) SE(3), world z up, metres.

Camera images follow the optical convention (x right, y down, z forward); depth is metric float32
with 0 marking a pixel with no measurement.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole camera model."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("width", "height"):
            object.__setattr__(self, name, int(getattr(self, name)))
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def backproject(self, depth: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points of valid depth pixels and their flat pixel indices."""
        h, w = depth.shape
        vs, us = np.mgrid[0:h:stride, 0:w:stride]
        z = depth[vs, us]
        valid = np.isfinite(z) & (z > 0)
        us, vs, z = us[valid], vs[valid], z[valid]
        pts = np.stack([(us - self.cx) * z / self.fx, (vs - self.cy) * z / self.fy, z], axis=1)
        return pts.astype(np.float64), (vs * w + us).astype(np.int64)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in ("width", "height", "fx", "fy", "cx", "cy")}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CameraIntrinsics:
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]))


@dataclass
class RGBDFrame:
    """One RGB-D image pair. ``depth`` is metric float32 (0 = no measurement)."""

    index: int
    timestamp: float
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32, metres
    pose: np.ndarray | None = None  # (4, 4) camera(optical)-to-world, None when unknown


@dataclass
class LaserScan:
    """A planar 2D laser scan taken at ``pose`` (sensor-to-world; the scan plane is the sensor's x-y)."""

    timestamp: float
    angle_min: float
    angle_increment: float
    ranges: np.ndarray  # (N,) float32 metres; inf = no return
    range_max: float
    pose: np.ndarray | None = None

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))


@dataclass
class LidarScan:
    """A 3D LiDAR sweep: points in the sensor frame."""

    timestamp: float
    points: np.ndarray  # (N, 3) float64
    pose: np.ndarray | None = None
    intensities: np.ndarray | None = None


class TimedSequence(Sequence):
    """Items at ``timestamps``, item ``k`` made by ``_item(k)`` each time it is read (a slice: a list),
    so that a long recording's frames or sweeps are read when used, not held."""

    timestamps: list[float]

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        if k < 0:
            k += len(self)
        if not 0 <= k < len(self):
            raise IndexError(k)
        return self._item(k)

    def _item(self, k: int) -> Any:
        raise NotImplementedError


class LidarSweeps(TimedSequence):
    """LiDAR sweeps read when accessed, not held: a long recording's sweeps outgrow memory (an hour of a
    64-beam LiDAR at 10 Hz is 36,000 sweeps of some 100,000 points). The poses live here, so a source's
    odometry and gravity alignment set them as on a list of scans (``sweeps[k].pose = T``). Each access
    to a sweep's ``points`` reads them again, so ``read`` must be deterministic."""

    def __init__(
        self, timestamps: list[float], read: Callable[[int], np.ndarray], poses: list[np.ndarray | None]
    ) -> None:
        if len(timestamps) != len(poses):
            raise ValueError(f"{len(timestamps)} timestamps for {len(poses)} poses")
        self.timestamps, self.read, self.poses = timestamps, read, poses

    def _item(self, k: int) -> LidarScan:
        return _Sweep(self, k)


class _Sweep(LidarScan):
    """Sweep ``k`` of a :class:`LidarSweeps`: its points are read on access, its pose is the list's."""

    def __init__(self, sweeps: LidarSweeps, k: int) -> None:  # no dataclass __init__: nothing is held
        self._sweeps, self._k = sweeps, k

    @property  # type: ignore[override]
    def timestamp(self) -> float:
        return self._sweeps.timestamps[self._k]

    @property  # type: ignore[override]
    def points(self) -> np.ndarray:
        return self._sweeps.read(self._k)

    @property  # type: ignore[override]
    def pose(self) -> np.ndarray | None:
        return self._sweeps.poses[self._k]

    @pose.setter
    def pose(self, value: np.ndarray | None) -> None:
        self._sweeps.poses[self._k] = value

    @property  # type: ignore[override]
    def intensities(self) -> np.ndarray | None:
        return None


@dataclass
class SensorStream:
    """What a source yields: RGB-D frames, laser and LiDAR scans, and static point clouds.

    ``frames`` may be any sequence (a list, or a lazy loader that reads images on access).
    """

    name: str
    intrinsics: CameraIntrinsics | None = None
    frames: Sequence[RGBDFrame] = field(default_factory=list)
    laser_scans: list[LaserScan] = field(default_factory=list)
    lidar_scans: Sequence[LidarScan] = field(default_factory=list)
    points: np.ndarray | None = None  # static cloud (N, 3), when the input is a point cloud
    point_colors: np.ndarray | None = None  # (N, 3) float 0..1
    #: (N,) which of ``metadata['sensor_positions']`` saw each point of ``points`` (a scanner file's
    #: stations); None when the file does not say.
    point_sensor_ids: np.ndarray | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.frames)


@dataclass
class FrameSegmentation:
    """Per-pixel labels of one frame: class ids (vocabulary ids) and instance ids (0 = none)."""

    frame_index: int
    class_ids: np.ndarray  # (H, W) uint16
    instance_ids: np.ndarray  # (H, W) int32, unique per frame; consistent across frames only if the segmenter tracks
    scores: np.ndarray | None = None  # (H, W) float32 confidence, optional

    @classmethod
    def unlabelled(cls, frame_index: int) -> FrameSegmentation:
        """A frame the segmenter did not label (not a keyframe): mappers fuse its depth, not its labels."""
        return cls(frame_index, np.zeros((0, 0), np.uint16), np.zeros((0, 0), np.int32))

    @property
    def labelled(self) -> bool:
        """False for a frame the segmenter left unlabelled (:meth:`unlabelled`)."""
        return bool(np.asarray(self.class_ids).size)


@dataclass
class FrameLabels:
    """The segmenter's output for a stream, aligned with ``SensorStream.frames``.

    ``frames`` is any sequence: a list, the compressed images of a segmenter that labels every frame
    up front (:class:`PackedFrames`), or images computed on access (:class:`MappedFrames`), so that
    a long stream's label images are never all held at once."""

    segmenter: str
    frames: Sequence[FrameSegmentation] = field(default_factory=list)
    #: True when instance ids are consistent across frames (oracle, trackers) so the mapper may fuse them directly.
    tracked_instances: bool = False

    def __len__(self) -> int:
        return len(self.frames)


class PackedFrames(Sequence):
    """Frame segmentations kept compressed, each unpacked when read: a label image is mostly runs of
    a few ids, so a long stream's labels (1.8 MB a 640 x 480 frame, 4.6 GB for 2,500 frames) take a
    few percent of their size. For a segmenter that labels every frame up front, as ``frames``."""

    def __init__(self, items: Iterable[FrameSegmentation] = ()):
        self._packed: list[tuple[int, list[tuple[str, str, tuple[int, ...], bytes]]]] = []
        for item in items:
            self.append(item)

    def append(self, seg: FrameSegmentation) -> None:
        arrays = []
        for name in ("class_ids", "instance_ids", "scores"):
            value = getattr(seg, name)
            if value is not None:
                value = np.ascontiguousarray(value)
                arrays.append((name, value.dtype.str, value.shape, zlib.compress(value.tobytes(), 1)))
        self._packed.append((seg.frame_index, arrays))

    def __len__(self) -> int:
        return len(self._packed)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        index, arrays = self._packed[k]
        fields = {
            name: np.frombuffer(zlib.decompress(blob), dtype=dtype).reshape(shape).copy()
            for name, dtype, shape, blob in arrays
        }
        return FrameSegmentation(index, **fields)

    def nbytes(self) -> int:
        """Bytes the packed images take."""
        return sum(len(blob) for _, arrays in self._packed for *_, blob in arrays)


class MappedFrames(Sequence):
    """``function(source[k])`` for every ``k``, computed when item ``k`` is read and not kept: a
    per-frame stage (a segmenter) over a lazy stream costs the memory of one frame, not of the stream.
    Reading a frame twice computes it twice, so ``function`` must be deterministic."""

    def __init__(self, source: Sequence[Any], function: Callable[[Any], Any]):
        self.source = source
        self.function = function

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        return self.function(self.source[k])


class _RenumberedFrames(Sequence):
    """A read-on-access sequence whose ``k``-th item is ``_item(k)`` renumbered to ``k``; slices and
    negative indices as a list has them."""

    def _item(self, k: int) -> Any:
        raise NotImplementedError

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        k = int(k)
        if k < 0:
            k += len(self)
        if not 0 <= k < len(self):
            raise IndexError(f"frame {k} out of range ({type(self).__name__} has {len(self)} frames)")
        return renumbered(self._item(k), k)


class ConcatenatedFrames(_RenumberedFrames):
    """Several frame sequences read as one, each item read from its own sequence on access. Items
    that carry an ``index`` (frames, segmentations) are renumbered to their place in the whole, so
    that labels stay aligned with frames."""

    def __init__(self, parts: Sequence[Sequence[Any]]):
        self.parts = list(parts)
        self.starts = np.concatenate([[0], np.cumsum([len(p) for p in self.parts])]).astype(np.int64)

    def __len__(self) -> int:
        return int(self.starts[-1])

    def _item(self, k: int) -> Any:
        part = int(np.searchsorted(self.starts, k, side="right")) - 1
        return self.parts[part][k - int(self.starts[part])]


class FrameWindow(_RenumberedFrames):
    """Items ``start`` to ``stop`` of a sequence, read on access and renumbered from 0 (a part of a
    recording as a recording of its own)."""

    def __init__(self, source: Sequence[Any], start: int, stop: int):
        self.source = source
        self.start, self.stop = max(0, start), min(stop, len(source))

    def __len__(self) -> int:
        return max(0, self.stop - self.start)

    def _item(self, k: int) -> Any:
        return self.source[self.start + k]


def renumbered(item: Any, index: int) -> Any:
    """A frame or segmentation with its index set to ``index`` (other items unchanged)."""
    if isinstance(item, RGBDFrame) and item.index != index:
        return dataclasses.replace(item, index=index)
    if isinstance(item, FrameSegmentation) and item.frame_index != index:
        return dataclasses.replace(item, frame_index=index)
    return item


#: Where a map with no sensor is looked at from: this high (m) over its lowest point, over its centre.
EYE_HEIGHT = 1.5


def sensor_viewpoints(stream: SensorStream | None, points: np.ndarray) -> np.ndarray:
    """Where a map of ``points`` (N, 3) was seen from, (V, 3): the camera positions of posed frames (at
    most about 200, evenly spaced), a scanner file's scan positions (``sensor_positions``: E57), a static
    cloud's sensor (``world_transform``), EYE_HEIGHT over the centre of a cloud with no sensor
    (``metadata['sensor_origin']`` False: a mesh's surface samples, a LAS file), else a point 2 m above
    the map's centre."""
    if stream is not None:
        poses = getattr(stream.frames, "poses", None)
        if poses is None:
            poses = [f.pose for f in stream.frames]
        centres = np.array([np.asarray(pose)[:3, 3] for pose in poses if pose is not None]).reshape(-1, 3)
        if len(centres):
            return centres[:: max(1, len(centres) // 200)]
        if stream.points is not None and stream.metadata.get("sensor_positions"):  # a scanner file's (E57)
            return np.asarray(stream.metadata["sensor_positions"], float).reshape(-1, 3)
        if stream.points is not None and stream.metadata.get("sensor_origin", True):
            transform = np.asarray(stream.metadata.get("world_transform") or np.eye(4))
            return transform[:3, 3][None]
        if stream.points is not None:
            # No sensor (a mesh's surface samples): where someone inside would stand, eye high.
            centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
            return np.array([[centre[0], centre[1], float(points[:, 2].min()) + EYE_HEIGHT]])
    return (points.mean(axis=0) + [0.0, 0.0, 2.0])[None]


def evenly_spaced(count: int, most: int) -> np.ndarray:
    """Up to ``most`` of the indices 0 .. ``count`` - 1, evenly spaced, the first and the last among them."""
    if count <= 0:
        return np.zeros(0, int)
    return np.unique(np.linspace(0, count - 1, min(most, count)).astype(int))


def posed_depth_frames(stream: Any, most: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The depth image (float32, metres) and camera-to-world pose of up to ``most`` of the stream's
    frames, evenly spaced (``evenly_spaced``); a frame without a pose or a depth image, or whose depth
    is not the intrinsics' size, is left out. Nothing for a stream without intrinsics or frames."""
    if stream is None or getattr(stream, "intrinsics", None) is None or not len(getattr(stream, "frames", ())):
        return
    intr = stream.intrinsics
    for k in evenly_spaced(len(stream.frames), most):
        frame = stream.frames[int(k)]
        if frame.pose is None or frame.depth is None:
            continue
        depth = np.asarray(frame.depth, np.float32)
        if depth.shape == (intr.height, intr.width):
            yield depth, np.asarray(frame.pose, float)
