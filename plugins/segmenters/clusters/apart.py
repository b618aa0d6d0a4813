"""Pass ``split_seen_apart``: the parts of one object touch, so an instance whose parts the frames
saw empty space between is two objects.

A detector's 2D mask covers whatever lies behind it in the image. On a real kitchen the frames'
counter mask also took the wall shelf 0.4 m above the worktop, and the fused votes gave the counter
both: a 1.5 m tall counter that matches its true box with IoU 0.43 and a shelf that is no object. The
votes hold no evidence against that. The geometry does, with the frames' depth: no point lies between
the two parts, and the depth rays passed through the space between them on their way to the tiles
behind. Where that space was never seen (a chair's seat under a table top, between the backrest seen
over the table and the legs seen under it), nothing says the parts are apart, and they stay one."""

from __future__ import annotations

import numpy as np

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.priors import UNNAMED
from stratamap.plugins.segmenters.clusters.enclosed import ENCLOSED_MARGIN_VOXELS, ENCLOSED_SHARE
from stratamap.plugins.segmenters.clusters.grid import components, neighbour_pairs
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import NONE

#: Parts closer than this (m) are not judged: a gap that small is a seam or a thin part the map lost.
MIN_GAP = 0.15
#: The gap is judged along the lines from this many of the part's cells facing the rest to their
#: nearest cells of the rest, spread over the facing cells: those within FACING times the least
#: distance (a shelf's whole underside over a worktop, not only its edge along the wall).
PATHS = 12
FACING = 1.5
#: A point on such a line is seen empty when this many frames saw past it (one frame's ray may run
#: past an edge by its noise).
MIN_FRAMES = 2
#: The parts are apart when this share of the points along the lines (their ends' own surfaces left
#: out) was seen empty.
SEEN_SHARE = 0.8
#: A point on such a line is judged only this far (m) or more from every surface of the map: nearer,
#: a ray that ends on that surface runs past it by less than the depth noise (FreeSpace's BEYOND), and
#: nothing can be seen free there (the ends of the line, the wall a shelf and a counter both touch).
CLEARANCE = 0.06
#: Fewer judged points than this on all the lines together say nothing.
MIN_JUDGED = 5
#: A piece hangs on a wall when wall cells lie within this (m) of it: a wall cabinet or shelf seen
#: from the front only lies its own depth, up to 0.4 m, from the wall.
HANG_REACH = 0.45


def split_seen_apart(lab: Labelling) -> None:
    """Sets ``class_ids``, ``instance_ids`` and ``naming``: each part of a thing instance (connected
    cells within ``radius_voxels``) of ``scrap_size`` cells or more that lies MIN_GAP or more from the
    rest of the instance, across space the frames saw empty (``gap_seen_empty``), and where each of
    the two stands or hangs without the other (``Footing.holds``), becomes an instance of its own, unnamed
    until the passes after name it; a part lying mostly on the layout (floor, wall, ceiling cells) becomes
    that stuff (noted with ``part`` 0). Smallest parts are judged first, each against what the instance
    still holds; the largest part keeps the instance. Each split is noted (``split_seen_apart``) and
    kept apart from the rest by the joining passes after it. Needs posed depth frames
    (``Labelling.free_space``): without them nothing changes."""
    from scipy.spatial import cKDTree

    from stratamap.core.map.instances import instance_members

    if not lab.cfg.recognize or UNNAMED not in lab.vocab:
        return
    radius = lab.cfg.radius_voxels * lab.voxel
    next_id = int(lab.instance_ids.max(initial=0)) + 1
    splits = []
    # Every cell of the map (for what is too near a surface to judge) and what holds objects up: built
    # when an instance first has two parts.
    surfaces = footing = None
    for iid, sel in instance_members(lab.instance_ids).items():
        cls = int(np.bincount(lab.class_ids[sel]).argmax())
        if not lab.vocab.is_thing[cls]:
            continue
        own, cell_of_member = np.unique(lab.cell_of_point[sel], return_inverse=True)
        if len(own) < 2 * lab.scrap_size:
            continue
        cell_of_member = cell_of_member.reshape(-1)
        cells = lab.cells[own]
        part = components(len(own), neighbour_pairs(cells, radius))
        size = np.bincount(part)
        if (size >= lab.scrap_size).sum() < 2:
            continue
        free = lab.free_space
        if free is None:
            return
        if surfaces is None:
            surfaces, footing = cKDTree(lab.cells), Footing(lab)
        remaining = np.ones(len(own), bool)
        order = np.argsort(size, kind="stable")[:-1]  # smallest first; the largest part stays
        for k in order:
            if size[k] < lab.scrap_size:
                continue
            mine = part == k
            rest = remaining & ~mine
            # Two objects each stand or hang: a swivel chair's seat and back over its base (their
            # column lost between them) is held up by nothing but that base. Every large part left
            # must, not only one of them (a table beside that seat holds up only itself).
            left = [q for q in np.unique(part[rest]) if size[q] >= lab.scrap_size]
            if not footing.holds(own[mine]) or not all(footing.holds(own[rest & (part == q)]) for q in left):
                continue
            # A piece within the rest's box is a part of it, as join_enclosed has it (a table's
            # stretcher under its top).
            within = gravity_aligned_box(cells[rest]).contains(cells[mine], ENCLOSED_MARGIN_VOXELS * lab.voxel)
            if within.mean() >= ENCLOSED_SHARE:
                continue
            # Last, as it costs most: the frames saw the gap between them empty.
            if not gap_seen_empty(cells[mine], cells[rest], free, lab.voxel, surfaces):
                continue
            remaining &= ~mine
            members = sel[mine[cell_of_member]]
            labels = lab.layout.labels[own[mine]]
            if (labels != NONE).mean() > 0.5:
                # Apart from the object and on the room's walls or floor, as the layout found: that stuff,
                # which a frame's mask took along (a strip of wall beside a chair).
                lab.relabel(members, instance=0, cls=lab.stuff_ids[lab.layout.labels[lab.cell_of_point[members]]])
                splits.append({"instance": iid, "class": lab.vocab.name(cls), "part": 0, "points": len(members)})
                continue
            lab.relabel(members, instance=next_id, cls=lab.vocab.id(UNNAMED))
            lab.naming[next_id] = ("unnamed", f"seen apart from object {iid}")
            lab.keep_apart(members, sel[remaining[cell_of_member]])
            splits.append({"instance": iid, "class": lab.vocab.name(cls), "part": next_id, "points": len(members)})
            next_id += 1
    lab.note("split_seen_apart", splits)


