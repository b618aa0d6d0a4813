"""Exporter ``scene_graph``: the contact graph as JSON, with each object's class, box, pose, model and score;
optionally also as a 3D scene graph in Hydra's format (``spark_dsg``).

The Hydra graph (``formats: [json, hydra]``) holds one node per object on the objects layer
(``NodeSymbol('O', id)``): ``semantic_label`` the class id (the layer's labelspace names it),
``name`` the class name, ``position`` and an oriented ``bounding_box`` from the object's box,
``world_R_object`` its yaw (or its completed model's rotation), and ``metadata`` with the
instance id, the completion's model and what supports the object. Edges are the contact graph's
relations between objects (``metadata.relation``: ``support`` from supporter to supported, with the
plane, or ``proximal``). It is written with spark_dsg's own ``save``; ``spark_dsg.DynamicSceneGraph.load``
reads it back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path, write_json
from stratamap.core.errors import PluginError
from stratamap.core.geometry.transforms import matrix_to_quat_xyzw
from stratamap.core.lazy import lazy_module

nx = lazy_module("networkx")

HYDRA_INSTALL_HINT = "pip install 'stratamap[hydra]'"


class SceneGraphConfig(StageConfig):
    filename: str = Field(default="scene_graph.json", description="File name of the JSON graph in the export folder.")
    formats: list[Literal["json", "hydra"]] = Field(
        default_factory=lambda: ["json"],
        min_length=1,
        description="What to write: json (node-link JSON) and/or hydra (a spark_dsg 3D scene graph, Hydra's format).",
    )
    hydra_filename: str = Field(  # Hydra names its own output dsg.json
        default="dsg.json",
        description="File name of the Hydra graph: JSON for a .json name, spark_dsg's binary format otherwise.",
    )


class SceneGraphExporter(Exporter[SceneGraphConfig]):
    """The support and proximal graph as node-link JSON with object attributes (class, box, pose, model, score)."""

    name = "scene_graph"
    Config = SceneGraphConfig
    requires = frozenset({"contact_graph"})
    optional = frozenset({"instances"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        written = []
        if "json" in self.config.formats:
            written.append(self._write_json(data, out_dir))
        if "hydra" in self.config.formats:
            written += self._write_hydra(data, out_dir)
        return written

    def _write_json(self, data: PipelineData, out_dir: Path) -> Path:
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
        return path

    def _write_hydra(self, data: PipelineData, out_dir: Path) -> list[Path]:
        instances = data.map.instances
        if instances is None:
            self.warn(f"no instances layer: the Hydra graph {self.config.hydra_filename} is not written")
            return []
        try:
            import spark_dsg
        except ImportError:
            raise PluginError(f"scene_graph's hydra format needs spark-dsg: {HYDRA_INSTALL_HINT}") from None
        graph = hydra_scene_graph(spark_dsg, data)
        path = out_dir / self.config.hydra_filename
        with atomic_path(path) as tmp:
            # spark_dsg picks the encoding from the name's suffix: save under the final name's suffix
            named = tmp.with_name(tmp.name + (".json" if path.suffix == ".json" else ".sparkdsg"))
            graph.save(named, include_mesh=False)
            named.replace(tmp)
        return [path]


def _object_node(spark_dsg: Any, instance_id: Any) -> Any:
    return spark_dsg.NodeSymbol("O", int(instance_id))


def hydra_scene_graph(spark_dsg: Any, data: PipelineData) -> Any:
    """A spark_dsg ``DynamicSceneGraph`` of the map's objects and the contact graph's relations between them."""
    instances = data.map.instances
    assert instances is not None
    vocabulary = data.map.semantics.vocabulary if data.map.semantics is not None else data.map.vocabulary
    graph = spark_dsg.DynamicSceneGraph()
    layer = graph.get_layer_key(spark_dsg.DsgLayers.OBJECTS)
    contact = data.map.contact_graph
    labels: dict[int, str] = {}
    for inst in sorted(instances, key=lambda i: i.id):
        class_id = vocabulary.id(inst.class_name) if inst.class_name in vocabulary else 0
        labels[class_id] = inst.class_name
        box = inst.box
        rotation = inst.completion.pose[:3, :3] if inst.completion is not None else box.pose[:3, :3]
        attrs = spark_dsg.ObjectNodeAttributes()
        attrs.semantic_label = class_id
        attrs.name = inst.class_name
        attrs.position = np.asarray(box.center, dtype=np.float64)
        x, y, z, w = matrix_to_quat_xyzw(rotation)
        attrs.world_R_object = spark_dsg.Quaternion(float(w), float(x), float(y), float(z))
        attrs.bounding_box = spark_dsg.BoundingBox(
            spark_dsg.BoundingBoxType.OBB,
            box.size.astype(np.float32),
            box.center.astype(np.float32),
            box.pose[:3, :3].astype(np.float32),
        )
        supporter = contact.parent(inst.id) if contact is not None and inst.id in contact.support else None
        attrs.metadata.add(
            {
                "instance_id": inst.id,
                "class_name": inst.class_name,
                "score": float(inst.score),
                "model_id": inst.completion.model_id if inst.completion is not None else None,
                "supported_by": None if supporter is None else str(supporter),
            }
        )
        graph.add_node(layer.layer, _object_node(spark_dsg, inst.id), attrs)
    graph.set_labelspace(spark_dsg.Labelspace(labels), layer.layer, layer.partition)
    if contact is not None:
        _add_relations(spark_dsg, graph, contact, instances)
    return graph


def _add_relations(spark_dsg: Any, graph: Any, contact: Any, instances: Any) -> None:
    """Support edges (supporter to supported, with the plane) and proximal edges between objects."""

    def between_objects(a: Any, b: Any) -> bool:
        return all(isinstance(n, (int, np.integer)) and int(n) in instances for n in (a, b))

    for parent, child, attrs in sorted(contact.support.edges(data=True), key=lambda e: (str(e[0]), str(e[1]))):
        if between_objects(parent, child):
            edge = spark_dsg.EdgeAttributes()
            plane = attrs.get("plane")
            edge.metadata.add({"relation": "support", "plane": None if plane is None else [float(v) for v in plane]})
            graph.insert_edge(_object_node(spark_dsg, parent), _object_node(spark_dsg, child), edge)
    for a, b in sorted(contact.proximal.edges(), key=lambda e: (str(e[0]), str(e[1]))):
        source, target = _object_node(spark_dsg, a), _object_node(spark_dsg, b)
        if between_objects(a, b) and not graph.has_edge(source, target):
            edge = spark_dsg.EdgeAttributes()
            edge.metadata.add({"relation": "proximal"})
            graph.insert_edge(source, target, edge)


@hookimpl
def stratamap_register_exporters():
    return [SceneGraphExporter]
