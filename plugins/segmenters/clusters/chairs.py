"""Pass ``assemble_chairs`` (``recognize``): a chair seen in pieces stacked one over another (a swivel
chair's base under its seat and back, the post between them too thin for the map) becomes one chair."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from stratamap.core.map.priors import ON_SUPPORTS, ONE_SEAT, STANDS_ON_OTHERS, UNNAMED
from stratamap.plugins.segmenters.clusters.grid import share_within
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, SEAT_HEIGHTS, fits_class

#: Pieces of one chair lie one over another at most this far apart (m): the part of a swivel chair's
#: post, or of its legs under the seat, that the map lost.
STACK_GAP = 0.12
#: A chair's back, behind its seat, may reach this far (m) below the seat's top (a swivel chair's back
#: on the bar that holds it).
BACK_BELOW_SEAT = 0.2
#: Elsewhere a piece may reach this far (m) below the top of the one it rests on.
OVERLAP = 0.05
#: Pieces stack when one's top view covers this share of the other's.
STACK_SHARE = 0.5
#: Top views of pieces are thinned to about this many points for their hulls.
HULL_POINTS = 2000


class _Piece(NamedTuple):
    """An instance as a possible piece of a chair seen in stacked pieces."""

    points: np.ndarray  # indices of its points
    bottom: float  # m
    top: float  # m
    whole: bool  # on the floor and a whole object of its class by itself
    xy: np.ndarray  # its top view, thinned
    lo: np.ndarray  # the top view's corners
    hi: np.ndarray


def assemble_chairs(lab: Labelling) -> None:
    """Instances each resting on another's top within one footprint, whose union stands on the floor,
    is of a chair's size and has no flat top (a back rises over one side of the seat), become one
    chair. What a class of things that stand on others fits (a cup, a monitor, a box on a cabinet) is
    never a piece, and nothing is assembled onto a whole object standing on the floor (a lamp on a
    cabinet). Sets ``instance_ids``, ``class_ids`` and ``naming``; each assembly is noted
    (``chairs_assembled``)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from stratamap.core.map.instances import instance_members

    vocab, points, base_z = lab.vocab, lab.points, lab.base_z
    if not lab.cfg.recognize or ONE_SEAT not in vocab:
        return
    stands_on_others = [name for name in (*ON_SUPPORTS, *STANDS_ON_OTHERS) if name in vocab]
    pieces = {}
    for iid, sel in instance_members(lab.instance_ids).items():
        cls = int(np.bincount(lab.class_ids[sel]).argmax())
        if len(sel) < 4 or not vocab.is_thing[cls]:
            continue
        name = vocab.name(cls)
        shape = lab.shape(sel)
        if name in stands_on_others and fits_class(name, shape):
            continue
        z = points[sel, 2]
        # On the floor and a whole object of its class by itself (a cabinet, a table): what rests on
        # it stands on it.
        whole = name != UNNAMED and shape.bottom <= FLOOR_GAP and fits_class(name, shape)
        xy = points[sel[:: max(1, len(sel) // HULL_POINTS)], :2]  # top views, thinned for the hulls
        if len(np.unique(xy, axis=0)) >= 3:
            pieces[iid] = _Piece(sel, float(z.min()), float(z.max()), whole, xy, xy.min(axis=0), xy.max(axis=0))
    ids = sorted(pieces)
    edges = []
    for a, upper_id in enumerate(ids):
        for b, lower_id in enumerate(ids):
            upper, lower = pieces[upper_id], pieces[lower_id]
            # ``upper`` rests on ``lower``'s top (a gap of a thin post at most) within its footprint, or
            # over it; a back behind a seat reaches below the seat's top.
            at_seat = SEAT_HEIGHTS[0] <= lower.top - base_z <= SEAT_HEIGHTS[1]
            if a == b or not -(BACK_BELOW_SEAT if at_seat else OVERLAP) <= upper.bottom - lower.top <= STACK_GAP:
                continue
            if np.any(upper.lo > lower.hi) or np.any(lower.lo > upper.hi):  # apart in the top view
                continue
            if max(share_within(upper.xy, lower.xy), share_within(lower.xy, upper.xy)) >= STACK_SHARE:
                edges.append((a, b))
    if not edges:
        return
    pairs = np.array(edges)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(ids), len(ids)))
    _, component = connected_components(graph, directed=False)
    groups: dict[int, list[int]] = {}
    for k, iid in enumerate(ids):
        groups.setdefault(int(component[k]), []).append(iid)
    assembled = []
    for group in groups.values():
        if len(group) < 2:
            continue
        sel = np.concatenate([pieces[i].points for i in group])
        shape = lab.shape(sel)
        # Standing on the floor, of a chair's size, its top no flat surface over its footprint (a
        # back rises over one side of the seat). Against a wall or not: chairs stand there too.
        if shape.bottom > FLOOR_GAP or shape.flat_top or not fits_class(ONE_SEAT, shape):
            continue
        # A whole object on the floor carries what rests on it (a lamp on a cabinet), unless it is a
        # seat and the rest its back: its top at sitting height, the rest reaching below that top
        # (behind the seat, not standing on it), and the two seating seen from above (a swivel
        # chair's seat and base that a "table" box named, its back apart).
        wholes = [i for i in group if pieces[i].whole]
        if wholes:
            seat_top = min(pieces[i].top for i in wholes)
            back = all(pieces[i].bottom <= seat_top - OVERLAP for i in group if not pieces[i].whole)
            if not (shape.seat and back and seat_top - base_z <= SEAT_HEIGHTS[1]):
                continue
        keep = max(group, key=lambda i: (len(pieces[i].points), -i))
        lab.relabel(sel, instance=keep, cls=vocab.id(ONE_SEAT))
        assembled.append({"instance": keep, "pieces": sorted(group)})
        lab.naming[keep] = ("shape", f"{len(group)} pieces stacked into a seat with a back, of a chair's size")
    lab.note("chairs_assembled", assembled)
