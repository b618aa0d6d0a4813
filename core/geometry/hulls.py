"""Convex hulls of point sets as meshes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from stratamap.core.lazy import lazy_module

if TYPE_CHECKING:
    import trimesh
else:
    trimesh = lazy_module("trimesh")


def convex_hull(points: np.ndarray) -> trimesh.Trimesh:
    """trimesh's convex hull of ``points``. A flat set's hull has no volume, and trimesh divides by it
    while orienting the faces: that numpy warning is silenced here (callers test the volume)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        hull = trimesh.convex.convex_hull(points)
        _ = hull.volume  # computed (and cached) under the same silence
    return hull
