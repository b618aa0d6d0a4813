"""What every file-based sequence source shares: frame selection, odometry when poses are missing,
gravity alignment, and keeping ground truth in the same world frame as the sensor data."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
from pydantic import Field

from stratamap.core.errors import DataError
from stratamap.core.evaluation.trajectory import ate, rpe
from stratamap.core.geometry.transforms import apply
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.sensors import RGBDFrame, SensorStream, TimedSequence
from stratamap.core.stages import Source, StageConfig
from stratamap.plugins.sources._gravity import (
    GravityAlignment,
    camera_up_hint,
    estimate_alignment,
    sensor_positions,
    stream_planes,
    transform_stream,
)

#: Below this share of its pixels matched to the model, a tracked frame is reported: 640 x 480 frames
#: of a camera moving at walking pace at 30 Hz match 70-90 % (the real align3d office clip: 82-88 %),
#: a 160 x 120 orbit 2.5 degrees a frame 35-41 %; a walk read every 0.25 m matched 16-58 % and lost its way.
WEAK_TRACKING = 0.3
#: Up in the camera's frame (x right, y down) when it is held level.
LEVEL = (0.0, -1.0, 0.0)
#: Ways a camera may be held other than level: which of its axes is then up.
CAMERA_TURNS = (
    ("turned a quarter clockwise (image left up)", (-1.0, 0.0, 0.0)),
    ("turned a quarter anticlockwise (image right up)", (1.0, 0.0, 0.0)),
    ("upside down", (0.0, 1.0, 0.0)),
)
#: The floor found held level stands unless the cameras' heights above it spread (std) more than
#: this (m) and over four times as much as above another way's: a walk carried level spreads 0.01 m
#: above its floor, and 1 m above the walls a turned hint finds (and the reverse when carried turned).
STEADY_HEIGHT = 0.25
#: The floor is sought within this angle (degrees) of the up hint (``estimate_alignment``'s default).
UP_HINT_DEG = 35.0
#: Held level, a camera looking down at a desk or a worktop has its image's up leaning back by its
#: pitch: when no floor lies within UP_HINT_DEG of that hint, it is sought again within this angle (a
#: handheld Kinect over office desks, TUM fr1/rpy, looks down 38 degrees on average).
LOOKING_DOWN_DEG = 60.0


class SequenceConfig(StageConfig):
    path_fields = ("path",)

    path: str = Field(description="Folder of the sequence.")
    max_frames: int | None = Field(default=None, ge=1, description="Read at most this many frames (after `stride`).")
    stride: int = Field(default=1, ge=1, description="Read every n-th frame.")
    first_frame: int = Field(
        default=0,
        ge=0,
        description=(
            "Start at this frame of the sequence (0: the first); `stride` and `max_frames` count from it. Skips a "
            "camera still being set down, or reads a second subsample of a long recording."
        ),
    )
    gravity: Literal["auto", "off"] = Field(
        default="auto",
        description=(
            "auto: find the floor, and re-align the world to z-up with the floor at z = 0 if needed; off: trust the "
            "input."
        ),
    )
    odometry: Literal["auto", "always", "never"] = Field(
        default="auto",
        description=(
            "auto: estimate poses when the input has none; always: estimate them even if given (given poses become "
            "ground truth)."
        ),
    )


class PosedFrames(TimedSequence):
    """Frames read on access; their poses come from a list the source may update (odometry, gravity)."""

    def __init__(
        self,
        timestamps: list[float],
        read: Callable[[int], tuple[np.ndarray, np.ndarray]],
        poses: list[np.ndarray | None],
        cache: int = 3,
    ):
        self.timestamps, self._read, self.poses = timestamps, read, poses
        self._cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._cache_size = cache

    def _item(self, k: int) -> RGBDFrame:
        if k not in self._cache:
            self._cache[k] = self._read(k)
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        rgb, depth = self._cache[k]
        pose = self.poses[k]
        return RGBDFrame(k, self.timestamps[k], rgb, depth, None if pose is None else pose.copy())

    def __deepcopy__(self, memo: dict) -> list:
        import copy

        return [copy.deepcopy(f, memo) for f in self]


def select(
    indices: list[int], stride: int, max_frames: int | None, first_frame: int = 0, where: str = "the sequence"
) -> list[int]:
    """The frames read: from ``first_frame`` on, every ``stride``-th, at most ``max_frames``."""
    if indices and first_frame >= len(indices):
        raise DataError(f"{where}: first_frame is {first_frame}, but it has {len(indices)} frames")
    picked = indices[first_frame::stride]
    return picked[:max_frames] if max_frames else picked


SequenceConfigT = TypeVar("SequenceConfigT", bound=SequenceConfig)


class SequenceSource(Source[SequenceConfigT]):
    """Base of RGB-D sequence sources. Subclasses implement :meth:`load`."""

    Config = SequenceConfig
    provides = frozenset({"frames", "ground_truth"})

    def sequence_folder(self, subfolders: Sequence[str] = (), layout: str = "") -> Path:
        """The configured sequence folder, checked to exist with its ``subfolders`` (``layout``
        says in errors what the format's folder holds)."""
        root = Path(self.config.path).expanduser()
        if not root.is_dir():
            raise DataError(f"{root}: sequence folder not found")
        for sub in subfolders:
            if not (root / sub).is_dir():
                raise DataError(f"{root}: no {sub}/ folder ({layout})")
        return root

    def load(self) -> tuple[SensorStream, PosedFrames, GroundTruth | None]:
        raise NotImplementedError

    def read(self) -> dict[str, Any]:
        return self.finish(*self.load())

    def finish(self, stream: SensorStream, frames: PosedFrames, gt: GroundTruth | None) -> dict[str, Any]:
        """Odometry where poses are missing, gravity alignment, and the layers to return."""
        cfg = self.config
        if len(frames) == 0:
            raise DataError(f"{cfg.path}: no frames to read")
        given = [None if p is None else p.copy() for p in frames.poses]
        missing = sum(p is None for p in given)
        if cfg.odometry == "always" or (cfg.odometry == "auto" and missing):
            self._odometry(stream, frames, given, gt)
        elif missing:
            raise DataError(f"{cfg.path}: {missing} of {len(given)} frames have no pose and odometry is 'never'")
        if cfg.gravity == "auto":
            self._align(stream, frames, gt)
        out: dict[str, Any] = {"frames": stream}
        if gt is not None:
            out["ground_truth"] = gt
        return out

    def _odometry(
        self, stream: SensorStream, frames: PosedFrames, given: list[np.ndarray | None], gt: GroundTruth | None
    ) -> None:
        from stratamap.plugins.sources._odometry import rgbd_frame_to_model

        assert stream.intrinsics is not None
        raw = PosedFrames(frames.timestamps, frames._read, [None] * len(frames))
        fitness: list[float] = []
        tracked: list[int] = []
        empty: list[int] = []

        def with_depth(read: Any) -> Any:
            # A frame that measured nothing (a view down a corridor, a covered lens) has nothing to
            # track: it is left without a pose, which the mappers skip, and the walk goes on past it.
            for frame in read:
                depth = np.asarray(frame.depth)
                if np.any(np.isfinite(depth) & (depth > 0)):
                    tracked.append(frame.index)
                    yield frame
                else:
                    empty.append(frame.index)

        poses = rgbd_frame_to_model(
            with_depth(self.progress(raw, description="RGB-D odometry")), stream.intrinsics, fitness=fitness
        )
        if not poses:
            raise DataError(f"{self.config.path}: none of its {len(frames)} frames has valid depth to track")
        if empty:
            self.warn(
                f"odometry: {len(empty)} of {len(frames)} frames have no valid depth and no pose "
                f"(frames {', '.join(map(str, empty[:12]))}{', ...' if len(empty) > 12 else ''})"
            )
        report: dict[str, Any] = {"method": "open3d frame-to-model RGB-D odometry", "frames": len(poses)}
        if empty:
            report["frames_without_depth"] = empty
        if fitness:
            report["fitness"] = {"min": round(min(fitness), 3), "median": round(float(np.median(fitness)), 3)}
            self._weak_tracking(fitness, tracked[1:])
        reference = given if all(p is not None for p in given) else None
        if reference is None and gt is not None and "true_poses" in gt.layout:
            reference = [np.asarray(p) for p in gt.layout["true_poses"]]
        if reference is not None and len(reference) == len(frames):
            # Express the estimate in the reference world: the first poses coincide.
            reference = [np.asarray(reference[k]) for k in tracked]
            anchor = reference[0] @ np.linalg.inv(poses[0])
            poses = [anchor @ p for p in poses]
            report.update(ate(poses, reference))
            report.update(rpe(poses, reference))
        estimated: list[np.ndarray | None] = [None] * len(frames)
        for k, pose in zip(tracked, poses, strict=True):
            estimated[k] = pose
        frames.poses[:] = estimated
        stream.metadata["odometry"] = report
        self.note("odometry", report)

    def _level_on_floor(self, stream: SensorStream) -> GravityAlignment:
        """The floor found below the camera held level (image up is up), unless the camera was held
        turned: a phone recording upright has image right or left up, a camera mounted upside down
        image down. Held level, such a camera finds a wall within the hint's tolerance, or nothing. The
        floor is where the cameras' heights hardly change: a person or a robot carries a camera at a
        steady height, and a wall's distance changes as the camera walks along the room."""
        planes = stream_planes(stream)
        centres = sensor_positions(stream)
        found: list[tuple[str, GravityAlignment, float]] = []
        level_error: DataError | None = None
        for held, axis in (("level", LEVEL), *CAMERA_TURNS):
            hint = camera_up_hint(stream, axis)
            try:
                alignment = self._floor_below(stream, hint, planes, looking_down=held == "level")
            except DataError as exc:
                level_error = level_error or exc
            else:
                heights = apply(alignment.transform, centres)[:, 2] if len(centres) else np.zeros(1)
                if held == "level" or heights.mean() > 0:
                    found.append((held, alignment, float(heights.std())))
            if hint is None:  # no poses: no camera to turn
                break
        if not found:
            assert level_error is not None
            raise level_error
        held, alignment, spread = min(found, key=lambda f: f[2])
        level = found[0] if found[0][0] == "level" else None
        if level is not None and not (level[2] > STEADY_HEIGHT and spread < level[2] / 4):
            return level[1]
        above_level = (
            f"above the plane found held level, {level[2]:.2f} m" if level is not None else "held level, none was found"
        )
        self.warn(
            f"the floor is found with the camera {held}, as a phone recording upright holds it (the cameras' heights "
            f"above it spread {spread:.2f} m; {above_level}): the map is levelled on it (if it stands on a wall, give "
            "z-up poses and set `gravity: off`)"
        )
        alignment.details["camera_held"] = held
        return alignment

    @staticmethod
    def _floor_below(stream: SensorStream, hint: Any, planes: Any, looking_down: bool) -> GravityAlignment:
        """The floor within UP_HINT_DEG of ``hint``; ``looking_down`` (the camera held level), within
        LOOKING_DOWN_DEG when none lies nearer."""
        try:
            return estimate_alignment(stream, hint, max_angle_deg=UP_HINT_DEG, planes=planes)
        except DataError:
            if not looking_down:
                raise
        return estimate_alignment(stream, hint, max_angle_deg=LOOKING_DOWN_DEG, planes=planes)

    def _weak_tracking(self, fitness: list[float], indices: list[int]) -> None:
        """Warn of frames that matched little of the model built so far: tracked a frame after
        one that was far from it (a fast camera, a large `stride`), odometry may have lost its way.
        ``fitness[k]`` is frame ``indices[k]``'s."""
        weak = [indices[k] for k, f in enumerate(fitness) if f < WEAK_TRACKING]
        if not weak:
            return
        runs: list[list[int]] = []
        for k in weak:
            if runs and k == runs[-1][1] + 1:
                runs[-1][1] = k
            else:
                runs.append([k, k])
        shown = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs[:5]) + (", ..." if len(runs) > 5 else "")
        self.warn(
            f"odometry: {len(weak)} of {len(fitness) + 1} frames matched under {WEAK_TRACKING:.0%} of their pixels "
            f"to the map built so far (frames {shown}): if the camera moved far between frames, their poses are "
            "unreliable (read more frames: a smaller `stride`; or give poses)"
        )

    def _align(self, stream: SensorStream, frames: PosedFrames, gt: GroundTruth | None) -> None:
        alignment = self._level_on_floor(stream)
        self.note("gravity_alignment", alignment.report())
        stream.metadata["gravity_alignment"] = alignment.report()
        if not alignment.realigned:
            return
        t = alignment.transform
        frames.poses[:] = [None if p is None else t @ p for p in frames.poses]
        frames._cache.clear()
        transform_stream(stream, t)
        if gt is not None:
            for obj in gt.objects:
                obj.pose = t @ obj.pose
            gt.layout["world_transform"] = (t @ np.asarray(gt.layout.get("world_transform", np.eye(4)))).tolist()
            if "true_poses" in gt.layout:
                gt.layout["true_poses"] = [(t @ np.asarray(p)).tolist() for p in gt.layout["true_poses"]]
        self.warn(
            f"input was not z-up: re-aligned by {alignment.rotation_deg:.1f} deg, floor moved by "
            f"{alignment.floor_offset_m:+.3f} m to z = 0"
        )


def example_sequence(
    write: Callable[[SensorStream, Path], Any], prefix: str, width: int = 128, height: int = 96, frames: int = 5
) -> Path:
    """A new temporary folder holding a tiny synthetic room seen from an orbit, written by
    ``write(stream, folder)`` in a source's own format: the example input of the conformance kit."""
    from stratamap.core.paths import scratch_dir
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld

    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 1,
            "camera": {"width": width, "height": height},
            "trajectory": {"type": "orbit", "frames": frames},
        }
    )
    folder = scratch_dir(f"stratamap-{prefix}-")
    write(SyntheticWorld(spec).stream(), folder)
    return folder
