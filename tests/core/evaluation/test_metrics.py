"""Metric families on hand-made cases: average precision, box and mask mAP, frame quality."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.evaluation.bench import detection_by_iou
from stratamap.core.evaluation.detection import MISSED, average_precision, box_map
from stratamap.core.evaluation.panoptic import frame_quality, instance_map, panoptic_quality
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


def test_detection_by_iou_says_what_each_true_object_was_called():
    """A table found as a table, a cabinet found but called a counter, a cup missed, and a stray box
    that matches nothing: the class-aware F1 loses the counter, the cup and the box."""
    table = OrientedBox(np.array([0, 0, 0.4]), 0.0, np.array([1.2, 0.8, 0.75]))
    cabinet = OrientedBox(np.array([3, 0, 0.45]), 0.0, np.array([1.0, 0.6, 0.9]))
    cup = OrientedBox(np.array([0, 0, 0.8]), 0.0, np.array([0.08, 0.08, 0.1]))
    gts = [GT("table", table), GT("cabinet", cabinet), GT("cup", cup)]
    shifted = OrientedBox(cabinet.center + [0.1, 0, 0], 0.0, cabinet.size)
    stray = OrientedBox(np.array([-2, 2, 0.2]), 0.0, np.array([0.3, 0.3, 0.3]))
    preds = [
        ObjectInstance(1, "table", np.zeros((1, 3)), table),
        ObjectInstance(2, "counter", np.zeros((1, 3)), shifted),
        ObjectInstance(3, "box", np.zeros((1, 3)), stray),
    ]
    labels = detection_by_iou(preds, gts)[1]
    assert labels["called"] == {"table": {"table": 1}, "cabinet": {"counter": 1}, "cup": {MISSED: 1}}
    assert labels["extra"] == {"box": 1}
    # A box too far off its object (IoU < 0.25) is no match: the object is missed, the box extra.
    far = OrientedBox(cabinet.center + [0.8, 0, 0], 0.0, cabinet.size)
    labels = detection_by_iou([ObjectInstance(2, "cabinet", np.zeros((1, 3)), far)], [GT("cabinet", cabinet)])[1]
    assert labels == {"called": {"cabinet": {MISSED: 1}}, "extra": {"cabinet": 1}}


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


def test_pq_of_a_kind_no_segment_has_is_undefined_not_zero():
    vocab = Vocabulary.default()
    chair, table, floor = vocab.id("chair"), vocab.id("table"), vocab.id("floor")
    # Things only, in the truth and the prediction: no stuff segment either way.
    gt_c = np.array([chair] * 10 + [table] * 10)
    gt_i = np.array([1] * 10 + [2] * 10)
    res = panoptic_quality(gt_c, gt_i + 4, gt_c, gt_i, vocab)
    assert res["pq"] == pytest.approx(1.0) and res["pq_things"] == pytest.approx(1.0)
    assert res["pq_stuff"] is None
    assert set(res["by_class"]) == {"chair", "table"}
    # Stuff only: PQ of things is undefined.
    floor_only = np.full(8, floor)
    res = panoptic_quality(floor_only, np.zeros(8), floor_only, np.zeros(8), vocab)
    assert res["pq_stuff"] == pytest.approx(1.0) and res["pq_things"] is None
    # A stuff class the prediction invents counts (PQ over classes in the truth or the prediction).
    pred_c = gt_c.copy()
    pred_c[:3] = floor
    res = panoptic_quality(pred_c, gt_i + 4, gt_c, gt_i, vocab)
    assert res["pq_stuff"] == pytest.approx(0.0) and res["by_class"]["floor"]["fp"] == 1
    # Nothing at all: every average is undefined.
    empty = np.zeros(0, np.int64)
    res = panoptic_quality(empty, empty, empty, empty, vocab)
    assert res["pq"] is None and res["sq"] is None and res["pq_things"] is None and res["pq_stuff"] is None


def test_frame_quality_without_stuff_reports_none():
    vocab = Vocabulary.default()
    chair = vocab.id("chair")
    cls = np.array([[0, 0, chair, chair]] * 2, np.uint16)
    inst = np.array([[0, 0, 1, 1]] * 2, np.int32)
    q = frame_quality([FrameSegmentation(0, cls.copy(), inst * 3)], [FrameSegmentation(0, cls, inst)], vocab, stride=1)
    assert q["pq_things"] == pytest.approx(1.0) and q["pq_stuff"] is None
    assert q["miou"] == pytest.approx(1.0)
    unknown = np.zeros((2, 4), np.uint16)
    q = frame_quality(
        [FrameSegmentation(0, unknown.copy(), np.zeros((2, 4), np.int32))],
        [FrameSegmentation(0, unknown, np.zeros((2, 4), np.int32))],
        vocab,
        stride=1,
    )
    assert q["miou"] is None and q["pq"] is None
