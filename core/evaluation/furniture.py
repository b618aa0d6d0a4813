"""The ``furniture`` metric family: does a map of a real room keep its furniture apart and name it?

Ground truth at furniture scale is every labelled object of a class in :data:`FURNITURE_CLASSES`;
a predicted instance is at furniture scale when its class is one of them or, whatever it is called
(an unnamed ``object`` too), its gravity-aligned box is at least :data:`FURNITURE_FOOTPRINT` long
and :data:`FURNITURE_HEIGHT` high: a 5 m blob of table, counters and shelves counts against
precision. An instance's box is the one the map refined where it has one (the contact graph's
``box_refined``: an object's unseen bottom reaches down to its support, the table whose legs the
chairs hide), its observed box elsewhere; ``observed`` gives the figures on observed boxes alone.
Matching is one to one (Hungarian, largest total IoU) between boxes overlapping with
3D IoU >= ``iou_threshold``; class-aware recall counts the matches of the same class. The family
also gives the largest share of the map's points one thing instance holds (the collapse of a room
into one object shows there first), and where a real room's labels give no doors or drawers, whether
the map's joints are on storage at all: ``joints_on_storage`` counts the revolute and prismatic joints
(as the exporters write them) whose moving part's centre lies inside a labelled object of a class
with fronts (``priors.WITH_FRONTS``), its box grown by :data:`FRONT_MARGIN`; ``joints_elsewhere`` the
rest (a drawer on a leaflet rack, a door on a wall).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from stratamap.core.geometry.boxes import OrientedBox, box_iou_3d

#: What a robot plans around as furniture: the classes scored (the benchmark's definition).
FURNITURE_CLASSES: tuple[str, ...] = (
    "chair",
    "table",
    "desk",
    "cabinet",
    "shelf",
    "counter",
    "sofa",
    "bench",
    "fridge",
    "oven",
    "cupboard",
    "appliance",
)
#: How far (m) outside a labelled storage box a front's centre may lie: the box was fitted to the
#: carcass's points and is good to about as much (benchmarks/real_rooms/README.md); a front stands proud of it.
FRONT_MARGIN = 0.1
#: An instance of another name is at furniture scale from this long a side (m) ...
FURNITURE_FOOTPRINT = 0.4
#: ... and this high (m): smaller than a stool is not furniture.
FURNITURE_HEIGHT = 0.4


def at_furniture_scale(class_name: str, box: OrientedBox) -> bool:
    if class_name in FURNITURE_CLASSES:
        return True
    return float(max(box.size[0], box.size[1])) >= FURNITURE_FOOTPRINT and float(box.size[2]) >= FURNITURE_HEIGHT


def match_one_to_one(pred: Sequence[OrientedBox], gt: Sequence[OrientedBox], iou_threshold: float) -> list[tuple]:
    """(pred index, gt index, IoU) of the one-to-one matching with the largest total IoU among
    pairs at or above ``iou_threshold``."""
    from scipy.optimize import linear_sum_assignment

    if not pred or not gt:
        return []
    iou = np.array([[box_iou_3d(p, g) for g in gt] for p in pred])
    score = np.where(iou >= iou_threshold, iou, 0.0)
    rows, cols = linear_sum_assignment(-score)
    return [(int(r), int(c), float(iou[r, c])) for r, c in zip(rows, cols) if iou[r, c] >= iou_threshold]


def largest_share(instances: Any, semantics: Any, n_points: int) -> tuple[float, int | None]:
    """The largest share of the map's points one thing instance holds, and its id."""
    if not n_points or instances is None or not len(instances):
        return 0.0, None
    if semantics is not None and len(semantics) == n_points:
        ids, n = np.unique(np.asarray(semantics.instance_ids), return_counts=True)
        of_id = dict(zip(ids.tolist(), n.tolist(), strict=True))
        counts = {int(i.id): of_id.get(int(i.id), 0) for i in instances}
    else:
        counts = {int(i.id): len(i.points) for i in instances}
    best = max(counts, key=lambda k: counts[k])
    return counts[best] / n_points, best


def evaluate_furniture(
    instances: Any,
    gt_objects: Sequence[Any],
    semantics: Any = None,
    n_points: int = 0,
    iou_threshold: float = 0.25,
    boxes: dict[int, OrientedBox] | None = None,
) -> dict[str, Any]:
    """The family's figures; ``boxes``: an instance's box as the map refined it (the contact graph's
    ``box_refined``: its unseen bottom down to its support), used in place of the observed box."""
    boxes = boxes or {}
    truths = [(o, o.box()) for o in gt_objects if o.class_name in FURNITURE_CLASSES]
    preds = [i for i in (instances or []) if at_furniture_scale(i.class_name, boxes.get(i.id, i.box))]
    matches = match_one_to_one([boxes.get(p.id, p.box) for p in preds], [b for _, b in truths], iou_threshold)
    tp = len(matches)
    same_class = sum(preds[p].class_name == truths[g][0].class_name for p, g, _ in matches)
    share, holder = largest_share(instances, semantics, n_points)
    by_class: dict[str, dict[str, int]] = {}
    for obj, _ in truths:
        by_class.setdefault(obj.class_name, {"ground_truth": 0, "found": 0, "named": 0})["ground_truth"] += 1
    for p, g, _ in matches:
        row = by_class[truths[g][0].class_name]
        row["found"] += 1
        row["named"] += int(preds[p].class_name == truths[g][0].class_name)
    recall = tp / len(truths) if truths else 0.0
    precision = tp / len(preds) if preds else 0.0
    return {
        "ground_truth": len(truths),
        "predicted": len(preds),
        "matched": tp,
        "recall": recall,
        "precision": precision,
        "f1": 2 * precision * recall / (precision + recall) if precision + recall else 0.0,
        "recall_class_aware": same_class / len(truths) if truths else 0.0,
        "largest_share": share,
        "largest_instance": None if holder is None else f"instance {holder}",  # a name, not a figure to average
        "by_class": by_class,
        **joints_on_storage(instances, gt_objects),
        "matches": [
            {
                "instance": int(preds[p].id),
                "class": preds[p].class_name,
                "gt": int(truths[g][0].id),
                "gt_class": truths[g][0].class_name,
                "iou": round(v, 3),
            }
            for p, g, v in matches
        ],
    }


def joints_on_storage(instances: Any, gt_objects: Sequence[Any]) -> dict[str, int]:
    """How many of the map's door and drawer joints move a part that lies in a labelled storage
    object (a class of ``priors.WITH_FRONTS``), and how many move something else."""
    from stratamap.core.evaluation.articulation import predicted_joints
    from stratamap.core.map.priors import WITH_FRONTS

    storage = [o.box() for o in gt_objects if o.class_name in WITH_FRONTS]
    on = elsewhere = 0
    for joint in predicted_joints(instances):
        centre = joint.pivot if joint.part_center is None else joint.part_center
        if any(bool(box.contains(np.asarray(centre, float)[None], FRONT_MARGIN)[0]) for box in storage):
            on += 1
        else:
            elsewhere += 1
    return {"joints_on_storage": on, "joints_elsewhere": elsewhere}
