"""Odometry is deterministic: the same input without poses gives byte-identical poses and maps on
every run (issue 27: Open3D's and KISS-ICP's multi-threaded reductions made every run differ)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from stratamap.core.config import load_pipeline
from stratamap.core.pipeline import Pipeline
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.writer import write_sequence
from stratamap.plugins.sources._odometry import lidar_odometry, open3d_threads, rgbd_frame_to_model
from stratamap.plugins.sources.tum import TUMSource
from tests.conftest import REPO, shared_data


def map_files(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted((out / "map").rglob("*")) if p.is_file()}


def run_map_geometry(sequence: Path, out: Path, max_frames: int) -> tuple[dict[str, bytes], bytes, dict]:
    """configs/map_geometry.yaml as shipped, on ``sequence``: (map files, poses, source metadata)."""
    overrides = [f"source.params.path={sequence}", f"source.params.max_frames={max_frames}"]
    pipeline = Pipeline(load_pipeline(REPO / "configs" / "map_geometry.yaml", overrides))
    pipeline.run(out)
    assert pipeline.data is not None
    stream = pipeline.data.get("frames")
    return map_files(out), np.stack([f.pose for f in stream.frames]).tobytes(), stream.metadata


@pytest.fixture(scope="module")
def world() -> SyntheticWorld:
    """A synthetic room seen from an orbit (2.5 degrees between frames)."""
    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 4,
            "camera": {"width": 160, "height": 120},
            "trajectory": {"type": "orbit", "frames": 144},
        }
    )
    return SyntheticWorld(spec)


@pytest.fixture(scope="module")
def no_pose_sequence(tmp_path_factory, world) -> Path:
    """The room in the TUM layout without groundtruth.txt (nor gt/)."""
    seq = write_sequence(world, tmp_path_factory.mktemp("nogt") / "seq")
    (seq / "groundtruth.txt").unlink()
    shutil.rmtree(seq / "gt")
    return seq


@pytest.mark.slow  # a whole pipeline run (make test runs it; make test-fast does not)
def test_rgbd_odometry_twice_gives_byte_identical_poses(world):
    frames = [world.frame(k)[0] for k in range(10)]
    first = rgbd_frame_to_model(frames, world.intrinsics)
    second = rgbd_frame_to_model(frames, world.intrinsics)
    assert np.stack(first).tobytes() == np.stack(second).tobytes()


@pytest.mark.slow
def test_no_pose_pipeline_twice_gives_byte_identical_poses_and_maps(no_pose_sequence, tmp_path):
    files_a, poses_a, meta_a = run_map_geometry(no_pose_sequence, tmp_path / "a", max_frames=12)
    files_b, poses_b, meta_b = run_map_geometry(no_pose_sequence, tmp_path / "b", max_frames=12)
    assert meta_a["odometry"]["frames"] == 12 and meta_a["gravity_alignment"]["realigned"]
    assert poses_a == poses_b, "odometry differs between two runs on the same input"
    assert meta_a["gravity_alignment"] == meta_b["gravity_alignment"]
    assert "map/geometry.npz" in files_a and files_a.keys() == files_b.keys()
    for name in files_a:
        assert files_a[name] == files_b[name], f"{name} differs between two runs on the same input"


@pytest.mark.slow
def test_real_office_without_poses_twice_gives_byte_identical_poses(tmp_path):
    office = shared_data("align3d_office")
    seq = tmp_path / "office"
    shutil.copytree(office, seq)
    (seq / "groundtruth.txt").unlink()

    def poses() -> tuple[bytes, list]:
        stream = TUMSource(path=str(seq), max_frames=10).run(PipelineData())["frames"]
        return np.stack([f.pose for f in stream.frames]).tobytes(), stream.metadata["world_transform"]

    assert poses() == poses()


def test_lidar_odometry_twice_gives_byte_identical_poses():
    spec = SceneSpec.model_validate(
        {
            "type": "room",
            "seed": 4,
            "camera": {"width": 32, "height": 24},
            "trajectory": {"type": "orbit", "frames": 30},
            "lidar": {"enabled": True, "rings": 16, "points_per_ring": 512},
        }
    )
    scans = SyntheticWorld(spec).lidar_scans
    points, stamps = [s.points for s in scans], [s.timestamp for s in scans]
    first, second = lidar_odometry(points, stamps), lidar_odometry(points, stamps)
    assert np.stack(first).tobytes() == np.stack(second).tobytes()


def test_open3d_thread_limit_is_restored():
    before = o3d.utility.get_max_threads()
    with open3d_threads(1):
        assert o3d.utility.get_max_threads() == 1
    assert o3d.utility.get_max_threads() == before
    with pytest.raises(RuntimeError), open3d_threads(1):
        raise RuntimeError("tracking lost")
    assert o3d.utility.get_max_threads() == before
