"""Metric families on hand-made cases: average precision, box and mask mAP, frame quality."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.evaluation.detection import average_precision, box_map
from stratamap.core.evaluation.panoptic import frame_quality, instance_map
from stratamap.core.map.layers import ObjectInstance, OrientedBox, Semantics
from stratamap.core.map.sensors import FrameSegmentation
from stratamap.core.map.vocabulary import Vocabulary


class GT:
    def __init__(self, cls, box):
        self.class_name, self._box = cls, box

    def box(self):
        return self._box


def test_average_precision_by_hand():
    assert average_precision(np.array([0.9, 0.8]), np.array([True, True]), 2) == pytest.approx(1.0)
    # A false positive ranked first: precision 1/2 when the only object is found.
    assert average_precision(np.array([0.9, 0.8]), np.array([False, True]), 1) == pytest.approx(0.5)
    # Half the objects never found.
    assert average_precision(np.array([0.9]), np.array([True]), 2) == pytest.approx(0.5)


def test_box_map_uses_3d_iou_and_refined_boxes():
    a = OrientedBox(np.array([0, 0, 0.5]), 0.0, np.array([1.0, 1.0, 1.0]))
    b = OrientedBox(np.array([3, 0, 0.5]), 0.3, np.array([0.5, 0.5, 1.0]))
    gts = [GT("table", a), GT("chair", b)]
    exact = [ObjectInstance(1, "table", np.zeros((1, 3)), a), ObjectInstance(2, "chair", np.zeros((1, 3)), b)]
    assert box_map(exact, gts) == pytest.approx(1.0)
    # The chair seen only from above: its box is the top 40%; refining it down to the floor recovers it.
    top = OrientedBox(np.array([3, 0, 0.8]), 0.3, np.array([0.5, 0.5, 0.4]))
    partial = [exact[0], ObjectInstance(2, "chair", np.zeros((1, 3)), top)]
    assert box_map(partial, gts) == pytest.approx(0.5)
    assert box_map(partial, gts, boxes={2: b}) == pytest.approx(1.0)


def test_instance_map_on_point_masks():
    vocab = Vocabulary.default()
    chair = vocab.id("chair")
    pred_inst = np.array([1, 1, 1, 1, 2, 2, 2, 2, 0, 0])
    sem = Semantics(np.where(pred_inst > 0, chair, 0).astype(np.int32), pred_inst.astype(np.int32), vocab)
    gt_inst = np.array([5, 5, 5, 5, 6, 6, 6, 6, 6, 6])
    gt_cls = np.full(10, chair)
    # Instance 2 covers 4 of the 6 points of object 6: IoU 0.67 >= 0.5, a hit.
    assert instance_map(sem, None, gt_cls, gt_inst) == pytest.approx(1.0)
    assert instance_map(sem, None, gt_cls, gt_inst, threshold=0.7) == pytest.approx(0.5)


def test_frame_quality_miou_and_pq():
    vocab = Vocabulary.default()
    floor, chair = vocab.id("floor"), vocab.id("chair")
    truth_cls = np.array([[floor, floor, chair, chair]] * 2, np.uint16)
    truth_inst = np.array([[0, 0, 1, 1]] * 2, np.int32)
    truth = [FrameSegmentation(0, truth_cls, truth_inst)]
    perfect = frame_quality([FrameSegmentation(0, truth_cls.copy(), truth_inst * 7)], truth, vocab, stride=1)
    assert perfect["miou"] == pytest.approx(1.0) and perfect["pq"] == pytest.approx(1.0)
    wrong_cls = truth_cls.copy()
    wrong_cls[:, 3] = floor  # half the chair called floor
    half = frame_quality(
        [FrameSegmentation(0, wrong_cls, np.where(wrong_cls == chair, 1, 0).astype(np.int32))], truth, vocab, stride=1
    )
    # IoU floor = 4/6, chair = 2/4.
    assert half["miou"] == pytest.approx((4 / 6 + 2 / 4) / 2)
