"""Completion quality: the completed shape against the ground-truth full shape.

For every detected object matched to a ground-truth object (see ``detection``), both shapes are
sampled at the same spacing: the completion's world mesh (or, with no completion, the observed
points: the ``none`` baseline) and the ground truth's full mesh. Reported per object and as medians:

* Chamfer-L1 (mean of both directions' mean nearest distances) and Chamfer-L2 (squared);
* F-score at 1, 2 and 5 cm (harmonic mean of the shares of each set within the threshold);
* pose: translation error and yaw error (completions placed from a model only; boxes and raw
  points have no orientation of their own), and Scan2CAD accuracy (translation <= 20 cm,
  rotation <= 20 deg, scale within 20%). As in Scan2CAD's evaluation the yaw error is
  symmetry-aware: an object whose ground-truth shape maps onto itself under a rotation about its
  vertical axis (180 deg: a rectangular table; 90 deg: a square one; any angle: a round table, a
  bottle) has its yaw error taken as the smallest over those rotations. The symmetry is measured
  on the ground-truth geometry (:func:`yaw_symmetry`), so it holds for any model library;
* visibility: the share of the ground-truth surface within 3 cm of an observed point.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.evaluation.detection import match_boxes
from stratamap.core.geometry.transforms import wrap_angle, yaw_of
from stratamap.core.lazy import lazy_module
from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import ObjectInstance, ObjectInstances

spatial = lazy_module("scipy.spatial")

trimesh = lazy_module("trimesh")
o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")

THRESHOLDS = (0.01, 0.02, 0.05)
#: Rotations (deg) unrelated to 90 deg and to each other: a shape that maps onto itself under all of
#: them is taken as round (symmetric under any rotation about its vertical axis).
ROUND_TEST_ANGLES = (23.0, 51.0, 137.0)
#: Symmetry periods about the vertical axis, in degrees (0: any angle).
SYMMETRY_PERIOD_DEG = {"none": 360.0, "180": 180.0, "90": 90.0, "round": 0.0}


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
    d_pg = spatial.cKDTree(gt).query(pred)[0]
    d_gp = spatial.cKDTree(pred).query(gt)[0]
    out = {
        "chamfer_l1": float((d_pg.mean() + d_gp.mean()) / 2),
        "chamfer_l2": float(((d_pg**2).mean() + (d_gp**2).mean()) / 2),
    }
    for tau in THRESHOLDS:
        p, r = float((d_pg < tau).mean()), float((d_gp < tau).mean())
        out[f"fscore_{int(round(tau * 100))}cm"] = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return out


def yaw_symmetry(
    mesh: trimesh.Trimesh, samples: int = 400, rel_tolerance: float = 0.02, max_tolerance: float = 0.01
) -> str:
    """The rotational symmetry of ``mesh`` (object frame, +z up) about the vertical axis through
    the centre of its box: ``"round"`` (any angle), ``"90"``, ``"180"`` or ``"none"``.

    ``samples`` surface points are rotated by the candidate angle (both ways) and their exact
    distances to the unrotated surface measured; the shape maps onto itself when 95% of them lie
    within ``min(rel_tolerance x largest extent, max_tolerance)``. A high quantile, not the mean
    (Chamfer) distance: a local difference such as a rectangular table's overhang under 90 deg,
    a cabinet's handles under 180 deg or a cup's handle moves few points far, which a mean
    dilutes below any useful tolerance.
    """
    if len(mesh.faces) == 0 or mesh.area <= 0:
        return "none"
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    tol = min(rel_tolerance * float(np.max(hi - lo)), max_tolerance)
    pts = np.asarray(trimesh.sample.sample_surface(mesh, samples, seed=0)[0])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3c.Tensor(np.asarray(mesh.vertices, np.float32)), o3c.Tensor(np.asarray(mesh.faces, np.uint32))
    )

    def maps_onto_itself(angle_deg: float) -> bool:
        dists = []
        for a in (np.radians(angle_deg), -np.radians(angle_deg)):
            c, s = np.cos(a), np.sin(a)
            q = pts.copy()
            xy = pts[:, :2] - centre[:2]
            q[:, 0] = centre[0] + c * xy[:, 0] - s * xy[:, 1]
            q[:, 1] = centre[1] + s * xy[:, 0] + c * xy[:, 1]
            dists.append(scene.compute_distance(o3c.Tensor(q.astype(np.float32))).numpy())
        return float(np.quantile(np.concatenate(dists), 0.95)) <= tol

    if not maps_onto_itself(180.0):
        return "none"
    if not maps_onto_itself(90.0):
        return "180"
    return "round" if all(maps_onto_itself(a) for a in ROUND_TEST_ANGLES) else "90"


def symmetric_yaw_error_deg(yaw_a: float, yaw_b: float, symmetry: str = "none") -> float:
    """The smallest |yaw_a - yaw_b| (degrees) over the rotations ``symmetry`` leaves the shape unchanged by."""
    period = SYMMETRY_PERIOD_DEG[symmetry]
    if period == 0.0:
        return 0.0
    err = float(np.degrees(abs(wrap_angle(yaw_a - yaw_b)))) % period
    return min(err, period - err)


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
        rec["visibility"] = (
            float((spatial.cKDTree(inst.points).query(gt_pts)[0] < 0.03).mean()) if len(inst.points) else 0.0
        )
        c = inst.completion
        if c is not None and c.model_id is not None:
            t_err = float(np.linalg.norm(c.pose[:3, 3] - gt.pose[:3, 3]))
            symmetry = yaw_symmetry(gt.mesh)
            yaw_err = symmetric_yaw_error_deg(yaw_of(c.pose), yaw_of(gt.pose), symmetry)
            ratio = float(np.mean(c.world_mesh().extents / np.maximum(gt_mesh.extents, 1e-6)))
            rec.update(
                {"translation_error_m": t_err, "yaw_error_deg": yaw_err, "yaw_symmetry": symmetry, "scale_ratio": ratio}
            )
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
