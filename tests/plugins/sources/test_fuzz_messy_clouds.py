"""Property-based fuzzing of what a messy recording's coordinates do past the readers (issue 69): a room
cloud or a LiDAR bag whose points are replaced, here and there, by NaN, infinities, 1e38, 1e9 or 100 km,
scaled to millimetres or not, or whose file is cut and its bytes flipped, goes through the source (floor
search on), the ``points`` mapper (voxel grid) and ``occupancy``. Whatever the input, the run gives a
finite geometry and a grid of bounded size, or the project's one-line ``DataError``; never another
exception (before: Open3D's "voxel_size is too small" on one stray point)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stratamap.core.errors import DataError
from stratamap.core.io.pointcloud import write_point_cloud
from stratamap.core.io.rosbag import write_lidar_bag
from stratamap.core.map.sensors import LidarScan
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.occupancy import MAX_CELLS, OccupancyMapper
from stratamap.plugins.mappers.points import PointsMapper
from stratamap.plugins.sources.pointcloud import PointCloudSource
from stratamap.plugins.sources.rosbag import RosbagSource
from tests.core.io.test_fuzz_readers import fuzz, inputs
from tests.plugins.sources.test_messy_clouds import room

# Bounded (a few seconds per test): `make test` runs them, `make test-fast` leaves them out.
pytestmark = pytest.mark.slow

ROOM = room(3000, seed=5)
WILD = [np.nan, np.inf, -np.inf, 3.0e38, -1e38, 1e9, 1e5, -2e4, 0.0]


@st.composite
def messy_points(draw) -> np.ndarray:
    """The room with some coordinates (one to a few dozen, or a whole column's share) made wild, scaled."""
    points = ROOM * draw(st.sampled_from([1.0, 1.0, 1000.0, 0.001]))
    rows = draw(st.lists(st.integers(0, len(points) - 1), min_size=1, max_size=40))
    columns = draw(st.lists(st.integers(0, 2), min_size=len(rows), max_size=len(rows)))
    values = draw(st.lists(st.sampled_from(WILD), min_size=len(rows), max_size=len(rows)))
    points = points.copy()
    points[rows, columns] = values
    if draw(st.booleans()):  # a tenth of the points at one wild value: not a stray any more
        points[::10, draw(st.integers(0, 2))] = draw(st.sampled_from(WILD))
    return points


def through_the_maps(stages: list, where: str) -> None:
    try:
        data = run_stages([*stages, PointsMapper(voxel_size=0.02, normals_radius=0.0), OccupancyMapper()])
    except DataError as err:
        assert str(err) and "\n" not in str(err), str(err)
        return
    assert np.isfinite(data.map.geometry.points).all(), where
    assert data.map.occupancy["slam"].data.size <= MAX_CELLS


@pytest.mark.parametrize("suffix", [".npy", ".pcd", ".ply"])
def test_fuzz_wild_coordinates_through_the_maps(suffix):
    @fuzz(25)
    @given(messy_points())
    def run(points: np.ndarray) -> None:
        with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
            path = Path(tmp) / f"c{suffix}"
            write_point_cloud(path, points if suffix == ".npy" else points.astype(np.float32), None, {})
            through_the_maps([PointCloudSource(path=str(path))], str(path))

    with np.errstate(over="ignore", invalid="ignore"):  # float32 of 3e38 x 1000: written as inf, as a file may
        run()


@st.composite
def wild_payload(draw, base: bytes) -> bytes:
    """``base`` with float32 values overwritten, anywhere past its first 10% (a header or index stays
    readable): NaN, infinities, 1e38, 1e9, or random bytes."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 12))):
        k = draw(st.integers(len(data) // 10, len(data) - 4))
        value = draw(st.sampled_from(WILD).map(lambda v: np.float32(v).tobytes()) | st.binary(min_size=4, max_size=4))
        data[k : k + 4] = value
    return bytes(data)


def _room_file() -> bytes:
    with tempfile.TemporaryDirectory() as tmp, np.errstate(over="ignore"):
        return write_point_cloud(Path(tmp) / "r.pcd", ROOM.astype(np.float32), None, {}, binary=True).read_bytes()


ROOM_PCD = _room_file()


def test_fuzz_damaged_room_file_through_the_maps():
    @fuzz(30)
    @given(st.one_of(inputs(ROOM_PCD), wild_payload(ROOM_PCD), wild_payload(ROOM_PCD)))
    def run(data: bytes) -> None:
        with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
            path = Path(tmp) / "r.pcd"
            path.write_bytes(data)
            try:
                PointCloudSource(path=str(path), gravity="off").run(PipelineData())
            except DataError as err:
                assert str(path) in str(err) and "\n" not in str(err), str(err)
                return
            through_the_maps([PointCloudSource(path=str(path))], str(path))

    run()


def _bag(root: Path, sweeps: list[np.ndarray], step: float) -> Path:
    scans = []
    for k, points in enumerate(sweeps):
        pose = np.eye(4)
        pose[:3, 3] = [2.6 + step * k, 1.5, 0.5]
        scans.append(LidarScan(0.1 * k, points - pose[:3, 3], pose))
    return write_lidar_bag(root / "s.bag", scans, ros_version=1)


def test_fuzz_wild_lidar_sweeps_through_the_maps():
    @fuzz(25)
    @given(st.lists(messy_points(), min_size=1, max_size=4), st.sampled_from([0.0, 0.15, 1.0]))
    def run(sweeps: list[np.ndarray], step: float) -> None:
        with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
            with np.errstate(over="ignore", invalid="ignore"):
                path = _bag(Path(tmp), sweeps, step)
            through_the_maps([RosbagSource(path=str(path))], str(path))

    run()


def test_fuzz_damaged_lidar_bag_through_the_maps():
    with tempfile.TemporaryDirectory() as tmp:
        base = _bag(Path(tmp), [ROOM[::3]] * 3, 0.0).read_bytes()

    @fuzz(30)
    @given(st.one_of(inputs(base, header=4096), wild_payload(base), wild_payload(base)))
    def run(data: bytes) -> None:
        with tempfile.TemporaryDirectory(prefix="stratamap-fuzz-") as tmp:
            path = Path(tmp) / "s.bag"
            path.write_bytes(data)
            through_the_maps([RosbagSource(path=str(path))], str(path))

    run()
