"""A whole floor: a map fused from two recordings equals the one-recording map; the tour finds every object."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from stratamap.core.evaluation.detection import evaluate_instances
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.tsdf import TSDFMapper
from stratamap.plugins.segmenters.oracle import OracleSegmenter
from stratamap.plugins.sources.recordings import RecordingsSource
from stratamap.plugins.sources.synthetic import SyntheticSource

OFFICE = {
    "type": "office",
    "camera": {"width": 320, "height": 240},
    "trajectory": {"frames": 80},
    "noise": {"depth": "kinect"},
}


def _map(source) -> PipelineData:
    return run_stages([source, OracleSegmenter(), TSDFMapper(voxel_size=0.03, extract_mesh=False)])


def test_two_halves_of_a_walk_fuse_into_the_whole_walks_map():
    whole = _map(SyntheticSource(scene=OFFICE))
    halves = [{"plugin": "synthetic", "params": {"scene": OFFICE, "frame_range": r}} for r in ([40, 80], [0, 40])]
    fused = _map(RecordingsSource(recordings=halves))
    a, b = whole.map.geometry.points, fused.map.geometry.points
    # The second half first: TSDF averages commute, so the surfaces agree to well under a voxel.
    assert abs(len(a) - len(b)) < 0.02 * len(a)
    gap_ab, _ = cKDTree(b).query(a)
    gap_ba, _ = cKDTree(a).query(b)
    assert np.mean(gap_ab) < 0.005 and np.mean(gap_ba) < 0.005
    assert np.quantile(gap_ab, 0.99) <= 0.03 + 1e-9
    # The same objects, found as well from the two recordings as from one.
    gt = whole.ground_truth.objects
    one, two = evaluate_instances(whole.map.instances, gt), evaluate_instances(fused.map.instances, gt)
    assert two["true_positives"] >= one["true_positives"] - 1
    assert abs(len(fused.map.instances) - len(whole.map.instances)) <= 1


@pytest.mark.parametrize("rooms", ["rooms-4"])
def test_the_tour_finds_every_object_of_four_rooms_with_the_oracle(rooms):
    """Detection recall of the oracle pipeline on the 4-room scene of configs/bench/scaling.yaml (at half
    the resolution and half the frames, to keep the test short): the walk found 39 of 80."""
    scene = {
        "type": "office",
        "room_size": [13.0, 11.0, 2.7],
        "objects": {
            "desk": 12,
            "chair": 16,
            "monitor": 12,
            "cabinet": 8,
            "shelf": 4,
            "table": 4,
            "book": 12,
            "cup": 12,
        },
        "camera": {"width": 320, "height": 240},
        "trajectory": {"type": "tour", "frames": 240},
        "noise": {"depth": "kinect"},
        "ground_truth": {"coverage": True},
    }
    data = run_stages(
        [SyntheticSource(scene=scene), OracleSegmenter(), TSDFMapper(voxel_size=0.02, extract_mesh=False)]
    )
    gt = data.ground_truth
    assert gt.layout["coverage"]["objects_seen"] == len(gt.objects) == 80
    detection = evaluate_instances(data.map.instances, gt.objects)
    assert detection["recall"] >= 0.95, detection["by_class"]
