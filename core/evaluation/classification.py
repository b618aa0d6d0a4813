"""Plane and furniture classification in the form of the kitchen paper's Table IV.

* ``horizontal`` (floor, table, ceiling) and ``vertical`` (wall, furniture): one decision per
  predicted planar segment; its true label is the majority of its points' labels.
* ``furniture`` (cupboard, drawer, appliance; panel reported too): one decision per true front
  (a door, drawer or appliance face seen by at least ``min_points`` points); its predicted label
  is the majority of the predicted labels on its points (``none`` when they are not furniture).
* ``hinge``: for every true door, the hinge side of the predicted front covering most of it.

Precision, recall and F1 per label; ``macro_f1`` averages F1 over the group's labels (for
furniture: cupboard, drawer and appliance, as in the contract of the benchmark).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.simulation.virtual_scan import (
    LEVEL1,
    LEVEL1_CLASS,
    LEVEL1_HORIZONTAL,
    LEVEL1_VERTICAL,
    LEVEL2,
    LEVEL2_CLASS,
)

FURNITURE_MACRO = ("cupboard", "drawer", "appliance")


def per_label(
    pred: list[str], truth: list[str], labels: tuple[str, ...], macro_over: tuple[str, ...] | None = None
) -> dict[str, Any]:
    """Precision, recall, F1 and support per label, and the macro F1 over ``macro_over`` (default all)."""
    pred_a, truth_a = np.asarray(pred, dtype=object), np.asarray(truth, dtype=object)
    out: dict[str, Any] = {}
    for c in labels:
        tp = int(np.sum((pred_a == c) & (truth_a == c)))
        n_pred, n_true = int(np.sum(pred_a == c)), int(np.sum(truth_a == c))
        p = tp / n_pred if n_pred else 0.0
        r = tp / n_true if n_true else 0.0
        out[c] = {
            "precision": p,
            "recall": r,
            "f1": 2 * p * r / (p + r) if p + r else 0.0,
            "support": n_true,
            "predicted": n_pred,
        }
    over = [c for c in (macro_over or labels) if out[c]["support"] > 0 or out[c]["predicted"] > 0]
    out["macro_f1"] = float(np.mean([out[c]["f1"] for c in over])) if over else 0.0
    return out


def _mode(values: np.ndarray) -> int:
    values = values[values >= 0]
    return int(np.bincount(values).argmax()) if len(values) else -1


def kitchen_tables(
    pred_level1: np.ndarray,
    pred_segment: np.ndarray,
    pred_level2: np.ndarray,
    pred_front: np.ndarray,
    pred_hinge: dict[int, str | None],
    true_level1: np.ndarray,
    true_level2: np.ndarray,
    true_front: np.ndarray,
    true_fronts: list[dict],
    min_points: int = 30,
) -> dict[str, Any]:
    """Table IV from per-point labels (indices into LEVEL1 / LEVEL2, -1 none), segment and front ids."""
    seg_pred, seg_true = [], []
    for s in np.unique(pred_segment[pred_segment >= 0]):
        mask = pred_segment == s
        t = _mode(true_level1[mask])
        if t < 0:
            continue
        p = _mode(pred_level1[mask])
        seg_pred.append(LEVEL1[p] if p >= 0 else "none")
        seg_true.append(LEVEL1[t])
    horiz_idx = [k for k, t in enumerate(seg_true) if t in LEVEL1_HORIZONTAL or seg_pred[k] in LEVEL1_HORIZONTAL]
    vert_idx = [k for k, t in enumerate(seg_true) if t in LEVEL1_VERTICAL or seg_pred[k] in LEVEL1_VERTICAL]
    out: dict[str, Any] = {
        "horizontal": per_label([seg_pred[k] for k in horiz_idx], [seg_true[k] for k in horiz_idx], LEVEL1_HORIZONTAL),
        "vertical": per_label([seg_pred[k] for k in vert_idx], [seg_true[k] for k in vert_idx], LEVEL1_VERTICAL),
        "segments": len(seg_true),
    }
    f_pred, f_true, doors, correct, hinge_rows = [], [], 0, 0, []
    for k, front in enumerate(true_fronts):
        kind = front["kind"]
        mask = (true_front == k) & (true_level2 == LEVEL2.index(kind))
        if mask.sum() < min_points:
            continue
        p = _mode(pred_level2[mask])
        f_true.append(kind)
        f_pred.append(LEVEL2[p] if p >= 0 else "none")
        if front.get("joint_type") == "revolute" and front.get("hinge"):
            doors += 1
            cover = _mode(pred_front[mask])
            guess = pred_hinge.get(cover) if cover >= 0 else None
            correct += int(guess == front["hinge"])
            hinge_rows.append({"front": front["name"], "true": front["hinge"], "predicted": guess})
    out["furniture"] = per_label(f_pred, f_true, LEVEL2, macro_over=FURNITURE_MACRO)
    out["furniture"]["fronts"] = len(f_true)
    out["hinge"] = {
        "doors": doors,
        "correct": correct,
        "accuracy": correct / doors if doors else 0.0,
        "by_door": hinge_rows,
    }
    return out


def format_table(tables: dict[str, Any]) -> str:
    """Markdown in the layout of the paper's Table IV: label, precision, recall, F1, support."""
    lines = ["| group | label | precision | recall | F1 | support |", "|---|---|---|---|---|---|"]
    for group, labels in (("horizontal", LEVEL1_HORIZONTAL), ("vertical", LEVEL1_VERTICAL), ("furniture", LEVEL2)):
        t = tables[group]
        for c in labels:
            r = t[c]
            lines.append(
                f"| {group} | {c} | {r['precision']:.2f} | {r['recall']:.2f} | {r['f1']:.2f} | {r['support']} |"
            )
        lines.append(f"| {group} | **macro F1** | | | **{t['macro_f1']:.2f}** | |")
    h = tables["hinge"]
    lines.append(f"| hinge | doors correct | | | **{h['accuracy']:.2f}** | {h['correct']}/{h['doors']} |")
    return "\n".join(lines)


