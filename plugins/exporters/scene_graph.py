"""Exporter ``scene_graph``: the contact graph as JSON, with each object's class, box, pose, model and score."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import write_json
from stratamap.core.lazy import lazy_module

nx = lazy_module("networkx")


class SceneGraphConfig(StageConfig):
    filename: str = Field(default="scene_graph.json", description="File name in the export folder.")


class SceneGraphExporter(Exporter[SceneGraphConfig]):
    """The support and proximal graph as node-link JSON with object attributes (class, box, pose, model, score)."""

    name = "scene_graph"
    Config = SceneGraphConfig
    requires = frozenset({"contact_graph"})
    optional = frozenset({"instances"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        graph = data.map.contact_graph
        assert graph is not None
        support = graph.support.copy()
        insts = data.map.instances
        for node in support.nodes:
            if insts is not None and isinstance(node, (int, np.integer)) and int(node) in insts:
                inst = insts[int(node)]
                attrs: dict[str, Any] = {
                    "class_name": inst.class_name,
                    "box": inst.box.to_dict(),
                    "observed_points": len(inst.points),
                }
                c = inst.completion
                if c is not None:
                    attrs.update(
                        {
                            "pose": c.pose.tolist(),
                            "model_id": c.model_id,
                            "completion_score": c.score,
                            "completer": c.completer,
                            "joints": [j.name for j in c.joints],
                        }
                    )
                support.nodes[node].update(attrs)
        doc = {
            "support": nx.node_link_data(support, edges="links"),
            "proximal": nx.node_link_data(graph.proximal, edges="links"),
        }
        path = out_dir / self.config.filename
        write_json(path, doc)
        return [path]


@hookimpl
def stratamap_register_exporters():
    return [SceneGraphExporter]
