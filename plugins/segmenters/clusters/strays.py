"""Pass ``drop_strays``: a thing's few cells apart from the rest of it and above everything else it
holds (a wall corner's cells a metre above a sofa), or far from the rest of it (a point or two a
frame's mask caught across the room), are not the object; they leave the instance before it is
named and measured."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.grid import components, neighbour_pairs
from stratamap.plugins.segmenters.clusters.labelling import Labelling

#: A small part of an instance this many voxels or more away from the rest of it and as far above all of
#: it is a stray, not a piece the map saw apart (a chair's back over an unseen joint is no small part).
STRAY_GAP_VOXELS = 4.0
#: A small part of an instance this far (m) from the rest of it is a stray at any height: farther than
#: any part of one object the sensor can miss between two of its seen parts (a caster past its spoke,
#: a worktop's edge: 15 cm). On a real kitchen two such points 2 m past a counter run's end made its
#: box 4.9 m long instead of 2.7 m, and no counter matched.
STRAY_FAR = 0.5


def drop_strays(lab: Labelling) -> None:
    """Sets ``class_ids`` and ``instance_ids``: strays become the layout's (or nothing's) and no instance."""
    if not lab.cfg.drop_strays:
        return
    class_ids, instance_ids = lab.class_ids.copy(), lab.instance_ids.copy()
    cells, cell_of_point, stuff_ids, labels = lab.cells, lab.cell_of_point, lab.stuff_ids, lab.layout.labels
    strays = 0
    radius, gap = lab.cfg.radius_voxels * lab.voxel, STRAY_GAP_VOXELS * lab.voxel
    for members in members_of(instance_ids, int(instance_ids.max(initial=0)) + 1)[1:]:
        # On the working grid's cells: a raw scan holds many points per cell.
        own, cell_of_member = np.unique(cell_of_point[members], return_inverse=True)
        if len(own) > 1:
            stray_cell = stray_points(cells[own], radius, gap, lab.scrap_size, STRAY_FAR)
            stray = members[stray_cell[cell_of_member.reshape(-1)]]
            class_ids[stray], instance_ids[stray] = stuff_ids[labels[cell_of_point[stray]]], 0
            strays += len(stray)
    lab.class_ids, lab.instance_ids = class_ids, instance_ids
    lab.counts["stray_points_dropped"] = strays


def stray_points(points: np.ndarray, radius: float, gap: float, smallest: int, far: float = np.inf) -> np.ndarray:
    """Which of one instance's points (z up) are strays: connected parts (neighbours within
    ``radius``) of fewer than ``smallest`` points, other than its largest part, that lie ``gap`` or
    more from that largest part and rise ``gap`` or more above the highest of all its other points,
    or that lie ``far`` or more from it at any height. Nothing holds the first up: a few cells of a
    wall corner a metre above a sofa double its box, and no rule names a 1.7 m sofa. The second is
    not the object either: a point or two a frame's mask caught across the room. A part beside the
    rest (a swivel chair's caster past its unseen spoke, on the floor) or within its height (the
    scraps of a worktop's edge) stays."""
    from scipy.spatial import cKDTree

    stray = np.zeros(len(points), bool)
    if len(points) < 2:
        return stray
    part = components(len(points), neighbour_pairs(points, radius))
    size = np.bincount(part)
    main = int(size.argmax())
    top = np.full(len(size), -np.inf)
    np.maximum.at(top, part, points[:, 2])
    order = np.argsort(-top, kind="stable")
    # The highest point of all the other parts: the highest part's, or for that part the next one's.
    others_top = np.where(np.arange(len(size)) == order[0], top[order[min(1, len(order) - 1)]], top[order[0]])
    above = top >= others_top + gap
    # Without a finite ``far`` only a part rising above the rest can be a stray.
    candidate = (size < smallest) & (above | np.isfinite(far))
    candidate[main] = False
    if not candidate.any():
        return stray
    apart = np.full(len(size), np.inf)
    on_candidate = candidate[part]
    np.minimum.at(apart, part[on_candidate], cKDTree(points[part == main]).query(points[on_candidate])[0])
    return (candidate & (((apart >= gap) & above) | (apart >= far)))[part]
