"""Pass ``split_standing``: where one segment holds both something standing on a support surface and
what lies below that surface (a mug flush with a table's edge), the standing part becomes a segment
of its own, which ``join_supports`` then keeps apart."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.config import ClustersConfig
from stratamap.plugins.segmenters.clusters.grid import hull_equations, linked
from stratamap.plugins.segmenters.clusters.labelling import Labelling, Supports

#: A part of a segment rising above a support surface within its footprint stands on it (a cup) when
#: it spans at most this share of the surface's narrower side; wider, it is the support's own (a
#: counter's upstand along its back, a desk's hutch).
STANDING_SHARE = 0.5


def split(lab: Labelling) -> None:
    """Sets ``segment``."""
    lab.segment = split_standing(lab.cells, lab.segment, lab.supports, lab.pairs, lab.voxel, lab.cfg)


def split_standing(
    cells: np.ndarray, segment: np.ndarray, supports: Supports, pairs: np.ndarray, voxel: float, cfg: ClustersConfig
) -> np.ndarray:
    """Where one segment holds both something standing on a support surface and what lies below
    that surface (a mug flush with a table's edge: its wall and the table's apron meet smoothly, so
    convexity did not part them): each connected part of its cells above the surface that lies wholly
    over the surface's footprint, rises above it from its height and spans at most STANDING_SHARE of
    the surface's narrower side becomes a segment of its own, which ``join_supports`` then keeps
    apart. Returns the segments. Linear in the map's size: each segment's cells and links are found
    with one sort, not one pass over the map per segment."""
    segment = segment.copy()
    n_sup = len(supports.height)
    n_seg = int(segment.max()) + 1 if (segment >= 0).any() else 0
    if not n_sup or not n_seg:
        return segment
    z = cells[:, 2]
    rise, off_surface = 2.5 * voxel, cfg.layout.plane_voxels * voxel
    min_cells = max(cfg.min_cells, int(np.ceil(cfg.min_area / voxel**2)))
    surface_cells, segment_cells = members_of(supports.of_cell, n_sup), members_of(segment, n_seg)
    pair_surface, pair_segment = supports.of_cell[pairs], segment[pairs]
    # Which segments touch which surface, in the order of the surfaces.
    touch = np.concatenate([pair_surface[:, [1]], pair_segment[:, [0]], pair_surface[:, [0]], pair_segment[:, [1]]], 1)
    touch = touch.reshape(-1, 2)
    touch = touch[(touch >= 0).all(axis=1)]
    key = np.unique(touch[:, 0] * n_seg + touch[:, 1])  # one 1-D unique: a row-wise one is slow on many pairs
    touch = np.stack([key // n_seg, key % n_seg], 1)
    inner = (pair_segment[:, 0] == pair_segment[:, 1]) & (pair_segment[:, 0] >= 0)
    inner_pairs = pairs[inner]
    inner_of_segment = members_of(pair_segment[inner, 0], n_seg)
    next_id, shape_of = n_seg, {}
    for sup, seg in touch:
        members = surface_cells[sup]
        if len(members) < 3:
            continue
        if sup not in shape_of:
            xy = cells[members, :2]
            # The surface's narrower side: its extent across its principal axis.
            centred = xy - xy.mean(axis=0)
            axes = np.linalg.svd(centred, full_matrices=False)[2]
            shape_of[sup] = (xy, axes, float(np.ptp(centred @ axes[-1])))
        xy, axes, narrow = shape_of[sup]
        height = float(supports.height[sup])
        own = segment_cells[seg]
        still = segment[own] == seg  # not split off for another surface
        if not still.any() or z[own[still]].min() >= height - off_surface:
            continue  # it stands there as a whole
        is_above = still & (z[own] > height + off_surface)
        above = own[is_above]
        if len(above) < min_cells:
            continue
        # The surface's footprint with its rim: the segment's cells at its height (a top's edge,
        # whose normals bend, is left out of the surface and clustered with the apron).
        rim = own[still & (np.abs(z[own] - height) <= off_surface)]
        a, b = hull_equations(np.concatenate([xy, cells[rim, :2]]))
        over = ((cells[above, :2] @ a.T + b) <= voxel).all(axis=1)
        links = np.searchsorted(own, inner_pairs[inner_of_segment[seg]])
        links = links[is_above[links].all(axis=1)]
        part = linked(len(above), (np.cumsum(is_above) - 1)[links])
        lifted = still & (z[own] > height + 0.5 * voxel)  # candidates for a split part's foot
        for k in range(int(part.max()) + 1):
            # Wholly over the surface: a sofa's back rising behind its seat reaches beyond it.
            if not over[part == k].all():
                continue
            piece = above[part == k]
            if len(piece) < min_cells or z[piece].max() < height + rise:
                continue
            if z[piece].min() > height + off_surface + 1.5 * voxel:
                continue  # held above the surface, not standing on it
            span = float(np.ptp(cells[piece, :2] @ axes.T, axis=0).max())
            if span > STANDING_SHARE * narrow:
                continue
            # Its foot: the segment's cells off the surface by half a voxel, under its top view.
            pa, pb = hull_equations(cells[piece, :2])
            foot = own[lifted & ((cells[own, :2] @ pa.T + pb) <= 0.5 * voxel).all(axis=1)]
            segment[np.union1d(piece, foot)] = next_id
            next_id += 1
    return segment
