"""Pass ``rename_by_priors`` (``recognize``): instances named ``object`` or by a class their size rules
out take the class the priors and their support context give (``prior_class``), once pieces have
joined the objects they belong to."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.map.priors import UNNAMED
from stratamap.plugins.segmenters.clusters.grid import share_within
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, THIN, fits_class, typical_rather

#: An object's foot: its lowest this many metres.
FOOT_HEIGHT = 0.03
#: It rests on what holds this share of its foot at least INSIDE_BY (m) inside that one's outline.
RESTING_SHARE = 0.9
INSIDE_BY = 0.05
#: It touches a top within this many voxels.
REACH_VOXELS = 2.5


def rename_by_priors(lab: Labelling) -> None:
    """An instance of a class that stands on no other object (NOT_STACKED: a chair, a table) whose
    foot rests well inside the top of another instance or of a support surface is none of that class
    (a unit on a desk that a weak "chair" box framed); nor is one holding a level surface larger than
    its class's ``max_top_area`` (a desk top in a "chair"). Sets ``class_ids`` and ``naming``; each
    change is noted (``recognition``)."""
    from scipy.spatial import cKDTree

    from stratamap.core.map.instances import instance_members
    from stratamap.core.map.priors import CLASS_SIZES, NOT_STACKED

    if not lab.cfg.recognize or lab.cfg.naming == "model":
        return
    points, vocab, base_z, instance_ids = lab.points, lab.vocab, lab.base_z, lab.instance_ids
    support_of_point, support_areas, support_heights = lab.support_of_point, lab.supports.area, lab.supports.height
    # What an object may stand on: support surfaces and other instances, each by its own key.
    holder = np.where(instance_ids > 0, len(support_areas) + instance_ids, -1)
    holder = np.where(support_of_point >= 0, support_of_point, holder)
    tops = np.flatnonzero(holder >= 0)
    top_tree = cKDTree(points[tops]) if len(tops) else None
    changes = []
    for iid, sel in instance_members(instance_ids).items():
        cls = int(np.bincount(lab.class_ids[sel]).argmax())
        name = vocab.name(cls)
        if len(sel) < 4 or not vocab.is_thing[cls]:
            continue
        shape = lab.shape(sel)
        new, reason = lab.prior(shape)
        carried = (
            top_tree is not None
            and name in NOT_STACKED
            and shape.bottom > FLOOR_GAP
            and rests_on_another(points, sel, iid, instance_ids, holder, tops, top_tree, REACH_VOXELS * lab.voxel)
        )
        most_top = CLASS_SIZES[name].max_top_area if name in CLASS_SIZES else None
        too_large_top = (
            most_top is not None
            and largest_top(
                support_of_point[sel],
                support_areas,
                support_heights,
                base_z + shape.bottom + lab.standing_tolerance,
                base_z + shape.bottom + shape.height,
            )
            > most_top
        )
        if (
            name != UNNAMED
            and fits_class(name, shape)
            and not carried
            and not too_large_top
            and not typical_rather(new, name, shape)
        ):
            continue
        if carried:
            reason = f"stands on another object's top, which a {name} does not; {reason}"
        elif too_large_top:
            reason = f"holds a level surface larger than a {name}'s; {reason}"
        if new != name:
            lab.relabel(sel, cls=vocab.id(new))
            changes.append({"instance": iid, "from": name, "to": new, "why": reason})
            lab.naming[iid] = ("shape", f"{reason} (was {name})")
    lab.note("recognition", changes)


def rests_on_another(
    points: np.ndarray,
    sel: np.ndarray,
    iid: int,
    instance_ids: np.ndarray,
    holder: np.ndarray,
    tops: np.ndarray,
    top_tree: Any,
    reach: float,
) -> bool:
    """Whether instance ``iid`` (its points ``sel``) rests on another object: its foot (its lowest
    3 cm) within ``reach`` of the points ``tops`` (a k-d tree over them: support surfaces and other
    instances, keyed by ``holder``) lying no higher, and 90 % of it at least 5 cm inside the outline of
    what it touches there. A chair's back seen over a desk's far edge, or at the edge of a table it is
    pushed under, its legs hidden, touches the top too, but not well inside it."""
    z = points[sel, 2]
    foot = points[sel][z <= z.min() + FOOT_HEIGHT]
    hits = top_tree.query_ball_point(foot, reach)
    near = np.unique(np.concatenate([np.asarray(h, np.int64) for h in hits]))
    near = tops[near]
    near = near[(instance_ids[near] != iid) & (points[near, 2] <= foot[:, 2].max())]
    return any(
        share_within(foot[:, :2], points[holder == k, :2], margin=-INSIDE_BY) >= RESTING_SHARE
        for k in np.unique(holder[near])
    )


def largest_top(
    support_of_point: np.ndarray, support_areas: np.ndarray, support_heights: np.ndarray, foot: float, top: float
) -> float:
    """The area (m^2) of the largest support surface among an object's points (``support_of_point``: -1
    none) that the object holds: not one at its ``foot`` that it rises above by more than THIN, which
    it stands on (a chair's mask takes the floor between its runners along). A surface at its foot
    that is also its top (a desk top seen without its legs) it holds."""
    held = support_of_point[support_of_point >= 0]
    height = support_heights[held]
    held = held[(height > foot) | (top - height <= THIN)]
    return float(support_areas[held].max()) if len(held) else 0.0
