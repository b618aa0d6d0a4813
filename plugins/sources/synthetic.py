"""Source ``synthetic``: a procedural room rendered as RGB-D frames, with full ground truth."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from stratamap.core import Source, StageConfig, hookimpl
from stratamap.core.synthetic import CameraSpec, SceneSpec, generate_sequence


class SyntheticConfig(StageConfig):
    scene: SceneSpec = Field(default_factory=SceneSpec, description="The procedural scene (room size, object counts, seed).")
    scene_file: str | None = Field(default=None, description="A scene spec YAML file; when set it replaces `scene`.")
    camera: CameraSpec = Field(default_factory=CameraSpec, description="The simulated RGB-D camera.")
    frames: int = Field(default=40, ge=1, le=100000, description="Number of frames rendered along the camera path.")


class SyntheticSource(Source):
    """Procedural room rendered by ray casting, with per-pixel labels, object meshes and poses as ground truth."""

    name = "synthetic"
    Config = SyntheticConfig
    provides = frozenset({"frames", "ground_truth"})

    def read(self) -> dict[str, Any]:
        cfg: SyntheticConfig = self.config  # type: ignore[assignment]
        spec = SceneSpec.from_yaml(cfg.scene_file) if cfg.scene_file else cfg.scene
        seq = generate_sequence(spec, cfg.camera, cfg.frames)
        self.note("scene", {"objects": len(seq.ground_truth.objects), "frames": len(seq.stream)})
        return {"frames": seq.stream, "ground_truth": seq.ground_truth}


@hookimpl
def stratamap_register_sources():
    return [SyntheticSource]
