"""Object detection: precision, recall and F1 of object instances against ground-truth objects.

As in the augmented-representations paper (Table I), a predicted object matches a ground-truth
object of the same class when their centers are closer than ``center_threshold`` or their 3D
boxes overlap with IoU above ``iou_threshold``. Matching is one-to-one (Hungarian, on center
distance), so one ground-truth object cannot justify two detections.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from stratamap.core.geometry.boxes import box_iou_3d
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ObjectInstance, OrientedBox

optimize = lazy_module("scipy.optimize")


def prf(tp: int, n_pred: int, n_gt: int) -> dict[str, float]:
    precision = tp / n_pred if n_pred else (1.0 if n_gt == 0 else 0.0)
    recall = tp / n_gt if n_gt else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {"precision": precision, "recall": recall, "f1": f1}


def match_boxes(
    pred: Sequence[tuple[str, OrientedBox]],
    gt: Sequence[tuple[str, OrientedBox]],
    center_threshold: float = 0.3,
    iou_threshold: float = 0.25,
) -> list[tuple[int, int]]:
    """One-to-one matches ``(pred_index, gt_index)`` of same-class boxes that are close enough."""
    if not pred or not gt:
        return []
    big = 1e6
    cost = np.full((len(pred), len(gt)), big)
    for i, (pc, pb) in enumerate(pred):
        for j, (gc, gb) in enumerate(gt):
            if pc != gc:
                continue
            d = float(np.linalg.norm(pb.center - gb.center))
            if d < center_threshold or box_iou_3d(pb, gb) > iou_threshold:
                cost[i, j] = d
    rows, cols = optimize.linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < big]


def evaluate_instances(
    instances: Iterable[ObjectInstance],
    gt_objects: Iterable[Any],
    center_threshold: float = 0.3,
    iou_threshold: float = 0.25,
) -> dict[str, Any]:
    pred = [(i.class_name, i.box) for i in instances]
    gt = [(o.class_name, o.box()) for o in gt_objects]
    matches = match_boxes(pred, gt, center_threshold, iou_threshold)
    out: dict[str, Any] = prf(len(matches), len(pred), len(gt))
    out.update({"true_positives": len(matches), "predicted": len(pred), "ground_truth": len(gt)})
    by_class: dict[str, dict[str, float]] = {}
    for cls in sorted({c for c, _ in gt} | {c for c, _ in pred}):
        tp = sum(1 for i, _ in matches if pred[i][0] == cls)
        by_class[cls] = prf(tp, sum(1 for c, _ in pred if c == cls), sum(1 for c, _ in gt if c == cls))
    out["by_class"] = by_class
    return out


#: The label of a true object no prediction's box matched.
MISSED = "(missed)"


def labels_of_matches(
    pred: Sequence[tuple[str, Any]], gt: Sequence[tuple[str, Any]], matches: Sequence[tuple[int, int]]
) -> dict[str, Any]:
    """What each true object was called, from class-agnostic ``matches`` (pred_index, gt_index) of
    ``(class, box)`` lists (the class-agnostic F1's): ``called[true class][predicted class]`` counts
    the matches, ``MISSED`` the true objects no box matched, and ``extra[predicted class]`` the
    predictions that matched nothing. Class-aware F1 is lost where a true class was called another
    or missed, and where predictions are extra."""
    called: dict[str, Counter[str]] = defaultdict(Counter)
    for pi, gi in matches:
        called[gt[gi][0]][pred[pi][0]] += 1
    matched_gt, matched_pred = {gi for _, gi in matches}, {pi for pi, _ in matches}
    for gi, (cls, _) in enumerate(gt):
        if gi not in matched_gt:
            called[cls][MISSED] += 1
    extra = Counter(cls for pi, (cls, _) in enumerate(pred) if pi not in matched_pred)
    return {"called": dict(called), "extra": extra}


def sum_labels(labels: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """``labels_of_matches`` of many runs added up: ``called[true class][name]`` and ``extra[name]``."""
    called: dict[str, Counter[str]] = defaultdict(Counter)
    extra: Counter[str] = Counter()
    for one in labels:
        for true, row in one["called"].items():
            called[true].update(row)
        extra.update(one["extra"])
    return {"called": dict(called), "extra": extra}


def average_precision(scores: np.ndarray, hits: np.ndarray, n_gt: int) -> float:
    """Area under the interpolated precision-recall curve (all points, as PASCAL VOC 2010+)."""
    if n_gt == 0:
        return float("nan")
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-np.asarray(scores), kind="stable")
    tp = np.cumsum(np.asarray(hits, bool)[order])
    fp = np.cumsum(~np.asarray(hits, bool)[order])
    recall = tp / n_gt
    precision = tp / np.maximum(tp + fp, 1)
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    steps = np.flatnonzero(mrec[1:] != mrec[:-1])
    return float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))


def mean_average_precision(
    pred: Sequence[tuple[str, float, Any]], gt: Sequence[tuple[str, Any]], iou, threshold: float = 0.5
) -> dict[str, Any]:
    """mAP over the classes with ground truth: predictions ``(class, score, item)`` are taken by
    decreasing score and match the unmatched ground truth ``(class, item)`` of their class with the
    highest ``iou(item, gt_item)`` at or above ``threshold``."""
    by_class: dict[str, float] = {}
    for cls in sorted({c for c, _ in gt}):
        preds = sorted([(s, item) for c, s, item in pred if c == cls], key=lambda t: -t[0])
        truths = [item for c, item in gt if c == cls]
        used = np.zeros(len(truths), bool)
        hits = []
        for _, item in preds:
            ious = np.array([iou(item, t) if not used[k] else -1.0 for k, t in enumerate(truths)])
            k = int(np.argmax(ious)) if len(ious) else -1
            hit = k >= 0 and ious[k] >= threshold
            if hit:
                used[k] = True
            hits.append(hit)
        by_class[cls] = average_precision(np.array([s for s, _ in preds]), np.array(hits, bool), len(truths))
    values = [v for v in by_class.values() if np.isfinite(v)]
    return {"map": float(np.mean(values)) if values else 0.0, "by_class": by_class}


def box_map(
    instances: Iterable[ObjectInstance],
    gt_objects: Iterable[Any],
    threshold: float = 0.5,
    boxes: dict[int, OrientedBox] | None = None,
) -> float:
    """Oriented 3D box mAP at IoU ``threshold`` (functional-scenes paper, Tables 3-4); ``boxes``
    replaces an instance's box by id (e.g. the support-refined boxes of the contact graph)."""
    boxes = boxes or {}
    pred = [(i.class_name, float(i.score), boxes.get(i.id, i.box)) for i in instances]
    gt = [(o.class_name, o.box()) for o in gt_objects]
    return mean_average_precision(pred, gt, box_iou_3d, threshold)["map"]
