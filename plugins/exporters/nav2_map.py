"""Exporter ``nav2_map``: occupancy layers as ``NAME.yaml`` + ``NAME.pgm`` that nav2_map_server loads.

By default the laser-only ``slam`` layer is written as ``map.*`` and the ``multimap`` as
``multimap.*`` (trinary, occupied_thresh 0.65, free_thresh 0.196, origin, rows flipped). A map with
no free cell is written with a warning: a planner finds no path on it.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.io.nav2 import no_free_space, write_map


class Nav2MapConfig(StageConfig):
    grids: dict[str, str] = Field(
        default_factory=lambda: {"slam": "map", "multimap": "multimap"},
        description="Occupancy layer name -> file basename in the export folder.",
    )


class Nav2MapExporter(Exporter[Nav2MapConfig]):
    """Nav2 map_server files (map.yaml + map.pgm) for the occupancy layers."""

    name = "nav2_map"
    Config = Nav2MapConfig
    requires = frozenset({"occupancy"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        written: list[Path] = []
        for layer, basename in self.config.grids.items():
            grid = data.map.occupancy.get(layer)
            if grid is None:
                self.warn(
                    f"no occupancy layer {layer!r} (have: {sorted(data.map.occupancy)}); {basename}.yaml not written"
                )
                continue
            empty = no_free_space(grid, f"{basename}.pgm (layer {layer!r})")
            if empty:
                self.warn(empty)
            written.extend(write_map(grid, out_dir, basename))
        return written


@hookimpl
def stratamap_register_exporters():
    return [Nav2MapExporter]