def gap_seen_empty(part: np.ndarray, rest: np.ndarray, free, voxel: float, surfaces=None) -> bool:
    """Whether the cells ``part`` lie MIN_GAP or more from the cells ``rest`` across space ``free``
    (a ``FreeSpace``) saw empty: along the lines from PATHS cells of ``part`` facing ``rest`` to
    their nearest cells of ``rest``, one point per voxel, those CLEARANCE or more from every surface
    (``surfaces``: a k-d tree of the map's cells; default the two parts') are judged, and SEEN_SHARE
    of them (MIN_JUDGED at least) were seen empty by MIN_FRAMES frames or more."""
    from scipy.spatial import cKDTree

    if not len(part) or not len(rest):
        return False
    dist, nearest = cKDTree(rest).query(part)
    if dist.min() < MIN_GAP:
        return False
    facing = np.flatnonzero(dist <= FACING * dist.min())
    closest = facing[np.unique(np.linspace(0, len(facing) - 1, PATHS).round().astype(int))]
    samples = np.concatenate(
        [part[i] + np.outer(np.arange(voxel, dist[i], voxel) / dist[i], rest[nearest[i]] - part[i]) for i in closest]
    )
    if surfaces is None:
        surfaces = cKDTree(np.vstack([part, rest]))
    samples = samples[surfaces.query(samples)[0] >= CLEARANCE]
    if len(samples) < MIN_JUDGED:
        return False
    return bool((free.seen_free(samples) >= MIN_FRAMES).mean() >= SEEN_SHARE)


class Footing:
    """What holds objects up in one labelling: the floor's height, the support surfaces' cells and
    the wall cells (a k-d tree, built when first asked)."""

    def __init__(self, lab: Labelling) -> None:
        from stratamap.plugins.segmenters.clusters.layout import WALL

        self.lab = lab
        self.surface = np.flatnonzero(lab.supports.of_cell >= 0)
        self.walls = lab.cells[lab.layout.labels == WALL]
        self._wall_tree = None

    def holds(self, own: np.ndarray) -> bool:
        """Whether the cells ``own`` (indices into ``lab.cells``) stand or hang by themselves: their
        bottom at the floor's height or at that of a support surface under them that is not theirs
        (within ``standing_tolerance``), or wall cells within HANG_REACH of them."""
        from scipy.spatial import cKDTree

        lab = self.lab
        cells, tolerance = lab.cells[own], lab.standing_tolerance
        bottom = float(cells[:, 2].min())
        if bottom - lab.base_z <= tolerance:
            return True
        lo, hi = cells[:, :2].min(axis=0) - tolerance, cells[:, :2].max(axis=0) + tolerance
        under = lab.cells[self.surface[~np.isin(self.surface, own)]]
        if (
            (np.abs(under[:, 2] - bottom) <= tolerance)
            & np.all(under[:, :2] >= lo, axis=1)
            & np.all(under[:, :2] <= hi, axis=1)
        ).any():
            return True
        if not len(self.walls):
            return False
        if self._wall_tree is None:
            self._wall_tree = cKDTree(self.walls)
        return bool(np.isfinite(self._wall_tree.query(cells, distance_upper_bound=HANG_REACH)[0]).any())
