"""Object instances from a panoptic labelling of map points."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import ObjectInstance, ObjectInstances, Semantics

#: ``ObjectInstance.attributes`` key saying how an object got its class: ``{"by": ..., "why": ...}``, ``by``
#: one of NAMED_BY. The run report and the viewer show it, so a user can see why a unit is a "counter".
NAMING = "naming"
NAMED_BY = {
    "labels": "the previous stage's per-frame labels, fused in the map (a detector's or a network's classes)",
    "votes": "the fused labels of most of its points, where the segmenter found the object by geometry",
    "shape": "class size priors and support context (recognition by priors)",
    "context": "what else the map holds (a counter's size in a room with nothing of a kitchen is a cabinet's)",
    "size rules": "the segmenter's own class_rules (extent and height) or a support surface on top",
    "matching": "the best-fitting library model over every class (recognition by matching)",
    "model": "a trained classifier over the object's measured features (clusters' naming: model), with its score",
    "unnamed": "nothing named it: no label, vote or rule fitted, so it keeps the catch-all class (object)",
}


#: ``ObjectInstance.attributes`` key of what a segmenter measured of an object's shape (``clusters``):
#: ``{"solid": ..., "seat": ..., "flat_top": ..., "against_wall": ..., "knee_space": ...}``, booleans
#: as ``clusters``' shapes define them. Later stages read the evidence rather than the class it led
#: to (``fronts`` looks for doors on a solid body without a seat, whatever it was named).
SHAPE = "shape"
SHAPE_FLAGS = ("solid", "seat", "flat_top", "against_wall", "knee_space")


def set_naming(inst: ObjectInstance, by: str, why: str) -> None:
    """Record how ``inst`` got its class (``by`` one of NAMED_BY; ``why`` a short sentence)."""
    if by not in NAMED_BY:
        raise ValueError(f"naming: {by!r} is none of {sorted(NAMED_BY)}")
    inst.attributes[NAMING] = {"by": by, "why": why}


def naming_text(inst: ObjectInstance) -> str:
    """``"by: why"`` of how ``inst`` got its class, or ``"-"`` when no stage said."""
    naming = inst.attributes.get(NAMING)
    if not isinstance(naming, dict) or "by" not in naming:
        return "-"
    return f"{naming['by']}: {naming.get('why', '')}".rstrip(": ")


def members_of(ids: np.ndarray, n: int) -> list[np.ndarray]:
    """Member indices of each id 0..n-1 (ids < 0 left out), ascending, found with one sort: selecting
    ``ids == k`` for each k costs a pass over every element per id, which on a hall of hundreds of
    tables was most of a run."""
    order = np.argsort(ids, kind="stable")
    starts = np.searchsorted(ids[order], np.arange(n + 1))
    return [order[starts[k] : starts[k + 1]] for k in range(n)]


def instance_members(point_instance: np.ndarray) -> dict[int, np.ndarray]:
    """The point indices of every positive instance id, in increasing id order (one sort of the
    points, not one scan of them per instance)."""
    point_instance = np.asarray(point_instance)
    order = np.argsort(point_instance, kind="stable")
    uniq, starts = np.unique(point_instance[order], return_index=True)
    ends = np.append(starts[1:], len(order))
    return {int(i): order[a:b] for i, a, b in zip(uniq, starts, ends, strict=True) if i > 0}


def instances_from_semantics(
    points: np.ndarray,
    colors: np.ndarray | None,
    sem: Semantics,
    min_points: int,
    naming: tuple[str, str] | None = None,
    axes: Sequence[float] = (),
    axes_slack: float = 0.0,
) -> ObjectInstances:
    """One object per instance id of a thing class, with its points and gravity-aligned box (turned
    to one of the room's ``axes`` where that costs at most ``axes_slack`` more footprint, see
    :func:`~stratamap.core.geometry.boxes.min_area_rectangle`); ``naming`` (``(by, why)``, see
    ``set_naming``) says how every one of them got its class."""
    out = ObjectInstances()
    ids = sem.instance_ids
    order = np.argsort(ids, kind="stable")
    uniq, starts = np.unique(ids[order], return_index=True)
    bounds = np.append(starts, len(ids))
    for k, iid in enumerate(uniq):
        if iid <= 0:
            continue
        sel = order[bounds[k] : bounds[k + 1]]
        if len(sel) < min_points:
            continue
        cls = int(np.bincount(sem.class_ids[sel]).argmax())
        if not sem.vocabulary.is_thing[cls]:
            continue
        pts = points[sel]
        out.add(
            ObjectInstance(
                id=int(iid),
                class_name=sem.vocabulary.name(cls),
                points=pts,
                colors=None if colors is None else colors[sel],
                box=gravity_aligned_box(pts, axes=axes, axes_slack=axes_slack),
                score=float((sem.class_ids[sel] == cls).mean()),
            )
        )
        if naming is not None:
            set_naming(out[int(iid)], *naming)
    return out


def plausible(class_name: str, points: np.ndarray, margin: float = 1.3, whole: bool = False) -> bool:
    """Whether an object of these points can be of this class by its size (core/map/priors.py): its
    farthest point from the centroid within ``margin`` times the class's largest extent, and its
    longest horizontal side within ``margin`` times the class's longest. Classes whose objects come in
    any length (tables, counters, shelves, sofas, benches) and classes without a prior pass those two.
    ``whole`` (an object seen whole, as recognition assumes) also asks its height to reach the class's
    lowest (``priors.lowest_height``): a flat sliver is no microwave."""
    from stratamap.core.map.priors import ANY_LENGTH, CLASS_SIZES, lowest_height

    if whole and len(points):
        lowest = lowest_height(class_name, margin)
        z = np.asarray(points, np.float64)[:, 2]
        if lowest is not None and float(z.max() - z.min()) < lowest:
            return False
    size = CLASS_SIZES.get(class_name)
    if size is None or class_name in ANY_LENGTH or len(points) == 0:
        return True
    pts = np.asarray(points, np.float64)
    reach = float(np.linalg.norm(pts - pts.mean(0), axis=1).max())
    if reach > margin * size.extent[1]:
        return False
    longest = size.longest(float(np.ptp(pts[:, 2])))
    if longest is not None:
        box = gravity_aligned_box(pts)
        if float(np.max(box.size[:2])) > margin * longest:
            return False
    return True


def veto_implausible_classes(
    points: np.ndarray,
    point_class: np.ndarray,
    point_instance: np.ndarray,
    vocabulary,
    fallback: str = "object",
    margin: float = 1.3,
) -> tuple[np.ndarray, list[dict]]:
    """Size priors veto impossible labels (a 2.2 m chair): each instance whose majority class its size
    rules out takes the next most voted thing class it fits, else ``fallback``. Returns the new point
    classes and one record per vetoed instance (id, from, to, reach)."""
    point_class = np.asarray(point_class).copy()
    vetoed = []
    if fallback not in vocabulary:
        return point_class, vetoed
    for iid, sel in instance_members(point_instance).items():
        votes = np.bincount(point_class[sel], minlength=len(vocabulary))
        order = [int(c) for c in np.argsort(-votes, kind="stable") if votes[c] > 0 and vocabulary.is_thing[c]]
        if not order:
            continue
        first = vocabulary.name(order[0])
        if plausible(first, points[sel], margin):
            continue
        chosen = next(
            (vocabulary.name(c) for c in order[1:] if plausible(vocabulary.name(c), points[sel], margin)), fallback
        )
        point_class[sel] = vocabulary.id(chosen)
        pts = points[sel]
        reach = float(np.linalg.norm(pts - pts.mean(0), axis=1).max())
        vetoed.append({"instance": int(iid), "from": first, "to": chosen, "reach_m": round(reach, 3)})
    return point_class, vetoed


def merge_overlapping_instances(
    points: np.ndarray, point_instance: np.ndarray, iou: float = 0.5
) -> tuple[np.ndarray, list[list[int]]]:
    """Two objects do not fill the same space: thing instances whose gravity-aligned boxes overlap at
    3D IoU ``iou`` or more are one object (a counter whose front frames called it a table and whose top
    frames a desk). Returns the new instance ids (each group takes its largest member's id) and the
    groups merged."""
    from stratamap.core.geometry.boxes import box_iou_3d

    point_instance = np.asarray(point_instance).copy()
    ids = [int(i) for i in np.unique(point_instance[point_instance > 0])]
    if len(ids) < 2:
        return point_instance, []
    members = instance_members(point_instance)
    boxes = {i: gravity_aligned_box(points[members[i]]) for i in ids if len(members[i]) >= 4}
    parent = {i: i for i in boxes}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    keys = sorted(boxes)
    lows = np.array([boxes[i].center - boxes[i].size.max() / 2 for i in keys])
    highs = np.array([boxes[i].center + boxes[i].size.max() / 2 for i in keys])
    for a in range(len(keys)):
        near = np.flatnonzero(np.all((lows[a + 1 :] <= highs[a]) & (highs[a + 1 :] >= lows[a]), axis=1)) + a + 1
        for b in near:
            if box_iou_3d(boxes[keys[a]], boxes[keys[b]]) >= iou:
                ra, rb = root(keys[a]), root(keys[b])
                if ra != rb:
                    parent[rb] = ra
    groups: dict[int, list[int]] = {}
    for i in keys:
        groups.setdefault(root(i), []).append(i)
    merged = []
    for group in groups.values():
        if len(group) < 2:
            continue
        keep = max(group, key=lambda i: (len(members[i]), -i))
        for i in group:
            point_instance[members[i]] = keep
        merged.append(sorted(group))
    return point_instance, merged
