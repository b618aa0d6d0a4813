"""Completer ``bbox``: each object becomes its gravity-aligned box, the baseline every smarter completer must beat."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Completer, PipelineData, StageConfig, hookimpl
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Completion, OrientedBox
from stratamap.core.parallel import ExecutorConfig, map_tasks

trimesh = lazy_module("trimesh")


class BBoxConfig(StageConfig, ExecutorConfig):
    classes: list[str] | None = Field(default=None, description="Complete only these classes (default: every object).")
    min_points: int = Field(default=10, ge=1, description="Objects with fewer observed points are left uncompleted.")
    workers: int = Field(
        default=1, ge=1, le=64, description="Objects boxed in parallel (threads, or the CPUs of a local Ray instance)."
    )


def box_completion(name: str, box: OrientedBox) -> Completion:
    """The box as a completion: a mesh in the object frame (origin at the bottom center) and its pose."""
    size = np.maximum(box.size, 1e-3)
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_translation((0.0, 0.0, size[2] / 2))
    pose = box.pose
    pose[2, 3] = box.bottom_z
    return Completion(mesh=mesh, pose=pose, completer=name, model_id=None, scale=size, score=1.0)


class BBoxCompleter(Completer[BBoxConfig]):
    """Replaces every object by its gravity-aligned minimal box."""

    name = "bbox"
    Config = BBoxConfig

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        insts = data.map.instances.copy()  # type: ignore[union-attr]
        todo = []
        for inst in insts:
            if cfg.classes is not None and inst.class_name not in cfg.classes:
                continue
            if len(inst.points) < cfg.min_points:
                self.warn(f"object {inst.id} ({inst.class_name}) has {len(inst.points)} points; not completed")
                continue
            todo.append(inst)
        # Only the boxes travel (a Ray task needs no points to build a box).
        mapped = map_tasks(
            box_completion,
            [inst.box for inst in todo],
            self.name,
            executor=cfg.executor,
            workers=cfg.workers,
            ray_address=cfg.ray_address,
        )
        for inst, completion in zip(todo, mapped.results, strict=True):
            inst.completion = completion
        return {"instances": insts}


@hookimpl
def stratamap_register_completers():
    return [BBoxCompleter]
