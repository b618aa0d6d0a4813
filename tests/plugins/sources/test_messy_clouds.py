"""Real recordings are messy (issue 69), point clouds: one stray point far from the room (a glitch at
1e9 m, 1e38, 100 km) is left out with a warning instead of stretching the floor search's voxels and the
occupancy grid, and a unit hint (millimetres? centimetres?) appears only where the bulk of the cloud says
so: on a room written in millimetres, never on a room in metres with one far point."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.geometry.points import bulk_box, far_from_bulk, unit_hint
from stratamap.core.io.pointcloud import write_point_cloud
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.occupancy import OccupancyMapper
from stratamap.plugins.mappers.points import PointsMapper
from stratamap.plugins.sources.pointcloud import PointCloudSource


def room(n: int = 12_000, seed: int = 0) -> np.ndarray:
    """A 4 x 3 x 2.5 m room's floor and walls, with a 0.6 m box on the floor, as a scanner samples them."""
    rng = np.random.default_rng(seed)
    k = n // 6
    floor = np.c_[rng.uniform(0, 4, (2 * k, 2)) * [1, 0.75], np.zeros(2 * k)]
    walls = []
    for axis, at in ((0, 0.0), (0, 4.0), (1, 0.0), (1, 3.0)):
        side = np.c_[rng.uniform(0, 4 if axis == 1 else 3, k // 2), rng.uniform(0, 2.5, k // 2)]
        walls.append(
            np.c_[np.full(k // 2, at), side] if axis == 0 else np.c_[side[:, 0], np.full(k // 2, at), side[:, 1]]
        )
    box = rng.uniform([1.5, 1.2, 0.0], [2.1, 1.8, 0.6], (k, 3))
    points = np.vstack([floor, *walls, box])
    return points + rng.normal(0, 0.003, points.shape)  # a scanner's noise: no plane is exact


def read(path: Path, **params) -> PipelineData:
    stages = [PointCloudSource(path=str(path), **params), PointsMapper(voxel_size=0.02, normals_radius=0.0)]
    return run_stages([*stages, OccupancyMapper()], PipelineData())


@pytest.mark.parametrize("far", [1e9, 1e38, 1e5, -3e7], ids=["1e9", "1e38", "100km", "-3e7"])
@pytest.mark.parametrize("suffix", [".pcd", ".npy"])
def test_one_stray_point_is_left_out_with_a_warning(tmp_path, far, suffix):
    """Before: Open3D's "voxel_size is too small" traceback from the floor search (1e9, 1e38), or the
    occupancy grid's 2e12 cells refused with a "cloud in millimetres?" hint (100 km)."""
    points = np.vstack([room(), [[far, far / 2, far]], [[np.nan, 0, 0]]])
    path = write_point_cloud(tmp_path / f"c{suffix}", points.astype(np.float32), None, {}, binary=True)
    data = read(path)
    warnings = [w for w in data.warnings if "far from the rest" in w]
    assert len(warnings) == 1 and f"1 of {len(points) - 1} points" in warnings[0] and str(path) in warnings[0]
    assert data.notes["pointcloud"]["points"]["dropped_far"] == 1
    assert np.abs(data.map.geometry.points).max() < 10
    grid = data.map.occupancy["slam"]
    assert grid.data.shape[0] * grid.data.shape[1] < 200 * 200  # the room's 4 x 3 m and its margin at 5 cm
    assert not any("millimetres" in w for w in data.warnings)


def test_a_room_in_millimetres_is_named_as_one(tmp_path):
    """Before: "no floor plane found" and no word of units."""
    path = write_point_cloud(tmp_path / "mm.npy", room() * 1000.0, None, {}, binary=True)
    with pytest.raises(DataError) as err:
        read(path)
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(path)) and "no floor plane found" in text
    assert re.search(r"millimetres \(source\.params\.scale=0\.001: 4\.\d+ x 3\.\d+ x 2\.\d+ m\)", text), text
    ok = read(path, scale=0.001)  # the hint's scale maps it
    assert ok.notes["pointcloud"]["gravity_alignment"]["floor_inliers"] > 100


def test_a_stray_point_gives_no_unit_hint_without_a_floor_search(tmp_path):
    """Before: with gravity off, the 100 km point made the grid too large and the error asked whether the
    room was in millimetres."""
    path = write_point_cloud(tmp_path / "c.npy", np.vstack([room(), [[1e5, 1e5, 1.0]]]), None, {}, binary=True)
    data = read(path, gravity="off")
    assert data.map.occupancy["slam"].data.size < 200 * 200


def test_a_large_map_in_metres_is_refused_without_a_unit_hint(tmp_path):
    """A 700 m car park (2 m of height) at 5 cm is over the grid's cells: the error says to coarsen the
    grid, not that the cloud is in millimetres (before: it did)."""
    rng = np.random.default_rng(1)
    lot = np.c_[rng.uniform(0, 700, (20_000, 2)), rng.uniform(0, 2, 20_000)]
    path = write_point_cloud(tmp_path / "lot.npy", lot, None, {}, binary=True)
    with pytest.raises(DataError, match="set a coarser occupancy resolution") as err:
        read(path, gravity="off")
    assert "millimetres" not in str(err.value)


def test_far_from_bulk_flags_strays_not_a_scene_s_own_extremes():
    rng = np.random.default_rng(3)
    flat = np.c_[rng.uniform(0, 5, (5000, 2)), np.zeros(5000)]  # a floor: no height to judge by
    boxes = rng.uniform([1, 1, 0], [1.5, 1.5, 1.0], (40, 3))  # under 1% of the points, above it
    view = np.array([[80.0, 2.0, 3.0], [-60.0, 1.0, 0.0]])  # trees through a window, 16 sides away
    stray = np.array([[1e9, 0, 0], [0, -2e3, 0], [np.inf, 0, 0]])
    far = far_from_bulk(np.vstack([flat, boxes, view, stray]))
    assert far.tolist() == [False] * (len(flat) + len(boxes) + len(view)) + [True] * 3
    low, high = bulk_box(np.vstack([flat[:99], [[1e9, 1e9, 1e9]]]))  # one stray in a hundred sets no bound
    assert high.max() < 6
    assert not far_from_bulk(np.zeros((50, 3))).any()  # one point's bulk: no scale, nothing is far


def test_unit_hint_needs_the_bulk_not_one_point():
    metres = room()
    assert unit_hint(metres) is None
    assert unit_hint(np.vstack([metres, [[1e6, 1e6, 1e6]]])) is None
    assert re.search(r"centimetres \(0\.01: 4\.\d+ x 3\.\d+ x 2\.\d+ m\)", unit_hint(metres * 100.0))
    assert unit_hint(np.c_[metres[:, :2] * 1000, metres[:, 2]]) is None  # 4 km long but 2.5 m tall: a site
