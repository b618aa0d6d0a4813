"""Pass ``join_parts`` (``recognize``): pieces that are no object by themselves join the
floor-standing object (a class of NOT_STACKED: chairs, tables, counters) they lie over or under: a
swivel chair's base under its seat, an armrest over it."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.priors import ON_SUPPORTS, UNNAMED
from stratamap.plugins.segmenters.clusters.grid import share_within
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, STANDING_GAP, fits_class, on_a_support

#: A piece whose top lies this far (m) below an anchor's lowest point is apart from it.
BELOW_ANCHOR = 0.15
#: A piece rising this far (m) above an anchor's top stands on it (or, of a class that stands on none
#: other, is its upper part).
ABOVE_ANCHOR = 0.05
#: A lifted piece joins an anchor whose footprint holds this share of it, a piece under or over one
#: the larger share, and a seat under a lifted back the smaller.
WITHIN_SHARE = 0.9
OVER_SHARE = 0.5
#: A small thing's foot lies this many voxels from a support surface's height when it stands on it.
SUPPORTED_VOXELS = 1.5


def join_parts(lab: Labelling) -> None:
    """A piece is one named ``object`` by the priors, one voted the anchor's class that cannot be of it
    alone (a 20 cm "chair" at seat height), or one that nothing of its own holds up (off the floor,
    off the walls, of no floor-standing class: a backrest's top voted "monitor"). Sets
    ``instance_ids`` and ``class_ids``; each join is noted (``parts_joined``)."""
    from stratamap.core.map.priors import NOT_STACKED, OPEN_BELOW

    if not lab.cfg.recognize:
        return
    instance_ids = lab.instance_ids
    if len(np.unique(instance_ids[instance_ids > 0])) < 2:
        return
    points, vocab, base_z, voxel = lab.points, lab.vocab, lab.base_z, lab.voxel
    support_heights = lab.supports.height
    info = {iid: (name, shape, sel, lab.prior(shape)[0]) for iid, (name, shape, sel) in lab.thing_shapes().items()}
    # Anchors by the class they will have: the voted one where their size allows it, else the
    # priors' (a counter a detector without a 'counter' label framed as a "box").
    anchor_class, standing_class = {}, {}
    for i, (name, shape, _, alone) in info.items():
        settled = name if name != UNNAMED and fits_class(name, shape) else alone
        if settled != UNNAMED and fits_class(settled, shape) and shape.bottom <= FLOOR_GAP:
            standing_class[i] = settled
        if settled in NOT_STACKED and fits_class(settled, shape):
            anchor_class[i] = settled
    joined, refused = [], []

    def join(iid: int, anchor: int, name: str, relabel: np.ndarray) -> None:
        if lab.held_apart(info[iid][2], info[anchor][2]):
            refused.append({"instance": iid, "into": anchor, "why": "kept apart by an earlier pass"})
            return
        lab.relabel(info[iid][2], instance=anchor)
        lab.relabel(relabel, cls=vocab.id(name))
        joined.append({"instance": iid, "into": anchor, "class": name})
        anchor_class.pop(iid, None)
        standing_class.pop(iid, None)

    for iid in sorted(info, key=lambda i: len(info[i][2])):
        name, shape, sel, alone = info[iid]
        # A small thing by its size, its foot at the height of a support surface (a mug on a worktop).
        supported = alone in ON_SUPPORTS and on_a_support(
            base_z + shape.bottom, support_heights, SUPPORTED_VOXELS * voxel
        )
        # Held up by nothing of its own: neither floor-standing, nor hung on a wall, nor a small thing
        # named as one on a support, its foot off the floor. Within a floor-standing object it is a
        # piece of it, whatever it was voted (a chair's backrest seen as a "monitor"); on it, it rises
        # above its top.
        floating = (
            name not in NOT_STACKED
            and not shape.against_wall
            and shape.bottom > STANDING_GAP
            and not (supported and name in ON_SUPPORTS)
        )
        # Off the floor and not on a support: within a floor-standing object that reaches lower, it is
        # a piece of that, whatever it was voted (a counter's upper front that a detector called a
        # chair or a monitor; a mug voted "table" on the worktop stays a mug).
        lifted = shape.bottom > FLOOR_GAP and not supported
        if (iid in anchor_class and not lifted) or (
            name != UNNAMED and fits_class(name, shape) and not floating and not lifted
        ):
            continue
        z = points[sel, 2]
        # A piece off the floor lies within any floor-standing object (a sliver of a sideboard's top),
        # other pieces join only objects that stand on no other one (chairs, tables, counters).
        anchors = {**standing_class, **anchor_class} if lifted else anchor_class
        for anchor in sorted(anchors, key=lambda i: -len(info[i][2])):
            a_name, a_sel = anchors[anchor], info[anchor][2]
            if anchor == iid or (not floating and not lifted and alone != UNNAMED and a_name != name):
                continue
            # A small thing standing at a support's height stands on a table's top, whatever the table's
            # mask made of it: not a piece of the table.
            if supported and a_name in OPEN_BELOW:
                continue
            # Within the anchor's height or under it: what rises above its top stands on it (a cup on a table).
            az = points[a_sel, 2]
            if z.max() < az.min() - BELOW_ANCHOR:
                continue
            if z.max() > az.max() + ABOVE_ANCHOR:
                # Rising above the anchor's top, it stands on it (a cup on a table), unless it is of a
                # class that stands on no other object, its foot at the anchor's top and the anchor
                # wholly under it: one object (a chair's back and seat over its seat and legs).
                if not (
                    lifted
                    and anchor in anchor_class
                    and name in NOT_STACKED
                    and fits_class(name, shape)
                    and z.min() <= az.max() + FLOOR_GAP
                    and share_within(points[a_sel, :2], points[sel, :2]) >= WITHIN_SHARE
                ):
                    continue
                merged = np.concatenate([sel, a_sel])
                if fits_class(name, lab.shape(merged)):
                    a_name = name
                    anchor_class[anchor] = name
                join(iid, anchor, a_name, merged)
                break
            if lifted and not az.min() < z.min() - FLOOR_GAP:
                # Under a lifted anchor of a class that stands on no other object, its foot on this
                # piece's top and its footprint over it: one object (a swivel chair's seat under its
                # back, their post unseen).
                if (
                    alone == UNNAMED
                    and anchor in anchor_class
                    and a_name in NOT_STACKED
                    and z.max() - ABOVE_ANCHOR <= az.min() <= z.max() + FLOOR_GAP
                    and share_within(points[a_sel, :2], points[sel, :2]) >= OVER_SHARE
                    and fits_class(a_name, lab.shape(np.concatenate([sel, a_sel])))
                ):
                    join(iid, anchor, a_name, sel)
                    break
                continue
            inside = share_within(points[sel, :2], points[a_sel, :2])
            # A lifted piece lies wholly within (a table top beside a chair overlaps its footprint).
            if lifted and inside < WITHIN_SHARE:
                continue
            # Never into an object its class's size then rules out (a strip of floor clutter under a
            # chair's base would make a 1.4 m "chair").
            if inside >= OVER_SHARE and fits_class(a_name, lab.shape(np.concatenate([sel, a_sel]))):
                join(iid, anchor, a_name, sel)
                break
    lab.note("parts_joined", joined)
    lab.note("joins_refused", refused)
