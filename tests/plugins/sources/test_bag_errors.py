"""Real recordings are messy (issue 69), bags: what rosbags cannot read, or a bag with nothing to map,
is one line naming the bag (rc 2 from the command line), never rosbags' own exception."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.io.rosbag import write_lidar_bag
from stratamap.core.map.sensors import LidarScan
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.rosbag import RosbagSource
from tests.conftest import REPO


def lidar_bag(path: Path, sweeps: int = 3, points: np.ndarray | None = None) -> Path:
    rng = np.random.default_rng(0)
    cloud = rng.normal(size=(200, 3)) if points is None else points
    return write_lidar_bag(path, [LidarScan(0.1 * k, cloud, np.eye(4)) for k in range(sweeps)], ros_version=1)


def one_line(path: Path, **params) -> str:
    with pytest.raises(DataError) as err:
        RosbagSource(path=str(path), **params).run(PipelineData())
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(path)), text
    return text


def test_a_folder_without_metadata_is_named(tmp_path):
    """Before: rosbags' FileNotFoundError ("Expected metadata file ... does not exist"), bare."""
    folder = tmp_path / "drive"
    folder.mkdir()
    (folder / "drive_0.db3").write_bytes(b"SQLite format 3\x00")
    assert "a folder without metadata.yaml" in one_line(folder)


def test_a_bag_with_nothing_to_map_names_its_topics(tmp_path):
    """Before: the message listed the message types under "topics"."""
    text = one_line(lidar_bag(tmp_path / "empty.bag", sweeps=0))
    assert "no depth images and no PointCloud2 messages (topics: ['/lidar/points', '/tf'])" in text


def test_a_lidar_bag_without_a_floor_names_the_bag(tmp_path):
    """Before: the error named the stream ("sweeps"), not the file."""
    ball = np.random.default_rng(1).normal(size=(3000, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True)
    assert "no floor plane found" in one_line(lidar_bag(tmp_path / "sweeps.bag", points=ball))


@pytest.mark.parametrize("damage", ["folder", "cut"])
def test_the_command_line_says_one_line_and_exits_2(tmp_path, damage):
    if damage == "folder":
        path = tmp_path / "drive"
        path.mkdir()
    else:
        path = lidar_bag(tmp_path / "cut.bag")
        path.write_bytes(path.read_bytes()[:3000])
    result = subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", "run", "configs/scan.yaml", "--set", "source.plugin=rosbag"]
        + ["--set", f"source.params.path={path}", "--out", str(tmp_path / "out")],
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    last = result.stderr.rstrip("\n").splitlines()[-1]
    assert last.startswith(f"error: {path}: ") and not (tmp_path / "out").exists(), result.stderr
