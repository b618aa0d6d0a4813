"""Completion quality: the completed shape against the ground-truth full shape.

For every detected object matched to a ground-truth object (see ``detection``), both shapes are
sampled at the same spacing: the completion's world mesh (or, with no completion, the observed
points: the ``none`` baseline) and the ground truth's full mesh. Reported per object and as medians:

* Chamfer-L1 (mean of both directions' mean nearest distances) and Chamfer-L2 (squared);
* F-score at 1, 2 and 5 cm (harmonic mean of the shares of each set within the threshold);
* pose: translation error and yaw error (completions placed from a model only; boxes and raw
  points have no orientation of their own), and Scan2CAD accuracy (translation <= 20 cm,
  rotation <= 20 deg, scale within 20%);
* visibility: the share of the ground-truth surface within 3 cm of an observed point.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from stratamap.core.evaluation.detection import match_boxes
from stratamap.core.geometry.transforms import wrap_angle, yaw_of
from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import ObjectInstance, ObjectInstances

THRESHOLDS = (0.01, 0.02, 0.05)


def sample_mesh(mesh: trimesh.Trimesh, spacing: float, seed: int = 0) -> np.ndarray:
    count = int(np.clip(mesh.area / spacing**2, 200, 30000))
    return np.asarray(trimesh.sample.sample_surface(mesh, count, seed=seed)[0])


def thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """One point per ``spacing`` voxel (deterministic), so raw observations match mesh samples' density."""
    if len(points) == 0:
        return points
    keys = np.floor(points / spacing).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def shape_distances(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    d_pg = cKDTree(gt).query(pred)[0]
    d_gp = cKDTree(pred).query(gt)[0]
    out = {
        "chamfer_l1": float((d_pg.mean() + d_gp.mean()) / 2),
        "chamfer_l2": float(((d_pg**2).mean() + (d_gp**2).mean()) / 2),
    }
    for tau in THRESHOLDS:
        p, r = float((d_pg < tau).mean()), float((d_gp < tau).mean())
        out[f"fscore_{int(round(tau * 100))}cm"] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return out


def evaluate_completion(
    instances: ObjectInstances, gt_objects: list[GroundTruthObject], spacing: float = 0.01
) -> dict[str, Any]:
    insts = list(instances)
    pred = [(i.class_name, i.box) for i in insts]
    gts = [(o.class_name, o.box()) for o in gt_objects]
    per_object = []
    for pi, gi in match_boxes(pred, gts):
        inst: ObjectInstance = insts[pi]
        gt = gt_objects[gi]
        gt_mesh = gt.world_mesh()
        gt_pts = sample_mesh(gt_mesh, spacing, seed=gt.id)
        if inst.completion is not None:
            pred_pts = sample_mesh(inst.completion.world_mesh(), spacing, seed=inst.id)
        else:
            pred_pts = thin(inst.points, spacing)
        rec: dict[str, Any] = {
            "id": inst.id,
            "gt_id": gt.id,
            "class": gt.class_name,
            **shape_distances(pred_pts, gt_pts),
        }
        rec["visibility"] = float((cKDTree(inst.points).query(gt_pts)[0] < 0.03).mean()) if len(inst.points) else 0.0
        c = inst.completion
        if c is not None and c.model_id is not None:
            t_err = float(np.linalg.norm(c.pose[:3, 3] - gt.pose[:3, 3]))
            yaw_err = float(np.degrees(abs(wrap_angle(yaw_of(c.pose) - yaw_of(gt.pose)))))
            ratio = float(np.mean(c.world_mesh().extents / np.maximum(gt_mesh.extents, 1e-6)))
            rec.update({"translation_error_m": t_err, "yaw_error_deg": yaw_err, "scale_ratio": ratio})
            rec["scan2cad"] = bool(t_err <= 0.2 and yaw_err <= 20.0 and abs(ratio - 1) <= 0.2)
            rec["model_id"] = c.model_id
            rec["same_family"] = c.model_id.startswith(gt.family + "_") if gt.family else None
        per_object.append(rec)

    def median(key: str, rows: list[dict]) -> float | None:
        vals = [r[key] for r in rows if r.get(key) is not None]
        return float(np.median(vals)) if vals else None

    out: dict[str, Any] = {"objects": len(per_object)}
    for key in (
        "chamfer_l1",
        "chamfer_l2",
        "fscore_1cm",
        "fscore_2cm",
        "fscore_5cm",
        "yaw_error_deg",
        "translation_error_m",
    ):
        out[key] = median(key, per_object)
    posed = [r for r in per_object if "scan2cad" in r]
    out["scan2cad_accuracy"] = float(np.mean([r["scan2cad"] for r in posed])) if posed else None
    out["chamfer_l1_by_class"] = {
        c: median("chamfer_l1", [r for r in per_object if r["class"] == c])
        for c in sorted({r["class"] for r in per_object})
    }
    out["per_object"] = per_object
    return out