def tables_from_map(m, scan_points: np.ndarray, kitchen: dict[str, Any]) -> dict[str, Any]:
    """Table IV for a map labelled by a plane segmenter, against the per-point ground truth of
    a ``urdf_scan`` source (``kitchen``: its ``ground_truth.layout["kitchen_scan"]``)."""
    from scipy.spatial import cKDTree

    sem = m.semantics
    vocab = sem.vocabulary
    names = np.array(vocab.names, dtype=object)[sem.class_ids]
    to2 = {cls: LEVEL2.index(lab) for lab, cls in LEVEL2_CLASS.items()}
    to1 = {cls: LEVEL1.index(lab) for lab, cls in LEVEL1_CLASS.items()} | dict.fromkeys(to2, LEVEL1.index("furniture"))
    pred1 = np.array([to1.get(n, -1) for n in names], np.int64)
    pred2 = np.array([to2.get(n, -1) for n in names], np.int64)
    pred_front = np.where(pred2 >= 0, sem.instance_ids, -1).astype(np.int64)
    hinge = {inst.id: inst.attributes.get("hinge") for inst in (m.instances or [])}
    t1, t2, tf = (np.asarray(kitchen[k]) for k in ("level1", "level2", "front"))
    pts = np.asarray(m.geometry.points)
    if len(pts) != len(scan_points) or not np.allclose(
        pts[:: max(1, len(pts) // 1000)], scan_points[:: max(1, len(pts) // 1000)]
    ):
        _, nearest = cKDTree(scan_points).query(pts)
        t1, t2, tf = t1[nearest], t2[nearest], tf[nearest]
    return kitchen_tables(
        pred1, sem.plane_ids.astype(np.int64), pred2, pred_front, hinge, t1, t2, tf, list(kitchen["fronts"])
    )
