"""Labelling only keyframes (issue 68): frames that see enough new surface are labelled, every frame is
still fused, and the mappers and the frame metrics pass over the frames left unlabelled."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.map.keyframes import KeyframeChooser
from stratamap.core.map.sensors import CameraIntrinsics, FrameSegmentation
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.plugins.mappers.tsdf import TSDFMapper
from stratamap.plugins.segmenters.detector import DetectorSegmenter

INTRINSICS = CameraIntrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)


def wall_pose(yaw_deg: float) -> np.ndarray:
    """A camera at the origin looking along the horizontal direction ``yaw_deg`` (optical z forward)."""
    yaw = np.radians(yaw_deg)
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, forward)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward], axis=1)
    return pose


def test_a_camera_that_looks_at_the_same_wall_labels_one_frame_and_a_turn_labels_another():
    depth = np.full((48, 64), 2.05, np.float32)  # mid-cell: no point on a cell boundary
    choose = KeyframeChooser(INTRINSICS, new_surface=0.2)
    chosen = [choose(depth, wall_pose(yaw)) for yaw in (0.0, 0.0, 1.0, 0.0, 90.0, 90.0)]
    assert chosen == [True, False, False, False, True, False]


def test_views_labels_the_same_surface_from_that_many_frames():
    """A slow walk sees each surface in dozens of frames; with ``views`` 3 the first three frames of a
    wall are labelled, then none until the camera turns to a wall no frame labelled."""
    depth = np.full((48, 64), 2.05, np.float32)  # mid-cell: no point on a cell boundary
    choose = KeyframeChooser(INTRINSICS, new_surface=0.2, views=3)
    chosen = [choose(depth, wall_pose(yaw)) for yaw in (0.0, 0.0, 0.0, 0.0, 90.0, 90.0, 90.0, 90.0)]
    assert chosen == [True, True, True, False, True, True, True, False]


def test_zero_new_surface_labels_every_frame_and_no_depth_is_no_keyframe():
    depth = np.full((48, 64), 2.05, np.float32)  # mid-cell: no point on a cell boundary
    every = KeyframeChooser(INTRINSICS, new_surface=0.0)
    assert all(every(depth, wall_pose(0.0)) for _ in range(3))
    choose = KeyframeChooser(INTRINSICS, new_surface=0.2)
    assert not choose(np.zeros((48, 64), np.float32), wall_pose(0.0))
    assert choose(depth, wall_pose(0.0))


def test_an_unlabelled_frame_says_so():
    assert not FrameSegmentation.unlabelled(3).labelled
    assert FrameSegmentation(3, np.ones((2, 2), np.uint16), np.zeros((2, 2), np.int32)).labelled


@pytest.fixture(scope="module")
def walk() -> PipelineData:
    spec = SceneSpec.model_validate(
        {
            "type": "office",
            "seed": 0,
            "camera": {"width": 160, "height": 120},
            "trajectory": {"type": "walk", "frames": 16},
        }
    )
    world = SyntheticWorld(spec)
    stream = world.stream()
    stream.frames = list(stream.frames)
    return PipelineData(stream=stream, ground_truth=world.ground_truth())


def test_the_detector_labels_keyframes_only_and_the_tsdf_fuses_every_frame(walk):
    data = PipelineData(stream=walk.stream, ground_truth=walk.ground_truth)
    detector = DetectorSegmenter(keyframes={"new_surface": 0.3})
    labels = detector.run(data)["frame_labels"]
    labelled = [seg.labelled for seg in labels.frames]
    assert len(labelled) == len(walk.stream.frames) and labelled[0]
    assert 1 < sum(labelled) < len(labelled)
    assert data.notes["detector"]["keyframes"] == {
        "labelled": sum(labelled),
        "frames": 16,
        "new_surface": 0.3,
        "views": 1,
    }
    data.frame_labels = labels
    out = TSDFMapper(voxel_size=0.04).run(data)
    assert len(out["geometry"]) > 0
    assert (np.asarray(out["semantics"].class_ids) > 0).any()


def test_frame_quality_passes_over_unlabelled_frames(walk):
    from stratamap.core.evaluation.panoptic import frame_quality

    truth = list(walk.ground_truth.frame_labels)
    vocab = walk.ground_truth.vocabulary
    half = [seg if k % 2 == 0 else FrameSegmentation.unlabelled(seg.frame_index) for k, seg in enumerate(truth)]
    scored = frame_quality(half, truth, vocab, stride=1)
    assert scored == frame_quality(truth[::2], truth[::2], vocab, stride=1)


def test_reading_and_detecting_ahead_in_a_thread_gives_the_labels_of_one_loop(walk):
    """The detector reads and detects frames ahead of the depth segmentation in a thread (issue 68);
    with keyframes, whose chooser keeps state from frame to frame, the labels are those of one loop."""
    runs = []
    for read_ahead in (0, 3):
        data = PipelineData(stream=walk.stream, ground_truth=walk.ground_truth)
        detector = DetectorSegmenter(keyframes={"new_surface": 0.3}, read_ahead=read_ahead)
        runs.append(list(detector.run(data)["frame_labels"].frames))
    serial, ahead = runs
    assert [seg.labelled for seg in serial] == [seg.labelled for seg in ahead]
    for a, b in zip(serial, ahead, strict=True):
        assert a.frame_index == b.frame_index
        assert np.array_equal(a.class_ids, b.class_ids) and np.array_equal(a.instance_ids, b.instance_ids)
