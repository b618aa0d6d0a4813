"""scripts/thin_tum.py: a TUM RGB-D sequence thinned to N evenly spaced frames (the held-out office of
configs/bench/real_rooms.yaml) reads back through the tum source with the same poses and depth; bad
input is one line and exit 2, with nothing written."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.writer import write_sequence
from stratamap.plugins.sources.tum import TUMSource
from tests.conftest import REPO

SCRIPT = REPO / "scripts" / "thin_tum.py"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    """Six rendered frames in TUM's layout, in a folder named as TUM names a Freiburg-2 sequence."""
    spec = SceneSpec.model_validate(
        {"type": "room", "seed": 1, "camera": {"width": 640, "height": 480}, "trajectory": {"frames": 6}}
    )
    return write_sequence(SyntheticWorld(spec), tmp_path_factory.mktemp("tum") / "rgbd_dataset_freiburg2_room")


def thin(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True)


def test_the_kept_frames_read_back_with_their_poses_and_depth(sequence, tmp_path):
    out = tmp_path / "thin"
    done = thin(sequence, out, "--frames", 3)
    assert done.returncode == 0, done.stderr
    whole = list(TUMSource(path=str(sequence), gravity="off").run(PipelineData())["frames"].frames)
    thinned = TUMSource(path=str(out), gravity="off").run(PipelineData())["frames"]
    frames = list(thinned.frames)
    assert len(frames) == 3
    assert thinned.intrinsics.fx == 520.9  # Freiburg 2, from the folder's name
    for frame, k in zip(frames, (0, 2, 5), strict=False):
        np.testing.assert_allclose(frame.pose, whole[k].pose, atol=1e-5)
        np.testing.assert_array_equal(np.asarray(frame.depth), np.asarray(whole[k].depth))
        assert np.abs(np.asarray(frame.rgb, float) - np.asarray(whole[k].rgb, float)).mean() < 8  # JPEG


def test_bad_input_is_one_line_and_exit_2_with_nothing_written(sequence, tmp_path):
    missing = thin(tmp_path / "nowhere", tmp_path / "a")
    assert missing.returncode == 2 and missing.stderr.count("\n") == 1 and "nowhere" in missing.stderr
    unnamed = tmp_path / "office"
    unnamed.mkdir()
    done = thin(unnamed, tmp_path / "b")
    assert done.returncode == 2 and "--freiburg" in done.stderr
    (tmp_path / "c").mkdir()
    done = thin(sequence, tmp_path / "c")
    assert done.returncode == 2 and "exists" in done.stderr
    broken = tmp_path / "rgbd_dataset_freiburg1_broken"
    broken.mkdir()
    (broken / "rgb.txt").write_text("0.0 rgb/a.png\n")
    (broken / "depth.txt").write_text("0.0 depth/a.png\n")
    (broken / "groundtruth.txt").write_text("0.0 0 0 0 0 0 0 1\n")
    done = thin(broken, tmp_path / "d")
    assert done.returncode == 2 and "missing" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["office", "c", "rgbd_dataset_freiburg1_broken"])
