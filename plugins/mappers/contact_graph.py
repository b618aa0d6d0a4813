"""Mapper ``contact_graph``: who supports whom (functional-scenes paper, section 2, in part).

A parent can support a child when it has a horizontal surface at the child's bottom height
(eq. 1: parent points within ``contact_tolerance`` of that height) and that surface covers at
least ``min_overlap`` (b_th) of the child's footprint (eq. 2). The surface's extent is the convex
hull of those points, so a tabletop hidden under the child still counts (the paper's hidden
supporting plane). Among valid parents the largest contact ratio wins (eq. 3); objects without
one stand on the floor. Layout nodes (floor, walls, ceiling) hang off the ``scene`` root;
proximal edges join objects whose boxes touch. (Plane extraction by RANSAC, wall support and box
refinement of the paper are still to come.)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.geometry import footprint_overlap
from stratamap.core.layers import ContactGraph


def support_ratio(child_box, surface_xy: np.ndarray) -> float:
    """Area (m^2) of the child's footprint covered by the convex hull of a parent's surface points."""
    from scipy.spatial import ConvexHull, QhullError

    from stratamap.core.geometry import clip_polygon, polygon_area

    try:
        hull = surface_xy[ConvexHull(surface_xy).vertices]
    except (QhullError, ValueError):
        return 0.0
    return polygon_area(clip_polygon(child_box.corners_2d(), hull))


class ContactGraphConfig(StageConfig):
    contact_tolerance: float = Field(default=0.04, gt=0.0, description="Max height difference between a child's bottom and its supporter's surface, metres (a_th).")
    min_overlap: float = Field(default=0.5, gt=0.0, le=1.0, description="Min share of the child's footprint the supporter must cover (paper's b_th).")
    proximal_distance: float = Field(default=0.05, ge=0.0, description="Boxes closer than this (grown by it) are proximal, metres.")


class ContactGraphMapper(Mapper):
    """Support relations (floor or the object below) and proximal relations between object boxes."""

    name = "contact_graph"
    Config = ContactGraphConfig
    requires = frozenset({"instances"})
    optional = frozenset({"semantics"})
    provides = frozenset({"contact_graph"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg: ContactGraphConfig = self.config  # type: ignore[assignment]
        insts = list(data.map.instances or [])
        graph = ContactGraph()
        g = graph.support
        floor_z = data.notes.get("occupancy", {}).get("floor_z", 0.0)
        g.add_node("floor", kind="layout", class_name="floor")
        g.add_edge("scene", "floor", relation="support")
        sem = data.map.semantics
        if sem is not None:
            present = set(np.unique(sem.class_ids).tolist())
            for layout in ("wall", "ceiling"):
                if layout in sem.vocabulary and sem.vocabulary.id(layout) in present:
                    g.add_node(layout, kind="layout", class_name=layout)
                    g.add_edge("scene", layout, relation="support")
        for inst in insts:
            g.add_node(inst.id, kind="object", class_name=inst.class_name, box=inst.box.to_dict())

        for child in insts:
            best, best_score, best_z = None, 0.0, 0.0
            area = max(float(child.box.size[0] * child.box.size[1]), 1e-9)
            bottom = float(np.percentile(child.points[:, 2], 1)) if len(child.points) else child.box.bottom_z
            if bottom - floor_z > cfg.contact_tolerance:
                for parent in insts:
                    if parent.id == child.id or parent.box.bottom_z >= bottom:
                        continue
                    z = parent.points[:, 2]
                    surface = parent.points[np.abs(z - bottom) <= cfg.contact_tolerance]
                    if len(surface) < 10:
                        continue
                    ratio = support_ratio(child.box, surface[:, :2]) / area
                    if ratio >= cfg.min_overlap and ratio > best_score:
                        best, best_score, best_z = parent, ratio, float(np.median(surface[:, 2]))
            if best is not None:
                g.add_edge(best.id, child.id, relation="support", plane=[0.0, 0.0, 1.0, -best_z], contact_ratio=best_score)
            else:
                g.add_edge("floor", child.id, relation="support", plane=[0.0, 0.0, 1.0, -float(floor_z)])

        graph.proximal.add_nodes_from(g.nodes)
        for i, a in enumerate(insts):
            for b in insts[i + 1 :]:
                za = min(a.box.top_z, b.box.top_z) - max(a.box.bottom_z, b.box.bottom_z)
                if za < -cfg.proximal_distance:
                    continue
                grown = type(a.box)(a.box.center, a.box.yaw, a.box.size + 2 * cfg.proximal_distance)
                if footprint_overlap(grown, b.box) > 0 and not (g.has_edge(a.id, b.id) or g.has_edge(b.id, a.id)):
                    graph.proximal.add_edge(a.id, b.id, relation="proximal")
        return {"contact_graph": graph}


@hookimpl
def stratamap_register_mappers():
    return [ContactGraphMapper]
