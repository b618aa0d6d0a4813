"""The built-in metric families against ground truth (one module per family beside this one),
contributed through the ``stratamap_evaluate`` hook like any plugin's."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.hookspecs import hookimpl
from stratamap.core.stages import PipelineData


def evaluate(data: PipelineData, details: bool = False) -> dict[str, Any]:
    """Metrics grouped by family for whatever layers ``data`` holds and its ground truth covers
    (``details``: keep the planned paths of the navigation family)."""
    from stratamap.core.evaluation import detection, panoptic

    gt = data.ground_truth
    out: dict[str, Any] = {}
    if gt is None:
        return out
    m = data.map
    if m.instances is not None and gt.objects:
        from stratamap.core.evaluation import completion

        out["detection"] = detection.evaluate_instances(m.instances, gt.objects)
        out["detection"]["box_map50"] = detection.box_map(m.instances, gt.objects)
        refined_boxes = None
        if m.contact_graph is not None:
            from stratamap.core.map.layers import OrientedBox

            refined_boxes = {
                n: OrientedBox.from_dict(d["box_refined"])
                for n, d in m.contact_graph.support.nodes(data=True)
                if "box_refined" in d
            }
            out["detection"]["box_map50_refined"] = detection.box_map(m.instances, gt.objects, boxes=refined_boxes)
        out["completion"] = completion.evaluate_completion(m.instances, gt.objects)
        from stratamap.core.evaluation.furniture import evaluate_furniture

        n_points = len(m.geometry) if m.geometry is not None else 0
        out["furniture"] = evaluate_furniture(m.instances, gt.objects, m.semantics, n_points, boxes=refined_boxes)
        observed = evaluate_furniture(m.instances, gt.objects)  # its matches only: the shares are the same
        out["furniture"]["observed"] = {k: observed[k] for k in ("recall", "precision", "recall_class_aware")}
        if m.contact_graph is not None and gt.contact_graph is not None:
            from stratamap.core.evaluation.graph import evaluate_graph

            out["graph"] = evaluate_graph(m.contact_graph, m.instances, gt.contact_graph, gt.objects)
    from stratamap.core.evaluation.articulation import evaluate_articulation, has_articulation

    if has_articulation(gt.objects):  # doors and drawers to find: scored even when the map has none
        out["articulation"] = evaluate_articulation(m.instances, gt.objects, data.stream)
    if m.semantics is not None and m.geometry is not None and len(m.geometry) == len(m.semantics):
        if gt.point_class_ids is not None and data.stream is not None and data.stream.points is not None:
            gt_cls, gt_inst = panoptic.transfer_point_labels(
                m.geometry.points, np.asarray(data.stream.points), gt.point_class_ids, gt.point_instance_ids
            )
        else:
            gt_cls, gt_inst = panoptic.ground_truth_point_labels(m.geometry.points, gt)
        pq = panoptic.panoptic_quality(
            m.semantics.class_ids, m.semantics.instance_ids, gt_cls, gt_inst, m.semantics.vocabulary
        )
        inst = pq.pop("instances")
        p, r = inst["precision"], inst["recall"]
        out["panoptic"] = pq
        out["instances"] = {
            "precision": p,
            "recall": r,
            "f1": 2 * p * r / (p + r) if p + r else 0.0,
            "count": len(m.instances or []),
        }
        out["instances"]["map50"] = panoptic.instance_map(m.semantics, m.instances, gt_cls, gt_inst)
    kitchen = gt.layout.get("kitchen_scan") if isinstance(gt.layout, dict) else None
    if (
        kitchen is not None
        and m.semantics is not None
        and m.semantics.plane_ids is not None
        and m.geometry is not None
        and data.stream is not None
    ):
        from stratamap.core.evaluation.classification import tables_from_map

        out["classification"] = tables_from_map(m, np.asarray(data.stream.points), kitchen)
    if data.frame_labels is not None and gt.frame_labels and len(gt.frame_labels) == len(data.frame_labels):
        out["frames"] = panoptic.frame_quality(data.frame_labels.frames, gt.frame_labels, gt.vocabulary)
    occ = m.occupancy
    if "objects" in gt.occupancy and "slam" in occ and "multimap" in occ:
        from stratamap.core.evaluation.navigation import evaluate_navigation

        nav = evaluate_navigation(occ["slam"], occ["multimap"], gt.occupancy["objects"])
        if not details:
            nav.pop("records", None)
        out["navigation"] = nav
    odometry = (data.stream.metadata.get("odometry") if data.stream is not None else None) or {}
    if "ate_rmse_m" in odometry:
        out["trajectory"] = {k: v for k, v in odometry.items() if k.startswith(("ate", "rpe"))}
    return out


@hookimpl
def stratamap_evaluate(data: PipelineData, details: bool) -> dict[str, Any]:
    return evaluate(data, details=details)


__all__ = ["evaluate", "stratamap_evaluate"]
