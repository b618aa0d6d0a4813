"""Object detection: precision, recall and F1 of object instances against ground-truth objects.

As in the augmented-representations paper (Table I), a predicted object matches a ground-truth
object of the same class when their centers are closer than ``center_threshold`` or their 3D
boxes overlap with IoU above ``iou_threshold``. Matching is one-to-one (Hungarian, on center
distance), so one ground-truth object cannot justify two detections.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from stratamap.core.geometry import box_iou_3d
from stratamap.core.layers import ObjectInstance, OrientedBox


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
    rows, cols = linear_sum_assignment(cost)
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
