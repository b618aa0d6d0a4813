"""Mapper ``physical_check``: make the completed scene physically plausible before export.

The functional-scenes paper checks the matched CAD models for physical conflicts; here every
object is rested on the surface of its supporter from the contact graph, and an object that
overlaps one placed before it moves to the nearest horizontal offset without overlap (the
min-conflict choice; the least overlapping one when none is free within ``max_shift``). What
moved, and any overlap left, goes into the run's notes.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.simulation.physics import resolve_scene


class PhysicalCheckConfig(StageConfig):
    max_shift: float = Field(
        default=0.3, ge=0.0, description="Farthest an object may move sideways to leave an overlap, metres."
    )
    step: float = Field(default=0.01, gt=0.0, description="Radius step of the search for a free offset, metres.")
    directions: int = Field(default=16, ge=4, description="Directions tried on every radius of the search.")
    snap_distance: float = Field(
        default=0.1, ge=0.0, description="Largest gap or sinking closed by resting an object on its supporter, metres."
    )


class PhysicalCheckMapper(Mapper[PhysicalCheckConfig]):
    """Rests objects on their supporters and moves overlapping ones apart (min-conflict)."""

    name = "physical_check"
    Config = PhysicalCheckConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph"})
    provides = frozenset({"instances"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        instances = data.map.instances.copy()  # type: ignore[union-attr]
        floor_z = float(data.notes.get("occupancy", {}).get("floor_z", 0.0))
        result = resolve_scene(
            instances, data.map.contact_graph, floor_z, cfg.max_shift, cfg.step, cfg.directions, cfg.snap_distance
        )
        summary = result.to_dict()
        for key, value in summary.items():
            self.note(key, value)
        if summary["unresolved"]:
            self.warn(f"objects still overlapping after the physical check: {summary['unresolved']}")
        return {"instances": instances}


@hookimpl
def stratamap_register_mappers():
    return [PhysicalCheckMapper]
