"""Labels kept apart from a recording: the tum source reads a gt/ folder named by ground_truth_path
(real recordings live in read-only folders; their hand-made box labels live in the repository)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.writer import write_sequence
from stratamap.plugins.sources.tum import TUMSource
from tests.conftest import REPO

SMALL = {"type": "room", "seed": 2, "camera": {"width": 96, "height": 72}, "trajectory": {"type": "orbit", "frames": 3}}


@pytest.fixture(scope="module")
def moved(tmp_path_factory):
    """A sequence whose gt/ folder was moved out of it."""
    root = tmp_path_factory.mktemp("tum_gt")
    seq = write_sequence(SyntheticWorld(SceneSpec.model_validate(SMALL)), root / "seq")
    shutil.move(str(seq / "gt"), root / "labels")
    return seq, root / "labels"


def label_command(tmp_path) -> list[str]:
    script = REPO / "scripts" / "box_labels.py"
    return [sys.executable, str(script), str(tmp_path / "boxes.json"), "--out", str(tmp_path / "gt")]


def test_ground_truth_from_another_folder(moved):
    seq, labels = moved
    assert TUMSource(path=str(seq), gravity="off").run(PipelineData()).get("ground_truth") is None
    out = TUMSource(path=str(seq), gravity="off", ground_truth_path=str(labels)).run(PipelineData())
    assert out["ground_truth"] is not None and len(out["ground_truth"].objects) > 0


def test_a_missing_ground_truth_folder_is_named(moved):
    seq, labels = moved
    with pytest.raises(DataError, match="ground_truth_path is not a folder"):
        TUMSource(path=str(seq), gravity="off", ground_truth_path=str(labels / "nothing")).run(PipelineData())


def test_box_labels_drawn_in_the_aligned_world_come_back_there(tmp_path):
    """scripts/box_labels.py stores poses in the recording's frame; re-aligning them gives the boxes drawn."""
    from stratamap.core.geometry.transforms import make_pose
    from stratamap.core.io.groundtruth import load_ground_truth

    tilt = make_pose([0.3, -1.0, 1.4], 0.4) @ np.array(
        [[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float
    )  # aligned world <- a y-down recording frame
    boxes = {
        "frame": "aligned",
        "world_transform": tilt.tolist(),
        "boxes": [{"name": "t", "class": "table", "center": [1.0, 2.0, 0.37], "size": [1.6, 0.9, 0.74], "yaw": 0.5}],
    }
    (tmp_path / "boxes.json").write_text(json.dumps(boxes))
    cmd = label_command(tmp_path)
    subprocess.run(cmd, check=True, capture_output=True)
    (obj,) = load_ground_truth(tmp_path / "gt", [], None).objects
    obj.pose = tilt @ obj.pose  # what the source's gravity alignment does
    box = obj.box()
    np.testing.assert_allclose(box.center, [1.0, 2.0, 0.37], atol=1e-6)
    np.testing.assert_allclose(box.size, [1.6, 0.9, 0.74], atol=1e-6)
    assert abs(box.yaw - 0.5) < 1e-6


def test_box_labels_refuse_a_list_without_boxes(tmp_path):
    (tmp_path / "boxes.json").write_text(json.dumps({"frame": "aligned"}))
    cmd = label_command(tmp_path)
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 2 and "'boxes' list" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "gt").exists()
