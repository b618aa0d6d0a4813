"""Mapper ``occupancy``: 2D occupancy layers from the 3D geometry.

* ``slam`` -- what a planar laser at ``laser_height`` sees: geometry in a thin slice around that
  height (chair legs, table legs, walls; not chair seats). It stands in for a laser SLAM map.
* ``objects`` -- every obstacle in the band [``z_min``, ``robot_height``] projected to the floor.
* ``multimap`` -- the two overlaid (first paper, section V-C): occupied where either is occupied.

Cells where the floor was observed and nothing is occupied are free; the rest stay unknown.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field, model_validator

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.layers import OccupancyGrid, OccupancyMaps


class OccupancyConfig(StageConfig):
    resolution: float = Field(default=0.05, gt=0.005, le=1.0, description="Cell size, metres (Nav2's default is 0.05).")
    z_min: float = Field(default=0.1, ge=0.0, description="Lower edge of the obstacle band, metres above the floor.")
    robot_height: float = Field(default=1.0, gt=0.0, description="Upper edge of the obstacle band: the robot's height, metres.")
    laser_height: float = Field(default=0.25, gt=0.0, description="Height of the planar laser scanner the `slam` layer simulates, metres.")
    laser_slice: float = Field(default=0.04, gt=0.0, description="Thickness of the slice around laser_height, metres.")
    floor_tolerance: float = Field(default=0.05, gt=0.0, description="Points this close to the floor count as floor (free space), metres.")
    min_points_per_cell: int = Field(default=2, ge=1, description="A cell is occupied when at least this many points fall in it.")
    margin: float = Field(default=0.5, ge=0.0, description="Border of unknown cells around the mapped area, metres.")

    @model_validator(mode="after")
    def _band(self) -> OccupancyConfig:
        if self.z_min >= self.robot_height:
            raise ValueError(f"z_min ({self.z_min}) must be below robot_height ({self.robot_height})")
        return self


class OccupancyMapper(Mapper):
    """2D occupancy layers (laser slice, object band, multimap) projected from the 3D geometry."""

    name = "occupancy"
    Config = OccupancyConfig
    requires = frozenset({"geometry"})
    optional = frozenset({"semantics"})
    provides = frozenset({"occupancy"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg: OccupancyConfig = self.config  # type: ignore[assignment]
        geom = data.map.geometry
        assert geom is not None
        pts = geom.points
        if len(pts) == 0:
            self.warn("the geometry layer is empty; no occupancy grids made")
            return {}
        floor_z = self._floor_height(data)
        z = pts[:, 2] - floor_z
        lo = pts[:, :2].min(0) - cfg.margin
        hi = pts[:, :2].max(0) + cfg.margin
        origin = np.floor(lo / cfg.resolution) * cfg.resolution
        shape = (int(np.ceil((hi[1] - origin[1]) / cfg.resolution)), int(np.ceil((hi[0] - origin[0]) / cfg.resolution)))
        rc = np.floor((pts[:, [1, 0]] - origin[[1, 0]]) / cfg.resolution).astype(np.int64)

        def hits(mask: np.ndarray) -> np.ndarray:
            counts = np.zeros(shape, np.int64)
            np.add.at(counts, (rc[mask, 0], rc[mask, 1]), 1)
            return counts >= cfg.min_points_per_cell

        floor_seen = hits(np.abs(z) <= cfg.floor_tolerance)
        laser = hits(np.abs(z - cfg.laser_height) <= cfg.laser_slice / 2)
        band = hits((z >= cfg.z_min) & (z <= cfg.robot_height))

        def grid(occupied: np.ndarray) -> OccupancyGrid:
            cells = np.full(shape, -1, np.int8)
            cells[floor_seen] = 0
            cells[occupied] = 100
            return OccupancyGrid(cells, cfg.resolution, (float(origin[0]), float(origin[1]), 0.0))

        maps = OccupancyMaps(slam=grid(laser), objects=grid(band), multimap=grid(laser | band))
        self.note("floor_z", float(floor_z))
        return {"occupancy": maps}

    @staticmethod
    def _floor_height(data: PipelineData) -> float:
        sem = data.map.semantics
        pts = data.map.geometry.points  # type: ignore[union-attr]
        if sem is not None and "floor" in sem.vocabulary and len(sem) == len(pts):
            floor = sem.class_ids == sem.vocabulary.id("floor")
            if floor.sum() > 100:
                return float(np.median(pts[floor, 2]))
        return 0.0


@hookimpl
def stratamap_register_mappers():
    return [OccupancyMapper]
