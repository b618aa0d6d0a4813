"""scripts/convert_7scenes.py: a 7-Scenes sequence (the real kitchen of configs/bench/real_rooms.yaml)
becomes a TUM-layout folder the tum source reads with the same poses and depth; bad input is one line
and exit 2, with nothing written."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.tum import TUMSource
from tests.conftest import REPO

SCRIPT = REPO / "scripts" / "convert_7scenes.py"


def pose(k: int) -> np.ndarray:
    """A camera-to-world pose turning about the vertical and stepping sideways, frame by frame."""
    a = np.radians(10.0 * k)
    out = np.eye(4)
    out[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    out[:3, 3] = [0.1 * k, -0.2, 0.5]
    return out


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Four frames in 7-Scenes' layout: colour PNG, depth in millimetres with 65535 where none, pose.txt."""
    folder = tmp_path_factory.mktemp("seven_scenes") / "seq-01"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(4):
        colour = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
        depth = np.full((480, 640), 1500 + 100 * k, np.uint16)
        depth[:10] = 65535
        Image.fromarray(colour).save(folder / f"frame-{k:06d}.color.png")
        Image.fromarray(depth).save(folder / f"frame-{k:06d}.depth.png")
        np.savetxt(folder / f"frame-{k:06d}.pose.txt", pose(k))
    return folder


def convert(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_the_tum_source_reads_the_poses_and_depth_back(sequence, tmp_path):
    out = tmp_path / "tum"
    done = convert(sequence, out, "--frames", 3)
    assert done.returncode == 0, done.stderr
    stream = TUMSource(path=str(out), gravity="off").run(PipelineData())["frames"]
    frames = list(stream.frames)
    assert len(frames) == 3  # frames 0, 2 and 3 of 4, evenly spaced
    assert stream.intrinsics.fx == 585.0
    for frame, k in zip(frames, (0, 2, 3), strict=True):
        np.testing.assert_allclose(frame.pose, pose(k), atol=1e-5)
        depth = np.asarray(frame.depth)
        assert (depth[:10] == 0).all()  # 65535 is no measurement
        np.testing.assert_allclose(depth[10:], (1500 + 100 * k) / 1000.0, atol=1e-6)


@pytest.mark.parametrize("case", ["exists", "no_frames", "no_pose"])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(sequence, tmp_path, case):
    source, out = sequence, tmp_path / "tum"
    if case == "exists":
        out.mkdir()
        (out / "mine.txt").write_text("kept")
    elif case == "no_frames":
        source = tmp_path / "empty"
        source.mkdir()
    else:
        source = tmp_path / "broken"
        source.mkdir()
        for name in ("frame-000000.color.png", "frame-000000.depth.png"):
            (source / name).write_bytes((sequence / name).read_bytes())
    done = convert(source, out)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr, done.stderr
    if case == "exists":
        assert [p.name for p in out.iterdir()] == ["mine.txt"]
    else:
        assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".tum.")]
