"""Mapper ``contact_graph`` (minimal): who supports whom.

Every object is supported by the object right below it -- one whose top is within
``contact_tolerance`` of the object's bottom and whose footprint covers at least
``min_overlap`` of the object's footprint -- or else by the floor. Layout nodes (floor, walls,
ceiling) hang off the ``scene`` root. Proximal edges join objects whose boxes touch.
(The functional-scenes paper's full support inference grows here in the "Contact graph" issue.)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.geometry import footprint_overlap
from stratamap.core.layers import ContactGraph


class ContactGraphConfig(StageConfig):
    contact_tolerance: float = Field(default=0.06, gt=0.0, description="Max gap between a child's bottom and its supporter's top, metres.")
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
            best, best_score = None, 0.0
            area = max(float(child.box.size[0] * child.box.size[1]), 1e-9)
            for parent in insts:
                if parent.id == child.id or parent.box.top_z > child.box.bottom_z + cfg.contact_tolerance:
                    continue
                if child.box.bottom_z - parent.box.top_z > cfg.contact_tolerance:
                    continue
                ratio = footprint_overlap(child.box, parent.box) / area
                if ratio >= cfg.min_overlap and ratio > best_score:
                    best, best_score = parent, ratio
            if best is not None:
                g.add_edge(best.id, child.id, relation="support", plane=[0.0, 0.0, 1.0, -best.box.top_z])
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
