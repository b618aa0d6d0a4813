"""Exporter ``costmap``: Nav2 cost values from an occupancy layer, with inflation.

Cells: 0 free, 254 lethal (occupied), 253 inscribed (within ``inflation.inscribed_radius`` of an
obstacle), 255 unknown, and between them Nav2's inflation decay
``cost = 252 * exp(-cost_scaling_factor * (d - inscribed_radius))`` up to ``inflation_radius``.
Written as ``costmap.pgm`` (raw values) + ``costmap.yaml`` (``mode: raw``) for visualization
and as keepout filter masks. A layer with no free cell is written with a warning.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.io.nav2 import costmap_values, no_free_space, write_costmap
from stratamap.core.stages import warn_renamed
from stratamap.plugins.exporters._sections import (
    RENAMED_INFLATION,
    Inflation,
    inflation_section,
)


class CostmapConfig(StageConfig):
    layer: str = Field(
        default="multimap", description="Occupancy layer to inflate (multimap keeps the robot off chair seats)."
    )
    basename: str = Field(default="costmap", description="File basename in the export folder.")
    inflation: Inflation = inflation_section()

    renamed: ClassVar[Mapping[str, str]] = RENAMED_INFLATION


class CostmapExporter(Exporter[CostmapConfig]):
    """Nav2 costmap values (0 free, 253 inscribed, 254 lethal, 255 unknown) with inflation, as PGM + YAML."""

    name = "costmap"
    Config = CostmapConfig
    requires = frozenset({"occupancy"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        warn_renamed(self)
        grid = data.map.occupancy.get(cfg.layer)
        if grid is None:
            self.warn(f"no occupancy layer {cfg.layer!r} (have: {sorted(data.map.occupancy)}); costmap not written")
            return []
        empty = no_free_space(grid, f"{cfg.basename}.pgm (layer {cfg.layer!r})")
        if empty:
            self.warn(empty)
        inflation = cfg.inflation
        values = costmap_values(
            grid, inflation.inscribed_radius, inflation.inflation_radius, inflation.cost_scaling_factor
        )
        yml, pgm = write_costmap(values, grid, out_dir, cfg.basename)
        return [yml, pgm]


@hookimpl
def stratamap_register_exporters():
    return [CostmapExporter]
