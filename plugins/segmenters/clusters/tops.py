"""Pass ``split_beside_tops``: an object built around its top (UNDER_THEIR_TOP: a table, a desk) lies
under that top, so what its instance holds beside the top's outline is something else that touched
it: the chairs pushed in at a dining table.

On a real kitchen the frames' detector boxes a dining table and the chairs pushed in at it in one box
and misses the chairs; the depth segments that touch the table join its mask, the fused votes call
the chairs "table", and the table's instance holds five chairs. The votes hold no evidence against
that; the geometry does: a table's legs and a desk's pedestals stand under the top's outline, a
chair's seat and back beside it."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.priors import UNDER_THEIR_TOP, UNNAMED
from stratamap.plugins.segmenters.clusters.grid import components, neighbour_pairs
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import fits_class

#: The outline's grid (m): coarse enough that a top's unseen strips between seen ones (behind a cup,
#: a sink's rim) close, fine enough that a chair pushed in to the table's edge stays outside.
OUTLINE_CELL = 0.05
#: A top is at least this large (m^2): a chair's seat (0.2 m^2) is a support surface but no top
#: its back stands beside.
MIN_TOP_AREA = 0.3
#: The top's outline grows by this many outline cells before anything is beside it: a top's rim and
#: a leg set in under its edge are the object's.
MARGIN_CELLS = 1
#: Holes in the seen top up to this many outline cells across close (what stood on it hid the top).
CLOSE_CELLS = 2
#: Under the top means this far (m) below its level or more: the top's own rim and apron are not, and a
#: part beside the top lying wholly within this of its level is its rim.
BELOW_TOP = 0.1
#: A part beside the top takes what it reaches under the top up to this far (m): a chair's seat
#: pushed under a table, not the table's legs across it.
UNDER_REACH = 0.6
#: A part holding this much (m^2) at the top's level (within LEVEL_BAND m) is the top going on, beyond
#: where the plane fit stopped (a coffee table's top half under two cups); a chair's back crossing a
#: table's level holds 0.02-0.05 m^2 there.
TOP_GOES_ON = 0.1
LEVEL_BAND = 0.03
#: A part splits off only where the sensor saw through the top's level over it, by this many rays or
#: more (a chair's seat beside a table, open above): where nothing was seen there the top may be
#: there unseen, and the part is the object's (an island's end whose worktop no frame looked at).
MIN_RAYS_THROUGH = 10
#: A piece beside the top within this many voxels of another instance is a piece of that one.
TOUCH_VOXELS = 2.0


def split_beside_tops(lab: Labelling) -> None:
    """Sets ``class_ids``, ``instance_ids`` and ``naming``: each part beside a top's outline (with
    what it reaches under the top) joins another instance it touches, or, large enough to be an
    object (``scrap_size`` cells), becomes an instance of its own, unnamed until
    the passes after name it; other parts leave the instance (the layout's or nothing's). The parts
    and the table are kept apart from then on (``Labelling.keep_apart``). Each split is noted
    (``split_beside_tops``)."""
    from scipy.spatial import cKDTree

    from stratamap.core.map.instances import instance_members

    if not lab.cfg.recognize:
        return
    vocab = lab.vocab
    with_tops = {vocab.id(name) for name in UNDER_THEIR_TOP if name in vocab}
    if not with_tops or UNNAMED not in vocab:
        return
    support_of_point, areas = lab.support_of_point, lab.supports.area
    stuff_ids, labels = lab.stuff_ids, lab.layout.labels
    radius = lab.cfg.radius_voxels * lab.voxel
    next_id = int(lab.instance_ids.max(initial=0)) + 1
    splits = []
    for iid, sel in instance_members(lab.instance_ids).items():
        cls = int(np.bincount(lab.class_ids[sel]).argmax())
        if cls not in with_tops:
            continue
        found = beside_top(lab.points[sel], support_of_point[sel], areas)
        if found is None or not found[0].any():
            continue
        beside, below, level = found
        own, cell_of_member = np.unique(lab.cell_of_point[sel], return_inverse=True)
        cell_of_member = cell_of_member.reshape(-1)
        part = parts_beside(lab.cells[own], cell_of_member, beside, below, radius)
        size = np.bincount(part[part >= 0])
        crossing = lab.sight.across_level(level) if lab.sight is not None else None
        leaving = []
        for k in np.argsort(-size, kind="stable"):
            members = sel[part[cell_of_member] == k]
            z = lab.points[members, 2]
            if z.min() > level - BELOW_TOP and z.max() < level + BELOW_TOP:
                continue  # within the top's own thickness: its rim, which the plane fit left out
            level_cells = np.floor(lab.points[members[np.abs(z - level) <= LEVEL_BAND], :2] / OUTLINE_CELL)
            if len(np.unique(level_cells, axis=0)) * OUTLINE_CELL**2 >= TOP_GOES_ON:
                continue  # the top going on at its level where the plane fit stopped: the object's
            if not seen_open(crossing, lab.points[sel[beside & (part[cell_of_member] == k)], :2]):
                continue  # nothing shows the top is not there too: a part of the object whose top is unseen
            leaving.append((members, int(size[k])))
        if not leaving:
            continue
        # What stays must still be of its class by its shape: a sofa or a counter the frames called a
        # table holds its back or its front beside its seat or its worktop.
        rest = np.setdiff1d(sel, np.concatenate([m for m, _ in leaving]))
        if len(rest) < 4 or not fits_class(vocab.name(cls), lab.shape(rest)):
            continue
        # The other instances' points, for what a leaving part touches: only once something leaves.
        others = np.flatnonzero((lab.instance_ids > 0) & (lab.instance_ids != iid))
        near = cKDTree(lab.points[others]) if len(others) else None
        moved, joined, dropped = [], [], 0
        for members, cells in leaving:
            neighbour = touching(members, lab.points, near, others, lab.instance_ids, TOUCH_VOXELS * lab.voxel)
            if neighbour:
                # A piece of what stands beside the top, which the frames' masks made an instance of.
                its_class = int(np.bincount(lab.class_ids[lab.instance_ids == neighbour]).argmax())
                lab.relabel(members, instance=neighbour, cls=its_class)
                joined.append(neighbour)
            elif cells >= lab.scrap_size:
                lab.relabel(members, instance=next_id, cls=vocab.id(UNNAMED))
                lab.naming[next_id] = ("unnamed", f"beside the top of object {iid}")
                moved.append(next_id)
                next_id += 1
            else:
                lab.relabel(members, instance=0, cls=stuff_ids[labels[lab.cell_of_point[members]]])
                dropped += len(members)
        rest = sel[lab.instance_ids[sel] == iid]
        for new in {*moved, *joined}:
            lab.keep_apart(np.flatnonzero(lab.instance_ids == new), rest)
        if moved or joined or dropped:
            splits.append(
                {
                    "instance": iid,
                    "class": vocab.name(cls),
                    "new_instances": moved,
                    "joined_to": sorted(set(joined)),
                    "points_dropped": dropped,
                }
            )
    lab.note("split_beside_tops", splits)


def beside_top(
    points: np.ndarray, support: np.ndarray, areas: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Which of one object's points lie beside the outline of its highest support surface of
    MIN_TOP_AREA or more (its top), on an OUTLINE_CELL grid closed over small holes and grown by
    MARGIN_CELLS, which lie under the top by BELOW_TOP or more, and the top's height; None when it
    holds no such top."""
    from scipy import ndimage

    on = support >= 0
    if not on.any():
        return None
    ids = np.unique(support[on])
    ids = ids[areas[ids] >= MIN_TOP_AREA]
    if not len(ids):
        return None
    # The highest (a coffee table's low shelf may be larger than its top, under the cups).
    heights = [float(np.median(points[support == i, 2])) for i in ids]
    top = int(ids[int(np.argmax(heights))])
    cell = np.floor(points[:, :2] / OUTLINE_CELL).astype(np.int64)
    pad = CLOSE_CELLS + MARGIN_CELLS + 1
    origin = cell.min(axis=0) - pad
    shape = tuple(cell.max(axis=0) - origin + pad + 1)
    grid = np.zeros(shape, bool)
    on_top = support == top
    top_cells = cell[on_top] - origin
    grid[top_cells[:, 0], top_cells[:, 1]] = True
    grid = ndimage.binary_closing(grid, iterations=CLOSE_CELLS)
    grid = ndimage.binary_fill_holes(grid)
    grid = ndimage.binary_dilation(grid, iterations=MARGIN_CELLS)
    local = cell - origin
    beside = ~grid[local[:, 0], local[:, 1]]
    level = float(np.median(points[on_top, 2]))
    return beside, ~beside & (points[:, 2] <= level - BELOW_TOP), level


