"""A Nav2 map or costmap with no free cell gives a planner nowhere to go: the exporters still write it,
with a warning naming the file and what its cells are (before: rc 0 and no word)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.io.nav2 import read_map
from stratamap.core.map.layers import OccupancyGrid, OccupancyMaps
from stratamap.core.stages import PipelineData
from stratamap.plugins.exporters.costmap import CostmapExporter
from stratamap.plugins.exporters.nav2_map import Nav2MapExporter


def data_with(cells: np.ndarray) -> PipelineData:
    data = PipelineData()
    grid = OccupancyGrid(cells.astype(np.int8), 0.05, (0.0, 0.0, 0.0))
    data.map.occupancy = OccupancyMaps(slam=grid, multimap=grid)
    return data


def unknown_and_walls() -> np.ndarray:
    cells = np.full((40, 60), -1)
    cells[0, :] = cells[-1, :] = 100
    return cells


@pytest.mark.parametrize("exporter", [Nav2MapExporter, CostmapExporter], ids=["nav2_map", "costmap"])
def test_a_map_with_no_free_cell_is_written_with_a_warning(tmp_path, exporter):
    data = data_with(unknown_and_walls())
    files = exporter().run(data, tmp_path)
    assert files and all(p.exists() for p in files)
    warned = [w for w in data.warnings if "no free cells" in w]
    basename = "costmap" if exporter is CostmapExporter else "map"
    assert warned and f"{basename}.pgm (layer " in warned[0] and "120 occupied, 2,280 unknown of 2,400" in warned[0]
    if exporter is Nav2MapExporter:
        assert len(warned) == 2  # map.pgm and multimap.pgm
        assert not (read_map(tmp_path / "map.yaml").data == 0).any()


@pytest.mark.parametrize("exporter", [Nav2MapExporter, CostmapExporter], ids=["nav2_map", "costmap"])
def test_one_free_cell_is_no_warning(tmp_path, exporter):
    cells = unknown_and_walls()
    cells[20, 30] = 0
    data = data_with(cells)
    exporter().run(data, tmp_path)
    assert not data.warnings
