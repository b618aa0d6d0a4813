"""Frames a TSDF mapper cannot use (nothing within depth_max, no pose, an odd-sized image) are
skipped and reported, never fatal; a sequence with no usable frame is a one-line error."""

from __future__ import annotations

import copy
import dataclasses
import subprocess
import sys

import numpy as np
import pytest
import yaml

from stratamap.core.errors import DataError
from stratamap.core.pipeline import run_stages
from stratamap.plugins.mappers._volume import TOUCH_STRIDE, frame_list
from stratamap.plugins.mappers.semantic_tsdf import SemanticTSDFMapper
from stratamap.plugins.mappers.tsdf import TSDFMapper
from tests.conftest import REPO

SCENE = {"type": "office", "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 8}}
MAPPERS = {
    "labels": lambda **kw: TSDFMapper(voxel_size=0.05, **kw),
    "masks": lambda **kw: TSDFMapper(voxel_size=0.05, instances="masks", **kw),
    "semantic_tsdf": lambda **kw: SemanticTSDFMapper(voxel_size=0.05, **kw),
}


@pytest.fixture(scope="module")
def labelled():
    from stratamap.plugins.segmenters.oracle import OracleSegmenter
    from stratamap.plugins.sources.synthetic import SyntheticSource

    data = run_stages([SyntheticSource(scene=SCENE), OracleSegmenter()])
    data.stream.frames = list(data.stream.frames)
    return data


def with_frames(data, change: dict[int, dict]):
    """A copy of ``data`` whose frames ``k`` have the fields ``change[k]`` replaced."""
    out = copy.copy(data)
    out.stream = dataclasses.replace(data.stream)
    out.stream.frames = [dataclasses.replace(f, **change.get(f.index, {})) for f in data.stream.frames]
    out.warnings, out.notes = [], {}
    return out


def test_frame_list_names_runs_of_frames():
    assert frame_list([7, 0, 1, 2, 5, 8]) == "0-2, 5, 7-8"
    assert frame_list([3]) == "3"
    assert frame_list(list(range(0, 60, 2))).endswith("22 and 18 more runs of frames")


@pytest.mark.parametrize("mapper", sorted(MAPPERS))
def test_frames_with_nothing_usable_are_skipped_and_named(labelled, mapper):
    """A view down a corridor (nothing within depth_max), a frame with no depth at all, one odometry
    lost and one whose only depth lies between the pixels Open3D samples: each used to abort the
    mapping (Open3D's 'No block is touched in TSDF volume', or a DataError for the pose)."""
    depth = labelled.stream.frames[0].depth
    between = np.zeros_like(depth)
    between[1::TOUCH_STRIDE, 1::TOUCH_STRIDE] = 1.0  # valid depth, none on Open3D's sampling grid
    bad = {
        1: {"pose": None},
        3: {"depth": np.zeros_like(depth)},
        5: {"depth": np.full_like(depth, 9.0)},  # beyond depth_max (5 m)
        6: {"depth": between},
    }
    good = run_stages([MAPPERS[mapper]()], with_frames(labelled, {}))
    data = run_stages([MAPPERS[mapper]()], with_frames(labelled, bad))
    name = "tsdf" if mapper != "semantic_tsdf" else "semantic_tsdf"
    skipped = data.notes[name]["frames_skipped"]
    empty = "no depth within depth_min-depth_max (0.1-5 m)"
    assert skipped == {"no pose (enable odometry, or provide poses)": [1], empty: [3, 5, 6]}
    assert data.notes[name]["frames_integrated"] == 4
    (warning,) = [w for w in data.warnings if w.startswith(f"mappers.{name}:")]
    assert "skipped 4 of 8 frames" in warning and f"3 with {empty} (frames 3, 5-6)" in warning, warning
    assert 0.5 * len(good.map.geometry.points) < len(data.map.geometry.points) <= 1.2 * len(good.map.geometry.points)
    assert (data.map.semantics.class_ids > 0).mean() > 0.8
    assert "frames_skipped" not in good.notes[name] and not good.warnings


@pytest.mark.parametrize("mapper", sorted(MAPPERS))
def test_no_usable_frame_is_one_line_error(labelled, mapper):
    data = with_frames(labelled, {})
    with pytest.raises(DataError) as caught:
        run_stages([MAPPERS[mapper](depth_max=0.11)], data)
    message = str(caught.value)
    assert "\n" not in message
    assert "no usable RGB-D frame in its 8 frames" in message
    assert "8 with no depth within depth_min-depth_max (0.1-0.11 m) (frames 0-7)" in message


def test_frames_of_another_size_are_skipped_and_a_sequence_of_them_says_why(labelled):
    small = {k: {"depth": np.ones((60, 80), np.float32)} for k in (2, 4)}
    data = run_stages([TSDFMapper(voxel_size=0.05)], with_frames(labelled, small))
    assert data.notes["tsdf"]["frames_skipped"] == {"depth 80x60, the intrinsics say 160x120": [2, 4]}
    rgb = {0: {"rgb": np.zeros((60, 80, 3), np.uint8)}}
    data = run_stages([TSDFMapper(voxel_size=0.05)], with_frames(labelled, rgb))
    assert data.notes["tsdf"]["frames_skipped"] == {"a colour image of 80x60, its depth 160x120": [0]}
    unposed = {k: {"pose": None} for k in range(8)}
    with pytest.raises(DataError, match=r"8 with no pose \(enable odometry, or provide poses\) \(frames 0-7\)"):
        run_stages([TSDFMapper(voxel_size=0.05)], with_frames(labelled, unposed))


@pytest.mark.slow  # a whole benchmark or CLI run
def test_the_cli_maps_around_an_empty_frame_and_fails_in_one_line_when_all_are(tmp_path):
    """configs/demo.yaml's mapping on a short synthetic walk: depth_max 0.11 (the schema accepts it)
    leaves no frame, which is exit 2 with one line and no output folder."""
    doc = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())
    doc["source"]["params"]["scene"]["trajectory"]["frames"] = 6
    doc["source"]["params"]["scene"]["camera"] = {"width": 160, "height": 120}
    doc["stages"] = doc["stages"][:2]
    doc["stages"][1]["params"]["voxel_size"] = 0.05
    doc["output"] = {"save_map": False}
    config = tmp_path / "demo.yaml"
    config.write_text(yaml.safe_dump(doc))
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", "run", str(config), "--out", str(out)]
        + ["--set", "stages[1].params.depth_max=0.11"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2, result.stderr
    errors = [line for line in result.stderr.splitlines() if line.strip().startswith("error")]
    assert len(errors) == 1 and "Traceback" not in result.stderr, result.stderr
    assert "tsdf: no usable RGB-D frame in its 6 frames" in errors[0]
    assert not out.exists()


@pytest.mark.slow  # renders and writes a 144-frame orbit (7 s): make test runs it, test-fast does not
def test_odometry_walks_past_a_frame_without_depth_and_the_tsdf_skips_it(tmp_path):
    """A TUM folder without poses: the frame that measured nothing used to stop odometry ('cannot
    track it'); it is left without a pose, tracking goes on from the next frame, the TSDF skips it."""
    from PIL import Image

    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.core.synthetic.writer import write_sequence
    from stratamap.plugins.sources.tum import TUMSource

    spec = {"type": "room", "seed": 4, "camera": {"width": 160, "height": 120}, "trajectory": {"type": "orbit"}}
    spec["trajectory"]["frames"] = 144  # 2.5 degrees between frames, of which the first 10 are read
    seq = write_sequence(SyntheticWorld(SceneSpec.model_validate(spec)), tmp_path / "orbit")
    (seq / "groundtruth.txt").unlink()
    blank = sorted((seq / "depth").glob("*.png"))[5]
    Image.fromarray(np.zeros_like(np.asarray(Image.open(blank)))).save(blank)
    data = run_stages([TUMSource(path=str(seq), gravity="off", max_frames=10), TSDFMapper(voxel_size=0.05)])
    odometry = data.notes["tum"]["odometry"]
    assert odometry["frames_without_depth"] == [5] and odometry["frames"] == 9
    assert [f.pose is None for f in data.stream.frames] == [k == 5 for k in range(10)]
    assert odometry["ate_rmse_m"] < 0.05, odometry  # against gt/trajectory.txt: tracking went on past the gap
    assert data.notes["tsdf"]["frames_skipped"] == {"no depth within depth_min-depth_max (0.1-5 m)": [5]}
    assert any("1 of 10 frames have no valid depth and no pose (frames 5)" in w for w in data.warnings)
