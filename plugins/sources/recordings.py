"""Source ``recordings``: several recordings of one place, read by their own sources and fused into one
stream, so that the mappers build one map from all of them.

Each recording's poses must already be in one shared world frame (recordings registered to each
other, or a synthetic walk cut into parts). Frames are read from their recording when a stage reads
them (nothing is loaded up front beyond what each source loads), renumbered in recording order;
laser and LiDAR scans follow in the same order. The ground truth is the first recording's (one
place, one set of objects), with the per-frame labels of all recordings when every one has them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.documents import validation_problems
from stratamap.core.errors import ConfigError, DataError
from stratamap.core.map.sensors import ConcatenatedFrames, SensorStream


class Recording(BaseModel):
    """One recording: a source stage and its parameters."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    plugin: str = Field(description="The source that reads this recording (tum, redwood, synthetic, ...).")
    params: dict[str, Any] = Field(
        default_factory=dict, description="That source's parameters; relative paths are taken from the working folder."
    )


class RecordingsConfig(StageConfig):
    recordings: list[Recording] = Field(
        min_length=1, description="The recordings, in the order their frames are fused; poses in one world frame."
    )


class RecordingsSource(Source[RecordingsConfig]):
    """Several recordings of one place, each read by its own source, as one stream fused into one map."""

    name = "recordings"
    Config = RecordingsConfig
    provides = frozenset({"frames", "ground_truth"})

    @classmethod
    def example_params(cls) -> dict:
        """Two halves of a small synthetic walk."""
        scene = {"camera": {"width": 160, "height": 120}, "trajectory": {"frames": 20}}
        return {
            "recordings": [
                {"plugin": "synthetic", "params": {"scene": scene, "frame_range": [0, 10]}},
                {"plugin": "synthetic", "params": {"scene": scene, "frame_range": [10, 20]}},
            ]
        }

    def _sources(self) -> list[Source]:
        from stratamap.core.registry import default_registry

        registry = default_registry()
        out = []
        for k, rec in enumerate(self.config.recordings):
            key = f"recordings[{k}]"
            if rec.plugin == self.name:
                raise ConfigError([(f"{key}.plugin", "a recording cannot itself be `recordings`")])
            info = registry.stages["sources"].get(rec.plugin)
            if info is None:
                known = ", ".join(sorted(n for n in registry.stages["sources"] if n != self.name))
                raise ConfigError([(f"{key}.plugin", f"no source named {rec.plugin!r}; sources are {known}")])
            try:
                config = info.cls.Config(**rec.params)
            except ValidationError as exc:
                raise ConfigError(validation_problems(exc, ("recordings", k, "params"))) from None
            out.append(info.cls(config))
        return out

    def read(self) -> dict[str, Any]:
        streams, truths = [], []
        for k, source in enumerate(self._sources()):
            source._data = self._data
            result = source.read()
            stream = result.get("frames")
            if not isinstance(stream, SensorStream):
                raise DataError(f"recordings[{k}] ({source.name}): the source gave no stream")
            streams.append(stream)
            truths.append(result.get("ground_truth"))
        first = streams[0]
        for k, stream in enumerate(streams[1:], start=1):
            if (stream.intrinsics is None) != (first.intrinsics is None) or (
                stream.intrinsics is not None and stream.intrinsics != first.intrinsics
            ):
                raise DataError(
                    f"recordings[{k}] ({stream.name!r}): camera intrinsics {stream.intrinsics} differ from "
                    f"recordings[0]'s {first.intrinsics}; one stream needs one camera"
                )
        static = [s.points for s in streams if s.points is not None]
        colors = [s.point_colors for s in streams if s.points is not None]
        fused = SensorStream(
            name="+".join(s.name for s in streams),
            intrinsics=first.intrinsics,
            frames=ConcatenatedFrames([s.frames for s in streams]),
            laser_scans=[scan for s in streams for scan in s.laser_scans],
            lidar_scans=[scan for s in streams for scan in s.lidar_scans],
            points=np.vstack(static) if static else None,
            point_colors=np.vstack(colors) if static and all(c is not None for c in colors) else None,
            metadata={**first.metadata, "recordings": [{"name": s.name, "frames": len(s)} for s in streams]},
        )
        self.note("recordings", [{"name": s.name, "frames": len(s)} for s in streams])
        out: dict[str, Any] = {"frames": fused}
        gt = truths[0]
        if gt is not None:
            if all(t is not None and len(t.frame_labels) == len(s) for t, s in zip(truths, streams, strict=True)):
                labels: Any = ConcatenatedFrames([t.frame_labels for t in truths])
            else:
                labels = []
            layout = dict(gt.layout)
            if all(t is not None and "true_poses" in t.layout for t in truths):
                layout["true_poses"] = [p for t in truths for p in t.layout["true_poses"]]
            else:
                layout.pop("true_poses", None)
            layout.pop("coverage", None)
            out["ground_truth"] = dataclasses.replace(gt, frame_labels=labels, layout=layout)
        return out


@hookimpl
def stratamap_register_sources():
    return [RecordingsSource]
