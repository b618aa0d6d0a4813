"""Exporter ``costmap``: Nav2 cost values from an occupancy layer, with inflation.

Cells: 0 free, 254 lethal (occupied), 253 inscribed (within ``inscribed_radius`` of an obstacle),
255 unknown, and between them Nav2's inflation decay
``cost = 252 * exp(-cost_scaling_factor * (d - inscribed_radius))`` up to ``inflation_radius``.
Written as ``costmap.pgm`` (raw values) + ``costmap.yaml`` (``mode: raw``) for visualization
and as keepout filter masks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from PIL import Image
from pydantic import Field
from scipy import ndimage

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.layers import OccupancyGrid

FREE, INSCRIBED, LETHAL, UNKNOWN = 0, 253, 254, 255


def costmap_values(grid: OccupancyGrid, inscribed_radius: float, inflation_radius: float, cost_scaling_factor: float) -> np.ndarray:
    occupied = grid.data >= 65
    unknown = grid.data < 0
    dist = ndimage.distance_transform_edt(~occupied) * grid.resolution if occupied.any() else np.full(grid.data.shape, np.inf)
    cost = np.zeros(grid.data.shape, np.float64)
    ramp = (dist > inscribed_radius) & (dist <= inflation_radius)
    cost[ramp] = 252.0 * np.exp(-cost_scaling_factor * (dist[ramp] - inscribed_radius))
    out = np.rint(cost).astype(np.uint8)
    out[dist <= inscribed_radius] = INSCRIBED
    out[occupied] = LETHAL
    out[unknown & ~occupied] = UNKNOWN
    return out


class CostmapConfig(StageConfig):
    layer: str = Field(default="multimap", description="Occupancy layer to inflate (multimap keeps the robot off chair seats).")
    basename: str = Field(default="costmap", description="File basename in the export folder.")
    inscribed_radius: float = Field(default=0.2, ge=0.0, description="Robot's inscribed radius, metres (cells this close to an obstacle are 253).")
    inflation_radius: float = Field(default=0.55, gt=0.0, description="Inflation radius, metres (Nav2's default 0.55).")
    cost_scaling_factor: float = Field(default=10.0, gt=0.0, description="Exponential decay rate of the inflation (Nav2's default 10).")


class CostmapExporter(Exporter):
    """Nav2 costmap values (0 free, 253 inscribed, 254 lethal, 255 unknown) with inflation, as PGM + YAML."""

    name = "costmap"
    Config = CostmapConfig
    requires = frozenset({"occupancy"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg: CostmapConfig = self.config  # type: ignore[assignment]
        grid = data.map.occupancy.get(cfg.layer)
        if grid is None:
            self.warn(f"no occupancy layer {cfg.layer!r} (have: {sorted(data.map.occupancy)}); costmap not written")
            return []
        values = costmap_values(grid, cfg.inscribed_radius, cfg.inflation_radius, cfg.cost_scaling_factor)
        pgm = out_dir / f"{cfg.basename}.pgm"
        with atomic_path(pgm) as tmp:
            Image.fromarray(np.flipud(values), mode="L").save(tmp, format="PPM")
        meta = {
            "image": pgm.name,
            "mode": "raw",
            "resolution": float(grid.resolution),
            "origin": [float(v) for v in grid.origin],
            "negate": 0,
            "occupied_thresh": 0.65,
            "free_thresh": 0.196,
        }
        yml = out_dir / f"{cfg.basename}.yaml"
        write_text(yml, yaml.safe_dump(meta, sort_keys=False, default_flow_style=None))
        return [yml, pgm]


@hookimpl
def stratamap_register_exporters():
    return [CostmapExporter]
