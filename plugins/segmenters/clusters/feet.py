"""Pass ``trim_feet``: a thing gives back its points at its foot that lie outside its body's
footprint, where the floor or a support surface goes on beyond them (the ring of table top a
detector's mask takes at a cup's foot)."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.grid import hull_equations
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import FLOOR


def give_back_feet(lab: Labelling) -> None:
    """Sets ``class_ids`` and ``instance_ids``."""
    if not lab.cfg.trim_feet:
        return
    surface_of_cell = np.where(lab.layout.labels == FLOOR, len(lab.supports.height), lab.supports.of_cell)
    lab.class_ids, lab.instance_ids, feet = trim_feet(
        lab.points, lab.class_ids, lab.instance_ids, surface_of_cell[lab.cell_of_point], lab.voxel
    )
    lab.counts["foot_points_given_back"] = feet


def trim_feet(
    points: np.ndarray,
    class_ids: np.ndarray,
    instance_ids: np.ndarray,
    surface_of_point: np.ndarray,
    voxel: float,
) -> tuple[np.ndarray, np.ndarray, int]:
    """A thing gives back its points at its foot (within half a voxel of its lowest point) outside the
    top-view convex hull of its body (its points more than 1.5 voxels up) by more than half a voxel,
    where a surface things stand on goes on beyond them (``surface_of_point``: a support surface's id
    or the floor's, -1 for none): such a point takes the class and instance of a point of something
    else in such a surface, level with it (within half a voxel) and within two voxels, or of one of
    its own that did so first, from the outside in. Returns the new classes and instances, and how many moved.

    A detector's mask around a cup takes a ring of the table top with it, which widens the cup's box
    by half; its own base and a chair's feet lie under their bodies and stay, and a surface that is
    the thing's own (a seat's top, under a back) has nothing else in it to give back to. Things with
    no body above their base layer (a sheet of paper, a book lying flat) are left as they are."""
    from scipy.spatial import cKDTree

    class_ids, instance_ids = class_ids.copy(), instance_ids.copy()
    n = int(instance_ids.max()) if len(instance_ids) else 0
    rings = []
    for k, idx in enumerate(members_of(instance_ids, n + 1)):
        if k == 0 or len(idx) < 4:
            continue
        z = points[idx, 2]
        foot = float(z.min())
        body = z > foot + 1.5 * voxel
        layer = np.flatnonzero(z <= foot + 0.5 * voxel)
        if body.sum() < 3 or not len(layer):
            continue
        a, b = hull_equations(points[idx[body], :2])
        beyond = (points[idx[layer], :2] @ a.T + b).max(axis=1)
        outside = beyond > 0.5 * voxel
        if outside.any():
            rings.append((idx[layer[outside]], beyond[outside]))
    if not rings:
        return class_ids, instance_ids, 0
    ring = np.concatenate([r for r, _ in rings])
    # Farthest from the body first, so that a ring wider than the search radius moves from outside in.
    ring = ring[np.argsort(-np.concatenate([d for _, d in rings]), kind="stable")]
    near_dist, near = cKDTree(points).query(points[ring], k=16, distance_upper_bound=2.0 * voxel)
    owner = instance_ids[ring].copy()
    surface_of_point = surface_of_point.copy()
    pending = np.ones(len(ring), bool)
    while pending.any():
        moved_now = 0
        for row in np.flatnonzero(pending):
            for d, j in zip(near_dist[row], near[row], strict=True):
                if not np.isfinite(d):
                    break
                level = abs(points[j, 2] - points[ring[row], 2]) <= 0.5 * voxel
                if instance_ids[j] != owner[row] and surface_of_point[j] >= 0 and level:
                    class_ids[ring[row]], instance_ids[ring[row]] = class_ids[j], instance_ids[j]
                    surface_of_point[ring[row]] = surface_of_point[j]
                    pending[row] = False
                    moved_now += 1
                    break
        if not moved_now:
            break
    return class_ids, instance_ids, int((~pending).sum())
