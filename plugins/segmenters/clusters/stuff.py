"""Passes ``layout`` and ``flush_to_layout``: floor, walls and ceiling are stuff and leave the
object search; horizontal surfaces at table and counter heights are support surfaces, kept out of
the clustering so that what stands on them comes apart from them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from stratamap.plugins.segmenters.clusters.grid import neighbour_pairs
from stratamap.plugins.segmenters.clusters.labelling import Labelling, Supports
from stratamap.plugins.segmenters.clusters.layout import NONE, find_layout

#: An object's cells on a layout plane are the plane's when their normals turn less than this from it.
FLUSH_DEG = 45.0


def find_stuff(lab: Labelling) -> None:
    """Sets ``layout``, ``supports`` and ``pairs`` (neighbouring cells that are not stuff)."""
    cfg = lab.cfg
    layout = find_layout(
        lab.cells,
        lab.voxel,
        normals=lab.normals,
        gravity=cfg.gravity == "z",
        params=cfg.layout,
        viewpoints=lab.views,
        floor_hint=lab.floor_hint,
    )
    supports = Supports(
        np.full(len(lab.cells), -1, np.int64),
        np.array([s.height for s in layout.supports]),
        np.array([s.area for s in layout.supports]),
    )
    for k, surface in enumerate(layout.supports):
        supports.of_cell[surface.indices] = k
    objects = np.flatnonzero(layout.labels == NONE)
    lab.layout, lab.supports = layout, supports
    lab.pairs = objects[neighbour_pairs(lab.cells[objects], cfg.radius_voxels * lab.voxel)]


def flush_to_layout(lab: Labelling) -> None:
    """Cells of an object lying on a layout plane and facing its way are the plane's (where the
    object touches a wall, the normals there are bent and the layout fit left them out). Sets new
    ``obj`` and ``layout`` labels."""
    tol = lab.cfg.layout.plane_voxels * lab.voxel
    obj, labels = lab.obj.copy(), lab.layout.labels.copy()
    for plane in lab.layout.planes:
        flush = (
            (obj >= 0)
            & plane.near(lab.cells, tol)
            & (np.abs(lab.normals @ plane.normal) >= np.cos(np.radians(FLUSH_DEG)))
        )
        obj[flush] = -1
        labels[flush] = plane.label
    lab.obj, lab.layout = obj, replace(lab.layout, labels=labels)
