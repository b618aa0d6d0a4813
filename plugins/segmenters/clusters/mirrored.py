"""Pass ``cut_below_supports``: a thing standing on a support surface ends at that surface.

A worktop or a table top is opaque: what stands on it is not also seen beneath it, inside the
furniture that holds the surface up. A glossy surface (a black granite worktop, a lacquered table)
mirrors what stands on it, though, and the depth camera measures the mirror image: points up to
some 20 cm under the surface, in line with the object above. Fused, they join the object's
instance, whose box then reaches through the worktop. On a real kitchen, display stands on the
worktop became "cabinets" 0.4-0.8 m tall this way.

Of an instance standing on a support surface of another instance (most of its points above the
surface's height, over the top-view hull of the instance the surface belongs to: a worktop covers
its counter), the points below that height by more than the standing tolerance, over the hull,
leave it (to the layout's stuff there, or to nothing). A chair pushed in under a table keeps its
legs: most of it lies below the top."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.grid import hull_equations
from stratamap.plugins.segmenters.clusters.labelling import Labelling

#: An instance stands on a support surface when at least this share of its points lie above the
#: surface's height and over its hull (a chair pushed in under a table: a third at most).
STANDING_SHARE = 0.5
#: Top-view margin (m) of a support surface's hull: the surface under a thing is hidden by it, and its
#: seen cells stop short of the thing's foot.
HULL_MARGIN = 0.05


def cut_below_supports(lab: Labelling) -> None:
    """Sets ``class_ids`` and ``instance_ids`` of the points cut; notes ``cut_below_supports``."""
    if lab.supports is None or not len(lab.supports.height) or lab.instance_ids is None:
        return
    points, tolerance = lab.points, lab.standing_tolerance
    support_of_point = lab.support_of_point
    instance_ids = lab.instance_ids
    by_instance = members_of(instance_ids, int(instance_ids.max(initial=0)) + 1)
    surfaces = []
    for k, members in enumerate(members_of(support_of_point, len(lab.supports.height))):
        if len(members) < 3:
            continue
        owners = instance_ids[members]
        owner = int(np.bincount(owners[owners > 0]).argmax()) if (owners > 0).any() else 0
        # The surface covers the furniture holding it up: its seen cells may be a strip (a glossy
        # black worktop returns depth only near its edge).
        a, b = hull_equations(points[by_instance[owner] if owner else members, :2])
        surfaces.append((float(lab.supports.height[k]), a, b, owner))
    if not surfaces:
        return
    reach = _within_reach(points, by_instance, surfaces, tolerance)
    class_ids, new_ids = lab.class_ids.copy(), instance_ids.copy()
    notes = []
    for iid, members in enumerate(by_instance):
        if iid == 0 or not len(members) or not reach[iid].any():
            continue
        xy, z = points[members, :2], points[members, 2]
        for s in np.flatnonzero(reach[iid]):
            height, a, b, owner = surfaces[s]
            if owner == iid:
                continue
            over = ((xy @ a.T + b) <= HULL_MARGIN).all(axis=1)
            if (over & (z > height - tolerance)).mean() < STANDING_SHARE:
                continue
            below = members[over & (z < height - tolerance)]
            if not len(below):
                continue
            class_ids[below], new_ids[below] = lab.stuff_ids[lab.layout.labels[lab.cell_of_point[below]]], 0
            notes.append({"instance": iid, "points": int(len(below)), "surface_height": round(height, 3)})
    lab.class_ids, lab.instance_ids = class_ids, new_ids
    lab.note("cut_below_supports", notes)


def _within_reach(
    points: np.ndarray, by_instance: list[np.ndarray], surfaces: list[tuple], tolerance: float
) -> np.ndarray:
    """(instances, surfaces): whether any point of the instance's box may lie over the surface's
    hull (within the margin) and above its height less the tolerance. Only these pairs can pass the
    standing test; on a hall of 600 boxes, each one's own top is a support surface, and testing
    every instance's points against every hull cost 15 s."""
    n = len(by_instance)
    lo, hi = np.zeros((n, 2)), np.zeros((n, 2))
    top = np.full(n, -np.inf)  # an instance without points reaches nothing
    for iid, members in enumerate(by_instance):
        if len(members):
            lo[iid], hi[iid] = points[members, :2].min(axis=0), points[members, :2].max(axis=0)
            top[iid] = points[members, 2].max()
    reach = np.zeros((n, len(surfaces)), bool)
    for s, (height, a, b, _) in enumerate(surfaces):
        # The least of a linear function over a box is at a corner: per half-plane, per axis.
        least = b[None, :] + np.minimum(lo[:, :1] * a[None, :, 0], hi[:, :1] * a[None, :, 0])
        least += np.minimum(lo[:, 1:] * a[None, :, 1], hi[:, 1:] * a[None, :, 1])
        reach[:, s] = (least <= HULL_MARGIN).all(axis=1) & (top > height - tolerance)
    return reach
