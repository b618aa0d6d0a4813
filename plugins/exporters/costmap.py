"""Exporter ``costmap``: Nav2 cost values from an occupancy layer, with inflation.

Cells: 0 free, 254 lethal (occupied), 253 inscribed (within ``inscribed_radius`` of an obstacle),
255 unknown, and between them Nav2's inflation decay
``cost = 252 * exp(-cost_scaling_factor * (d - inscribed_radius))`` up to ``inflation_radius``.
Written as ``costmap.pgm`` (raw values) + ``costmap.yaml`` (``mode: raw``) for visualization
and as keepout filter masks.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.io.nav2 import costmap_values, write_costmap


class CostmapConfig(StageConfig):
    layer: str = Field(
        default="multimap", description="Occupancy layer to inflate (multimap keeps the robot off chair seats)."
    )
    basename: str = Field(default="costmap", description="File basename in the export folder.")
    inscribed_radius: float = Field(
        default=0.2, ge=0.0, description="Robot's inscribed radius, metres (cells this close to an obstacle are 253)."
    )
    inflation_radius: float = Field(default=0.55, gt=0.0, description="Inflation radius, metres (Nav2's default 0.55).")
    cost_scaling_factor: float = Field(
        default=10.0, gt=0.0, description="Exponential decay rate of the inflation (Nav2's default 10)."
    )


class CostmapExporter(Exporter[CostmapConfig]):
    """Nav2 costmap values (0 free, 253 inscribed, 254 lethal, 255 unknown) with inflation, as PGM + YAML."""

    name = "costmap"
    Config = CostmapConfig
    requires = frozenset({"occupancy"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        grid = data.map.occupancy.get(cfg.layer)
        if grid is None:
            self.warn(f"no occupancy layer {cfg.layer!r} (have: {sorted(data.map.occupancy)}); costmap not written")
            return []
        values = costmap_values(grid, cfg.inscribed_radius, cfg.inflation_radius, cfg.cost_scaling_factor)
        yml, pgm = write_costmap(values, grid, out_dir, cfg.basename)
        return [yml, pgm]


@hookimpl
def stratamap_register_exporters():
    return [CostmapExporter]
