"""Nav2 map files: round trip through a reader that follows nav2_map_server's rules, and real maps."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from PIL import Image

from stratamap.core.errors import DataError
from stratamap.core.io.nav2 import read_map, write_map
from stratamap.core.map.layers import OccupancyGrid
from tests.conftest import shared_data


def test_round_trip_same_grid(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.choice(np.array([-1, 0, 100], np.int8), size=(37, 53))
    grid = OccupancyGrid(data, 0.05, (-1.25, 2.5, 0.0))
    yml, pgm = write_map(grid, tmp_path, "map")
    back = read_map(yml)
    np.testing.assert_array_equal(back.data, grid.data)
    assert back.resolution == grid.resolution and back.origin == grid.origin


def test_file_layout_is_what_map_server_expects(tmp_path):
    data = np.full((4, 6), -1, np.int8)
    data[0, 0] = 100  # row 0 is the lowest y: the *last* image row
    data[3, 5] = 0
    yml, pgm = write_map(OccupancyGrid(data, 0.1, (0, 0, 0)), tmp_path, "map")
    meta = yaml.safe_load(yml.read_text())
    assert meta == {
        "image": "map.pgm", "mode": "trinary", "resolution": 0.1, "origin": [0.0, 0.0, 0.0],
        "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196,
    }  # fmt: skip
    raw = pgm.read_bytes()
    assert raw.startswith(b"P5")
    img = np.asarray(Image.open(pgm))
    assert img.dtype == np.uint8 and img.shape == (4, 6)
    assert img[3, 0] == 0 and img[0, 5] == 254 and img[0, 0] == 205


def test_reader_rules_scale_and_negate(tmp_path):
    img = np.array([[0, 100, 205, 254, 255]], np.uint8)
    Image.fromarray(img).save(tmp_path / "m.pgm")
    (tmp_path / "m.yaml").write_text(
        "image: m.pgm\nmode: scale\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\noccupied_thresh: "
        "0.65\nfree_thresh: 0.196\n"
    )
    cells = read_map(tmp_path / "m.yaml").data[0]
    # p = (255 - v) / 255: 1.0 -> 100, 0.608 -> scaled, 0.196 -> 0 (rounded), 0.0039 -> free, 0 -> free
    assert cells[0] == 100 and cells[3] == 0 and cells[4] == 0
    assert cells[1] == round(99 * ((255 - 100) / 255 - 0.196) / (0.65 - 0.196))
    (tmp_path / "n.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 1\n")
    neg = read_map(tmp_path / "n.yaml").data[0]
    assert neg[0] == 0 and neg[4] == 100


def test_missing_keys_and_files_are_named(tmp_path):
    (tmp_path / "a.yaml").write_text("image: a.pgm\norigin: [0, 0, 0]\n")
    with pytest.raises(DataError, match="resolution"):
        read_map(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("image: nowhere.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(DataError, match="nowhere.pgm"):
        read_map(tmp_path / "b.yaml")


def test_real_apartment_map_loads():
    grid = read_map(shared_data("iai_apartment", "maps", "map_25_08_2022.yaml"))
    assert grid.resolution == 0.02 and grid.origin == (-3.23, -4.95, 0.0)
    assert grid.data.shape == (752, 918)
    counts = grid.counts()
    assert counts["free"] > 0 and counts["occupied"] > 0


def test_real_map_with_missing_image_names_it():
    with pytest.raises(DataError) as exc:
        read_map(shared_data("iai_apartment", "maps", "map_24_08_2022.yaml"))
    assert "map.pgm" in str(exc.value) and "does not exist" in str(exc.value)


def test_costmap_values_follow_nav2_inflation():
    from stratamap.core.io.nav2 import costmap_values

    data = np.zeros((41, 41), np.int8)
    data[20, 20] = 100
    data[0, :] = -1
    costs = costmap_values(OccupancyGrid(data, 0.05, (0, 0, 0)), 0.2, 0.55, 10.0)
    assert costs[20, 20] == 254 and costs[20, 22] == 253  # 0.10 m: inside the inscribed radius
    assert costs[20, 25] == round(252 * np.exp(-10 * (0.25 - 0.2)))  # 0.25 m: on the decay
    assert costs[20, 40] == 0 and costs[0, 5] == 255
    assert all(costs[20, 24 + k] >= costs[20, 25 + k] for k in range(10))


def test_costmap_file_loads_raw(tmp_path):
    from stratamap.core.stages import PipelineData
    from stratamap.plugins.exporters.costmap import CostmapExporter

    data = PipelineData()
    grid = np.zeros((30, 40), np.int8)
    grid[10:12, 10:12] = 100
    data.map.set("occupancy", {"multimap": OccupancyGrid(grid, 0.05, (1.0, 2.0, 0.0))}, "test")
    yml, _ = CostmapExporter().run(data, tmp_path)
    back = read_map(yml)
    assert back.origin == (1.0, 2.0, 0.0)
    assert (back.data.astype(np.uint8)[10:12, 10:12] == 254).all()
