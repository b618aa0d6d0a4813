"""Real recordings are messy (issue 69), LiDAR: a bag from a sensor that stands still, or moves less
than a keyframe's travel per sweep, gives a laser map with free space (before: one or three planar
scans, and one look at a cell makes it no freer than p = 0.4, so no free cell at all), and a stray
return far from the room is left out with a warning instead of failing the floor search and the
voxel grid in Open3D."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stratamap.core.io.rosbag import write_lidar_bag
from stratamap.core.map.sensors import LidarScan
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.plugins.exporters.nav2_map import Nav2MapExporter
from stratamap.plugins.mappers.occupancy import OccupancyConfig, OccupancyMapper, sweeps_per_place
from stratamap.plugins.mappers.points import PointsMapper
from stratamap.plugins.sources.rosbag import RosbagSource
from tests.plugins.sources.test_messy_clouds import room

SENSOR = np.array([2.6, 1.5, 0.5])  # beside the room's box, half a metre up


def bag(tmp_path: Path, step: float, sweeps: int = 6, stray: bool = False) -> Path:
    """``sweeps`` sweeps of the room from a sensor moving ``step`` m along x per sweep (0: standing),
    posed by tf; ``stray``: each sweep also holds one return 1e9 m away."""
    points = room(6000)
    scans = []
    for k in range(sweeps):
        pose = np.eye(4)
        pose[:3, 3] = SENSOR + [step * k, 0, 0]
        local = points - pose[:3, 3]
        if stray:
            local = np.vstack([local, [[1e9, 2e8, 0.0]]])
        scans.append(LidarScan(0.1 * k, local, pose))
    return write_lidar_bag(tmp_path / "sweeps.bag", scans, ros_version=1)


def mapped(path: Path, out: Path | None = None) -> PipelineData:
    stages = [RosbagSource(path=str(path)), PointsMapper(voxel_size=0.05, normals_radius=0.0)]
    stages += [OccupancyMapper()] + ([Nav2MapExporter()] if out else [])
    return run_stages(stages, PipelineData(), out)


@pytest.mark.parametrize(
    ("step", "sweeps"), [(0.0, 6), (0.15, 6), (0.0, 1), (0.5, 3)], ids=["standing", "15cm-per-sweep", "one", "three"]
)
def test_a_standing_or_slow_sensor_maps_free_space(tmp_path, step, sweeps):
    """Fewer sweeps than a place takes (one, or three 0.5 m apart) are each one long look, as a tripod
    scanner's station."""
    data = mapped(bag(tmp_path, step, sweeps), tmp_path / "export")
    slam = data.map.occupancy["slam"].data
    free, occupied = int((slam == 0).sum()), int((slam == 100).sum())
    assert free > 2000 and occupied > 100  # the 4 x 3 m room's floor is 4,800 cells of 5 cm
    assert not [w for w in data.warnings if "no free cells" in w], data.warnings
    # what it calls free lies in the room, and its walls are not free
    rows, cols = np.nonzero(slam == 0)
    grid = data.map.occupancy["slam"]
    x = grid.origin[0] + (cols + 0.5) * grid.resolution
    y = grid.origin[1] + (rows + 0.5) * grid.resolution
    assert np.mean((x > 0.05) & (x < 3.95) & (y > 0.05) & (y < 2.95)) > 0.97


def test_a_long_stay_costs_a_few_planar_scans():
    """100 sweeps from one place become sweeps_per_place planar scans (5 at the defaults), not 100."""
    from stratamap.core.map.sensors import SensorStream
    from stratamap.plugins.mappers.occupancy import lidar_planar_scans

    pose = np.eye(4)
    pose[:3, 3] = SENSOR
    sweeps = [LidarScan(0.1 * k, room(3000) - SENSOR, pose) for k in range(100)]
    cfg = OccupancyConfig()
    planar, _ = lidar_planar_scans(sweeps, 0.0, cfg)
    assert len(planar) == sweeps_per_place(cfg) == 5
    data = run_stages(
        [PointsMapper(voxel_size=0.05, normals_radius=0.0), OccupancyMapper()],
        PipelineData(stream=SensorStream(name="still", lidar_scans=sweeps)),
    )
    assert data.notes["occupancy"]["slam_source"].startswith("5 of 100 LiDAR sweeps")


def test_a_stray_return_in_every_sweep_is_left_out_with_a_warning(tmp_path):
    """Before: Open3D's "voxel_size is too small" from the floor search on the first sweeps."""
    data = mapped(bag(tmp_path, 0.0, stray=True))
    assert [w for w in data.warnings if "6 points lie far from the rest" in w], data.warnings
    assert np.abs(data.map.geometry.points).max() < 10
    assert (data.map.occupancy["slam"].data == 0).sum() > 2000
