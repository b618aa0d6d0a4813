"""The floor's height, shared by the mappers that stand objects on it (``contact_graph``,
``physical_check``) and the one that projects obstacles above it (``occupancy``), whatever order
a pipeline runs them in."""

from __future__ import annotations

import numpy as np

from stratamap.core.stages import PipelineData

#: Fewer floor-labelled points than this say too little about the floor's height.
MIN_FLOOR_POINTS = 100


def floor_height(data: PipelineData) -> float:
    """The median height of the points labelled ``floor``; else what an earlier ``occupancy`` stage
    noted; else 0 (gravity-aligned maps have the floor at z = 0)."""
    sem, geom = data.map.semantics, data.map.geometry
    if sem is not None and geom is not None and "floor" in sem.vocabulary and len(sem) == len(geom):
        floor = sem.class_ids == sem.vocabulary.id("floor")
        if floor.sum() > MIN_FLOOR_POINTS:
            return float(np.median(geom.points[floor, 2]))
    return float(data.notes.get("occupancy", {}).get("floor_z", 0.0))
