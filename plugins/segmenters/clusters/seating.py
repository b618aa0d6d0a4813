"""Pass ``join_seating`` (``recognize``): a sofa seen as seats side by side (a detector boxed it as
chairs, and the mapper's size prior cut the over-long "chair" in two) becomes one sofa."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.priors import ONE_SEAT, SEATS_IN_A_ROW, UNNAMED
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, fits_class

#: Seats touch within this many voxels.
TOUCH_VOXELS = 2.0
#: Seats side by side make a row no deeper than the deeper of them, but for this much (m) of the
#: map's noise and a seat pushed back a little: what reaches out beside a chair's depth is no seat of
#: the same row (a bag at its side, a unit behind it).
ROW_DEPTH_SLACK = 0.15


def join_seating(lab: Labelling) -> None:
    """Floor-standing instances voted chair or sofa, or with no votes seating seen from above
    (``seat``), that touch (within TOUCH_VOXELS) and together are seating too long for one chair that
    fits a sofa, side by side (no deeper than the deeper one, ROW_DEPTH_SLACK), become one sofa. Two
    armchairs a hand apart touch nowhere. Sets ``instance_ids``, ``class_ids`` and ``naming``; each
    join is noted (``seating_joined``)."""
    from scipy.spatial import cKDTree

    from stratamap.core.map.instances import instance_members

    vocab, points = lab.vocab, lab.points
    if not lab.cfg.recognize or SEATS_IN_A_ROW not in vocab:
        return
    seats = {}
    for iid, sel in instance_members(lab.instance_ids).items():
        name = vocab.name(int(np.bincount(lab.class_ids[sel]).argmax()))
        if len(sel) < 4 or name not in (ONE_SEAT, SEATS_IN_A_ROW, UNNAMED):
            continue
        shape = lab.shape(sel)
        # Seating by its votes or, with none, by its shape.
        if shape.bottom <= FLOOR_GAP and not shape.flat_top and (shape.seat or name != UNNAMED):
            seats[iid] = sel

    def sofa_pair() -> tuple[int, int] | None:
        """The ids of two seats that touch and together are a sofa, not a chair; None: no such two."""
        ids = sorted(seats)
        for a, first in enumerate(ids):
            tree = cKDTree(points[seats[first]])
            for second in ids[a + 1 :]:
                near, _ = tree.query(points[seats[second]], distance_upper_bound=TOUCH_VOXELS * lab.voxel)
                if not np.isfinite(near).any() or lab.held_apart(seats[first], seats[second]):
                    continue
                union = np.concatenate([seats[first], seats[second]])
                shape = lab.shape(union)
                is_sofa = fits_class(SEATS_IN_A_ROW, shape) and not fits_class(ONE_SEAT, shape)
                if shape.seat and not shape.flat_top and is_sofa:
                    deeper = max(lab.shape(seats[first]).depth, lab.shape(seats[second]).depth)
                    if shape.depth <= deeper + ROW_DEPTH_SLACK:  # side by side
                        return first, second
        return None

    joined = []
    while (pair := sofa_pair()) is not None:
        first, second = pair
        union = np.concatenate([seats[first], seats.pop(second)])
        lab.relabel(union, instance=first, cls=vocab.id(SEATS_IN_A_ROW))
        seats[first] = union
        joined.append({"instance": first, "joined": second})
        lab.naming[first] = ("shape", "seating side by side, too long for one chair: a sofa")
    lab.note("seating_joined", joined)