def seen_open(crossing: tuple[np.ndarray, np.ndarray] | None, xy: np.ndarray) -> bool:
    """Whether the sensor saw through the top's level over the points ``xy`` (OUTLINE_CELL cells):
    MIN_RAYS_THROUGH of the rays ``crossing`` it there (``Sightlines.across_level``) went on past it.
    Without rays (a point cloud) nothing shows it."""
    if crossing is None or not len(xy) or not len(crossing[0]):
        return False
    cells = np.floor(xy / OUTLINE_CELL).astype(np.int64)
    low = cells.min(axis=0)
    grid = np.zeros(cells.max(axis=0) - low + 1, bool)
    grid[tuple((cells - low).T)] = True
    where, through = crossing
    at = np.floor(where[through] / OUTLINE_CELL).astype(np.int64) - low
    inside = (at >= 0).all(axis=1) & (at < grid.shape).all(axis=1)
    return int(grid[tuple(at[inside].T)].sum()) >= MIN_RAYS_THROUGH


def parts_beside(
    cells: np.ndarray, cell_of_point: np.ndarray, beside: np.ndarray, below: np.ndarray, radius: float
) -> np.ndarray:
    """Per cell of one object: the part beside its top it belongs to, -1 for the object's own. Parts
    are the connected pieces of the cells beside the top; each then takes the cells under the top
    it reaches first (connected through cells under it, no farther than UNDER_REACH): a chair pushed
    in has its seat under the table's top and its back beside it."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    n = len(cells)
    is_beside = np.zeros(n, bool)
    is_beside[cell_of_point[beside]] = True
    is_below = np.zeros(n, bool)
    is_below[cell_of_point[below]] = True
    is_below &= ~is_beside
    part = np.full(n, -1, np.int64)
    idx = np.flatnonzero(is_beside)
    part[idx] = components(len(idx), neighbour_pairs(cells[idx], radius))
    reach = np.flatnonzero(is_beside | is_below)
    pairs = neighbour_pairs(cells[reach], radius)
    if not len(pairs) or not is_below.any():
        return part
    length = np.linalg.norm(cells[reach[pairs[:, 0]]] - cells[reach[pairs[:, 1]]], axis=1)
    graph = coo_matrix((length, (pairs[:, 0], pairs[:, 1])), shape=(len(reach),) * 2).tocsr()
    sources = np.flatnonzero(is_beside[reach])
    _, _, nearest = dijkstra(
        graph, directed=False, indices=sources, min_only=True, limit=UNDER_REACH, return_predecessors=True
    )
    taken = is_below[reach] & (nearest >= 0)
    part[reach[taken]] = part[reach[nearest[taken]]]
    return part


def touching(
    members: np.ndarray, points: np.ndarray, tree, others: np.ndarray, instance_ids: np.ndarray, reach: float
) -> int:
    """The instance (of ``others``' points, in ``tree``) that most of the points ``members`` within
    ``reach`` touch; 0 for none."""
    if tree is None:
        return 0
    dist, hit = tree.query(points[members], distance_upper_bound=reach)
    hit = hit[np.isfinite(dist)]
    if not len(hit):
        return 0
    ids, counts = np.unique(instance_ids[others[hit]], return_counts=True)
    return int(ids[np.argmax(counts)])
