"""stratamap-hull: complete each object by the convex hull of its observed points, extruded to its base.

Better than a box for round or tapered objects, and still model-free. Registered through the
``stratamap.completers`` entry point declared in this package's pyproject.toml.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Completer, PipelineData, StageConfig, hookimpl
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Completion

# stratamap imports every installed plugin to list it (`stratamap plugins`) or check a pipeline
# (`stratamap validate`): a heavy library imported here would slow those down for everyone who has
# this plugin installed. As the built-in stages do, import it when the stage first uses it.
trimesh = lazy_module("trimesh")


class HullConfig(StageConfig):
    min_points: int = Field(default=10, ge=4, description="Objects with fewer observed points are left uncompleted.")
    extrude_to_base: bool = Field(
        default=True,
        description="Add the footprint of the points at the object's lowest height, so unseen undersides are filled.",
    )


class HullCompleter(Completer[HullConfig]):
    """Replaces every object by the convex hull of its observed points (extruded to its base)."""

    name = "hull"
    Config = HullConfig

    def complete(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        insts = data.map.instances.copy()  # never modify the input layer in place
        for inst in insts:
            if len(inst.points) < cfg.min_points:
                self.warn(f"object {inst.id} has {len(inst.points)} points; left uncompleted")
                continue
            pose = inst.box.pose
            pose[2, 3] = inst.box.bottom_z
            local = (inst.points - pose[:3, 3]) @ pose[:3, :3]
            if cfg.extrude_to_base:
                base = local.copy()
                base[:, 2] = 0.0
                local = np.vstack([local, base])
            try:
                hull = trimesh.convex.convex_hull(local)
            except Exception as exc:  # degenerate (flat or collinear) observations
                self.warn(f"object {inst.id}: no hull ({exc}); left uncompleted")
                continue
            if hull.volume <= 0:
                continue
            inst.completion = Completion(mesh=hull, pose=pose, completer=self.name, score=1.0)
        return {"instances": insts}


@hookimpl
def stratamap_register_completers():
    return [HullCompleter]
