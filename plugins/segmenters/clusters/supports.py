"""Passes ``grow_supports``, ``join_supports`` and ``return_feet``: support surfaces take the ring of
their top the plane fit left out, then get their object back (a table's legs and edge, a cabinet
under its counter top), while what stands on them stays apart (a cup, a monitor)."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.config import ClustersConfig
from stratamap.plugins.segmenters.clusters.grid import hull_equations
from stratamap.plugins.segmenters.clusters.labelling import Labelling, Supports
from stratamap.plugins.segmenters.clusters.layout import NONE

#: Support surfaces grow by this many rings of neighbouring cells at most.
GROW_RINGS = 3


def grow(lab: Labelling) -> None:
    """Sets ``supports`` (grown) and ``grown`` (the cells they took)."""
    free = lab.layout.labels == NONE
    lab.supports, lab.grown = grow_supports(
        lab.cells, lab.supports, free, lab.pairs, 0.5 * lab.voxel, lab.voxel, GROW_RINGS
    )


def join(lab: Labelling) -> None:
    """Sets ``obj``: an object id per cell, -1 for stuff."""
    has_floor = lab.layout.floor_height is not None
    lab.obj = join_supports(lab.cells, lab.segment, lab.supports, lab.pairs, lab.voxel, lab.cfg, has_floor)


def give_feet_back(lab: Labelling) -> None:
    """Sets ``obj`` and ``supports``: grown cells under what stands on a surface go back to it."""
    lab.obj, lab.supports = return_feet(lab.cells, lab.obj, lab.segment, lab.grown, lab.pairs, lab.supports)


def grow_supports(
    cells: np.ndarray,
    supports: Supports,
    free: np.ndarray,
    pairs: np.ndarray,
    tolerance: float,
    voxel: float,
    rings: int = 3,
) -> tuple[Supports, np.ndarray]:
    """Grow each support surface by up to ``rings`` rings of neighbouring ``free`` cells
    within ``tolerance`` of its height and inside its footprint (convex hull, grown by a voxel);
    returns the grown surfaces and the cells taken. Next to what stands on a table the normals bend and the layout's fit
    leaves a ring of the top out, through which a cup's segment would reach the table's edge and
    legs and join the table. Neighbours only: a chair's back at the table's height under its edge
    stays the chair's. One pass over the neighbour pairs per ring, whatever the number of surfaces."""
    n_sup = len(supports.height)
    if not n_sup or not len(pairs):
        return supports, np.zeros(0, np.int64)
    supports = supports._replace(of_cell=supports.of_cell.copy())
    z = cells[:, 2]
    hulls = [hull_equations(cells[m, :2]) if len(m) >= 3 else None for m in members_of(supports.of_cell, n_sup)]
    both = np.concatenate([pairs, pairs[:, ::-1]])
    # Only pairs from a cell that could join a surface (free, not on one, at a surface's height) matter.
    lo, hi = supports.height.min() - tolerance, supports.height.max() + tolerance
    both = both[free[both[:, 1]] & (z[both[:, 1]] >= lo) & (z[both[:, 1]] <= hi)]
    grown = []
    for _ in range(rings):
        k = supports.of_cell[both[:, 0]]
        open_ = (k >= 0) & (supports.of_cell[both[:, 1]] < 0)
        cand, k = both[open_, 1], k[open_]
        ok = np.abs(z[cand] - supports.height[k]) <= tolerance
        cand, k = cand[ok], k[ok]
        inside = np.zeros(len(cand), bool)
        for surface in np.unique(k):
            if hulls[surface] is None:
                continue
            sel = np.flatnonzero(k == surface)
            a, b = hulls[surface]
            inside[sel] = ((cells[cand[sel], :2] @ a.T + b) <= voxel).all(axis=1)
        cand, k = cand[inside], k[inside]
        if not len(cand):
            break
        # A cell next to two surfaces joins the lowest-numbered (deterministic).
        order = np.lexsort((k, cand))
        cand, k = cand[order], k[order]
        first = np.r_[True, cand[1:] != cand[:-1]]
        supports.of_cell[cand[first]] = k[first]
        grown.append(cand[first])
    return supports, (np.concatenate(grown) if grown else np.zeros(0, np.int64))


def return_feet(
    cells: np.ndarray, obj: np.ndarray, segment: np.ndarray, grown: np.ndarray, pairs: np.ndarray, supports: Supports
) -> tuple[np.ndarray, Supports]:
    """Cells a support took by :func:`grow_supports` that touch a clustered cell above them (the
    bottom row of a cup standing on a table) go back to that cell's object (the nearest such) and
    leave the support. Returns the objects and the support surfaces (new arrays)."""
    if not len(grown) or not len(pairs):
        return obj, supports
    is_grown = np.zeros(len(cells), bool)
    is_grown[grown] = True
    both = np.concatenate([pairs, pairs[:, ::-1]])
    foot, above = both[:, 0], both[:, 1]
    keep = is_grown[foot] & (segment[above] >= 0) & (obj[above] >= 0) & (cells[above, 2] > cells[foot, 2])
    foot, above = foot[keep], above[keep]
    if not len(foot):
        return obj, supports
    obj, supports = obj.copy(), supports._replace(of_cell=supports.of_cell.copy())
    order = np.lexsort((above, np.linalg.norm(cells[above] - cells[foot], axis=1), foot))
    foot, above = foot[order], above[order]
    first = np.r_[True, foot[1:] != foot[:-1]]
    obj[foot[first]] = obj[above[first]]
    supports.of_cell[foot[first]] = -1  # no longer the support's top
    return obj, supports


