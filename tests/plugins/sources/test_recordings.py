"""The `recordings` source: several recordings of one place as one stream (a map built in parts)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.errors import ConfigError, DataError
from stratamap.core.stages import PipelineData
from stratamap.plugins.sources.recordings import RecordingsSource
from stratamap.plugins.sources.synthetic import SyntheticSource

SCENE = {"camera": {"width": 64, "height": 48}, "trajectory": {"frames": 12}, "noise": {"depth": "none"}}


def _read(source) -> dict:
    return source.run(PipelineData())


def _part(start: int, stop: int, scene: dict = SCENE) -> dict:
    return {"plugin": "synthetic", "params": {"scene": scene, "frame_range": [start, stop]}}


def test_two_parts_of_a_walk_read_as_the_whole_walk():
    whole = _read(SyntheticSource(scene=SCENE))
    parts = _read(RecordingsSource(recordings=[_part(0, 5), _part(5, 12)]))
    stream, gt = parts["frames"], parts["ground_truth"]
    assert len(stream) == len(whole["frames"]) == 12
    assert [f.index for f in stream.frames] == list(range(12))
    for mine, theirs in zip(stream.frames, whole["frames"].frames, strict=True):
        assert np.array_equal(mine.depth, theirs.depth) and np.array_equal(mine.pose, theirs.pose)
    # Labels stay aligned with frames, renumbered with them; scans and true poses follow in order.
    assert [s.frame_index for s in gt.frame_labels] == list(range(12))
    assert np.array_equal(gt.frame_labels[7].instance_ids, whole["ground_truth"].frame_labels[7].instance_ids)
    assert len(stream.laser_scans) == 12
    assert np.allclose(gt.layout["true_poses"], whole["ground_truth"].layout["true_poses"])
    assert [o.id for o in gt.objects] == [o.id for o in whole["ground_truth"].objects]
    assert stream.metadata["recordings"] == [
        {"name": whole["frames"].name, "frames": 5},
        {"name": whole["frames"].name, "frames": 7},
    ]


def test_recordings_in_another_order_concatenate_in_that_order():
    parts = _read(RecordingsSource(recordings=[_part(6, 12), _part(0, 6)]))
    whole = _read(SyntheticSource(scene=SCENE))
    assert np.array_equal(parts["frames"].frames[0].depth, whole["frames"].frames[6].depth)
    assert parts["frames"].frames[0].index == 0
    assert np.array_equal(
        parts["ground_truth"].frame_labels[6].class_ids, whole["ground_truth"].frame_labels[0].class_ids
    )


def test_bad_recordings_are_named_by_key():
    with pytest.raises(ConfigError, match=r"recordings\[1\]\.plugin: no source named 'nope'"):
        _read(RecordingsSource(recordings=[_part(0, 5), {"plugin": "nope"}]))
    with pytest.raises(ConfigError, match=r"recordings\[0\]\.params\.frame_rang: extra field"):
        _read(RecordingsSource(recordings=[{"plugin": "synthetic", "params": {"frame_rang": [0, 2]}}]))
    with pytest.raises(ConfigError, match=r"frame_range: \[5, 40\) is not a range of the trajectory's 12 frames"):
        _read(RecordingsSource(recordings=[_part(5, 40)]))
    other_camera = {**SCENE, "camera": {"width": 80, "height": 60}}
    with pytest.raises(DataError, match=r"recordings\[1\].*intrinsics"):
        _read(RecordingsSource(recordings=[_part(0, 5), _part(5, 12, other_camera)]))
