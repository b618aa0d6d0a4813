"""Pass ``join_enclosed`` (``recognize``): a piece lying within a larger floor-standing object's box,
its centre within that object's outline, is a part of it (a chair's slat or post, a fridge's handle,
a worktop's edge that frames boxed on their own)."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.priors import ON_SUPPORTS, SEATING, UNNAMED
from stratamap.plugins.segmenters.clusters.grid import hull_equations
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, fits_class, on_a_support, thin

#: A piece with this share of its points inside a larger floor-standing object's box is a part of it,
#: the box grown by this many voxels on every side (the map's noise at its faces).
ENCLOSED_SHARE = 0.8
ENCLOSED_MARGIN_VOXELS = 2.5


def join_enclosed(lab: Labelling) -> None:
    """A piece within ENCLOSED_SHARE of a larger floor-standing object's box, its centre within the
    object's outline (the convex hull of its points, top view; both grown by ENCLOSED_MARGIN_VOXELS),
    joins that object, whose class must still fit it, unless it is an object of its own there: a
    small thing standing on a support surface (a cup on the worktop, or on the table a chair is
    pushed under), or at the height of a support surface of the object around it; or furniture
    standing on the floor, whose class its shape fits, within anything but seating (a chair under a
    table or a desk). Sets ``instance_ids`` and ``class_ids``; each join is noted
    (``enclosed_joined``); a join that would make an object larger than any class allows is refused
    and noted (``joins_refused``)."""
    from scipy.spatial import cKDTree

    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.map.priors import NOT_STACKED, ON_A_SUPPORT

    if not lab.cfg.recognize:
        return
    points, vocab, base_z, voxel = lab.points, lab.vocab, lab.base_z, lab.voxel
    support_heights, support_of_point = lab.supports.height, lab.support_of_point
    info = lab.thing_shapes()
    # Floor-standing objects hold pieces, each as the class it will have: its own where its shape
    # fits it, else the one its shape makes most likely (a unit a detector called a table).
    holders, outlines, kind = {}, {}, {}
    for iid, (name, shape, sel) in info.items():
        if shape.bottom <= FLOOR_GAP:
            holders[iid] = gravity_aligned_box(points[sel])
            outlines[iid] = hull_equations(points[sel, :2])
            fits = name != UNNAMED and fits_class(name, shape)
            kind[iid] = name if fits else lab.prior(shape, np.zeros(0))[0]
    if not holders:
        return
    tolerance = lab.standing_tolerance
    on_top = np.flatnonzero(support_of_point >= 0)
    surfaces = cKDTree(points[on_top]) if len(on_top) else None
    # A seat's surface holds pieces of its chair far more often than things: it spares none.
    seats = [h for h, k in kind.items() if k in SEATING]
    joined, refused = [], []
    margin = ENCLOSED_MARGIN_VOXELS * voxel
    for iid in sorted(info, key=lambda i: (len(info[i][2]), i)):
        name, shape, sel = info[iid]
        heights = np.zeros(0)
        if surfaces is not None:
            # The support surfaces under the piece's foot (by place, not only by height), its own
            # points left out (a worktop's edge is support surface itself).
            instance_ids = lab.instance_ids  # as the joins so far left it
            foot = points[sel][points[sel, 2] <= base_z + shape.bottom + voxel]
            near = on_top[sorted({int(j) for hits in surfaces.query_ball_point(foot, tolerance) for j in hits})]
            heights = points[near[(instance_ids[near] != iid) & ~np.isin(instance_ids[near], seats)], 2] - base_z
        # A small thing on a support surface is an object of its own. The surface under a cup is
        # hidden by it, and its edge may be too: at a support's height, a small thing stands on the
        # object around it where that object holds a support surface at that height (a worktop);
        # else it is level with a support elsewhere (a chair's post beside a table's top).
        shelved = lab.prior(shape, heights + base_z)[0] in ON_SUPPORTS or (
            name in ON_A_SUPPORT and fits_class(name, shape)
        )
        if shelved and on_a_support(shape.bottom, heights, tolerance):
            continue
        level = shelved and on_a_support(base_z + shape.bottom, support_heights, tolerance)
        furniture = (
            name in NOT_STACKED and fits_class(name, shape) and shape.bottom <= FLOOR_GAP and not thin(points[sel])
        )
        centre = points[sel, :2].mean(axis=0)
        for holder in sorted(holders, key=lambda i: (-len(info[i][2]), i)):
            h_name, _, h_sel = info[holder]
            if holder == iid or len(h_sel) <= len(sel):
                continue
            if furniture and kind[holder] not in SEATING:
                continue
            # Within its body, not only its box: an L of units frames floor between its arms, where a
            # chair may stand; a part of an object (an armchair's arm) has its centre in its outline.
            a, b = outlines[holder]
            within = holders[holder].contains(points[sel], margin).mean()
            if within < ENCLOSED_SHARE or (a @ centre + b > margin).any():
                continue
            if level and kind[holder] not in SEATING:
                held = support_of_point[h_sel] >= 0
                if on_a_support(base_z + shape.bottom, points[h_sel[held], 2], tolerance):
                    continue
            merged = np.concatenate([h_sel, sel])
            merged_shape = lab.shape(merged)
            if kind[holder] != UNNAMED and not fits_class(kind[holder], merged_shape):
                continue
            if lab.too_large(merged_shape):
                refused.append({"instance": iid, "into": holder, "why": "larger than any class together"})
                continue
            if lab.held_apart(sel, h_sel):
                refused.append({"instance": iid, "into": holder, "why": "kept apart by an earlier pass"})
                continue
            lab.relabel(sel, instance=holder, cls=vocab.id(h_name))
            info[holder] = (h_name, info[holder][1], merged)
            holders.pop(iid, None)
            joined.append({"instance": iid, "into": holder, "class": h_name, "was": name})
            break
    lab.note("enclosed_joined", joined)
    lab.note("joins_refused", refused)