def join_supports(
    cells: np.ndarray,
    segment: np.ndarray,
    supports: Supports,
    pairs: np.ndarray,
    voxel: float,
    cfg: ClustersConfig,
    has_floor: bool = True,
) -> np.ndarray:
    """Give each support surface its object back. ``segment``: segment id per cell (-1 for cells
    not clustered: stuff and supports); ``pairs``: neighbouring cells. Returns an object id per
    cell (-1 for stuff): segments standing on a support stay apart from it, the rest of what touches
    it (edges, legs, the body under a counter top, and what touches those below the surface) joins it.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_seg = int(segment.max()) + 1 if (segment >= 0).any() else 0
    n_sup = len(supports.height)
    z = cells[:, 2]
    clustered = segment >= 0
    # A segment's foot and top, and its size.
    bottom, top = np.full(n_seg, np.inf), np.full(n_seg, -np.inf)
    np.minimum.at(bottom, segment[clustered], z[clustered])
    np.maximum.at(top, segment[clustered], z[clustered])
    count = np.bincount(segment[clustered], minlength=n_seg)
    node = np.where(clustered, segment, np.where(supports.of_cell >= 0, n_seg + supports.of_cell, -1))
    a, b = node[pairs[:, 0]], node[pairs[:, 1]]
    touching = (a >= 0) & (b >= 0) & (a != b)
    edges = np.unique(np.sort(np.stack([a[touching], b[touching]], 1), axis=1), axis=0)
    links: list[tuple[int, int]] = []
    if n_sup and n_seg:
        # Each support's footprint: the convex hull of its top, so the hole an object's shadow
        # leaves in the scanned top still counts as on it; grown by a voxel for its rim.
        hulls = [hull_equations(cells[m, :2]) for m in members_of(supports.of_cell, n_sup)]
        order = np.argsort(segment, kind="stable")
        starts = np.searchsorted(segment[order], np.arange(n_seg + 1))
        rise = 2.5 * voxel
        stand_tol = 2.0 * cfg.layout.plane_voxels * voxel

        def inside(seg: int, sup: int) -> float:
            xy = cells[order[starts[seg] : starts[seg + 1]], :2]
            a, b = hulls[sup]
            return float(((xy @ a.T + b) <= voxel).all(axis=1).mean())

        sup_edges = edges[(edges[:, 0] < n_seg) & (edges[:, 1] >= n_seg)]
        stands = np.zeros(n_seg, bool)
        for seg, sup_node in sup_edges:
            sup = sup_node - n_seg
            # Its foot at the surface and rising above it: it stands there (a cup, or a box at the edge
            # of a partly seen table, its footprint out of the hull). What reaches below is the table's.
            if bottom[seg] >= supports.height[sup] - stand_tol and top[seg] >= supports.height[sup] + rise:
                stands[seg] = True
        owners: list[list[int]] = [[] for _ in range(n_seg)]  # the supports a segment joined
        for seg, sup_node in sup_edges:
            if not stands[seg]:
                links.append((int(seg), int(sup_node)))
                owners[seg].append(int(sup_node - n_seg))
        # What touches a joined segment and lies wholly below one of its supports (legs under the
        # edge) joins too.
        seg_edges = edges[edges[:, 1] < n_seg]
        grown = True
        while grown:  # each round joins at least one segment, so at most n_seg rounds
            grown = False
            for s1, s2 in np.concatenate([seg_edges, seg_edges[:, ::-1]]):
                if not owners[s1] or owners[s2] or stands[s2]:
                    continue
                for sup in owners[s1]:
                    if top[s2] <= supports.height[sup] + stand_tol and inside(s2, sup) >= cfg.below_share:
                        owners[s2].append(sup)
                        links.append((int(s2), int(n_seg + sup)))
                        grown = True
                        break
        if not has_floor:
            # No floor (a tabletop scan): what lies wholly below the largest support is its
            # furniture (its edge, legs, what stands under it); the scan sees nothing else there.
            main = int(np.argmax(supports.area))
            below = np.flatnonzero((top <= supports.height[main] + stand_tol) & ~stands & (count > 0))
            links += [(int(seg), n_seg + main) for seg in below]
    n = n_seg + n_sup
    if n == 0:  # all stuff (a scan of a bare floor)
        return np.full(len(cells), -1, np.int64)
    pairs_ = np.array(links, np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs_)), (pairs_[:, 0], pairs_[:, 1])), shape=(n, n))
    obj = connected_components(graph, directed=False)[1].astype(np.int64)
    return np.where(node >= 0, obj[np.maximum(node, 0)], -1)
