"""Source ``synthetic``: a procedural scene rendered as RGB-D frames (plus laser and LiDAR), with full ground truth."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from pydantic import Field

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.errors import ConfigError
from stratamap.core.map.sensors import FrameWindow
from stratamap.core.synthetic import SceneSpec, generate_sequence


class SyntheticConfig(StageConfig):
    path_fields = ("scene_file",)

    scene: SceneSpec = Field(
        default_factory=SceneSpec, description="The procedural scene: type, objects, seed, sensors, trajectory, noise."
    )
    scene_file: str | None = Field(
        default=None, description="A scene spec YAML file (configs/scenes/*.yaml); when set it replaces `scene`."
    )
    frames: int | None = Field(
        default=None, ge=1, le=100000, description="Override the number of frames of the trajectory."
    )
    seed: int | None = Field(default=None, description="Override the scene's seed.")
    frame_range: tuple[int, int] | None = Field(
        default=None,
        description=(
            "Only frames [start, stop) of the trajectory, renumbered from 0: a part of the walk as a recording of "
            "its own (the `recordings` source fuses several into one map)."
        ),
    )


class SyntheticSource(Source[SyntheticConfig]):
    """Procedural scene rendered by ray casting, with per-pixel labels, object meshes, poses and support as ground truth."""  # noqa: E501 (one-line summary shown by `stratamap plugins`)

    name = "synthetic"
    Config = SyntheticConfig
    provides = frozenset({"frames", "ground_truth"})

    @classmethod
    def example_params(cls) -> dict:
        """A small scene for the conformance kit (the default renders 120 frames at 640 x 480)."""
        return {"scene": {"camera": {"width": 160, "height": 120}, "trajectory": {"frames": 20}}}

    def spec(self) -> SceneSpec:
        cfg = self.config
        spec = SceneSpec.from_yaml(self._resolve(cfg.scene_file)) if cfg.scene_file else cfg.scene
        updates: dict[str, Any] = {}
        if cfg.seed is not None:
            updates["seed"] = cfg.seed
        if cfg.frames is not None:
            updates["trajectory"] = spec.trajectory.model_copy(update={"frames": cfg.frames})
        return spec.model_copy(update=updates) if updates else spec

    @staticmethod
    def _resolve(path: str) -> Path:
        """A relative scene file is looked up in the working directory, then in the stratamap checkout."""
        p = Path(path).expanduser()
        if p.is_absolute() or p.is_file():
            return p
        from stratamap.core.paths import repo_root

        candidate = repo_root() / p
        return candidate if candidate.is_file() else p

    def read(self) -> dict[str, Any]:
        seq = generate_sequence(self.spec())
        stream, gt = seq.stream, seq.ground_truth
        if self.config.frame_range is not None:
            start, stop = self.config.frame_range
            if not 0 <= start < stop <= len(stream):
                raise ConfigError(
                    [("frame_range", f"[{start}, {stop}) is not a range of the trajectory's {len(stream)} frames")]
                )
            stream = dataclasses.replace(
                stream,
                frames=FrameWindow(stream.frames, start, stop),
                laser_scans=stream.laser_scans[start:stop],
                lidar_scans=stream.lidar_scans[start:stop],
            )
            layout = dict(gt.layout)
            layout["true_poses"] = layout["true_poses"][start:stop]
            layout.pop("coverage", None)  # measured over the whole trajectory
            gt = dataclasses.replace(gt, frame_labels=FrameWindow(gt.frame_labels, start, stop), layout=layout)
        self.note("scene", {"objects": len(gt.objects), "frames": len(stream), "skipped": seq.scene.skipped})
        if "coverage" in gt.layout:
            self.note("coverage", {k: v for k, v in gt.layout["coverage"].items() if k != "per_object"})
        return {"frames": stream, "ground_truth": gt}


@hookimpl
def stratamap_register_sources():
    return [SyntheticSource]
