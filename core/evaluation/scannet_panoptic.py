"""3D panoptic quality of a map against a ScanNet scan's per-vertex annotations.

Each map point takes the class and instance of the nearest annotated vertex of the scan's
``_vh_clean_2`` mesh within :data:`MAX_DISTANCE` (else it is void), the vertices first taken into
the map's frame by the source's ``world_transform``; then PQ, SQ and RQ (things, stuff, per class)
are :func:`stratamap.core.evaluation.panoptic.panoptic_quality`'s, as for every other map. NYU40
classes map to the vocabulary by :data:`stratamap.core.io.scannet_labels.NYU40_CLASSES`; instances
are ScanNet's aggregated objects. As everywhere in :mod:`~stratamap.core.evaluation.panoptic`, the
score is over what the map holds: an annotated object the map never saw is no miss here.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.evaluation.panoptic import instance_map, panoptic_quality, transfer_point_labels
from stratamap.core.io.scannet_labels import ScanLabels

#: How far (m) a map point may be from the nearest annotated vertex and still take its labels
#: (the vertices of ``_vh_clean_2`` lie a few centimetres apart).
MAX_DISTANCE = 0.05


def evaluate_scannet_panoptic(
    points: np.ndarray,
    semantics: Any,
    instances: Any,
    labels: ScanLabels,
    world_transform: np.ndarray | None = None,
    label_set: str = "nyu40",
) -> dict[str, Any]:
    """The ``panoptic`` and ``instances`` families of one map (its points and their ``semantics``;
    ``instances`` for the mask mAP) against a scan's ``labels``, as the built-in families report
    them for synthetic scenes. ``panoptic.covered`` is the share of map points that took a label."""
    world = np.eye(4) if world_transform is None else np.asarray(world_transform, float)
    vertices = labels.points @ world[:3, :3].T + world[:3, 3]
    vocabulary = semantics.vocabulary
    gt_cls, gt_inst = transfer_point_labels(
        np.asarray(points, float), vertices, labels.class_ids(vocabulary, label_set), labels.instance_ids, MAX_DISTANCE
    )
    pq = panoptic_quality(semantics.class_ids, semantics.instance_ids, gt_cls, gt_inst, vocabulary)
    inst = pq.pop("instances")
    pq["covered"] = float(np.mean(gt_cls >= 0)) if len(gt_cls) else 0.0
    p, r = inst["precision"], inst["recall"]
    found = {"precision": p, "recall": r, "f1": 2 * p * r / (p + r) if p + r else 0.0, "count": len(instances or [])}
    found["map50"] = instance_map(semantics, instances, gt_cls, gt_inst)
    return {"panoptic": pq, "instances": found}
