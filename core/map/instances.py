"""Object instances from a panoptic labelling of map points."""

from __future__ import annotations

import numpy as np

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import ObjectInstance, ObjectInstances, Semantics


def instances_from_semantics(
    points: np.ndarray, colors: np.ndarray | None, sem: Semantics, min_points: int
) -> ObjectInstances:
    """One object per instance id of a thing class, with its points and gravity-aligned box."""
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
                box=gravity_aligned_box(pts),
                score=float((sem.class_ids[sel] == cls).mean()),
            )
        )
    return out
