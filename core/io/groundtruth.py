"""Read the ``gt/`` folder that ``stratamap synth`` writes beside a sequence into a :class:`GroundTruth`."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import networkx as nx
import numpy as np
import trimesh

from stratamap.core.errors import DataError
from stratamap.core.io.rgbd import read_image
from stratamap.core.map.groundtruth import GroundTruth, GroundTruthObject
from stratamap.core.map.layers import ContactGraph, Joint, OccupancyMaps
from stratamap.core.map.sensors import FrameSegmentation
from stratamap.core.map.vocabulary import Vocabulary


class FileLabels(Sequence):
    """Per-frame class and instance images read on access from ``gt/class`` and ``gt/instance``."""

    def __init__(self, gt_dir: Path, stamps: list[str]):
        self.gt_dir, self.stamps = gt_dir, stamps

    def __len__(self) -> int:
        return len(self.stamps)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        stamp = self.stamps[k]
        cls = read_image(self.gt_dir / "class" / f"{stamp}.png")
        inst = read_image(self.gt_dir / "instance" / f"{stamp}.png")
        if cls.shape != inst.shape:
            raise DataError(f"{self.gt_dir}: class and instance images of {stamp} differ in size")
        return FrameSegmentation(k, cls.astype(np.uint16), inst.astype(np.int32))

    def __deepcopy__(self, memo: dict) -> list:
        return [self[i] for i in range(len(self))]


def load_ground_truth(gt_dir: Path, stamps: list[str]) -> GroundTruth:
    scene_file = gt_dir / "scene.json"
    if not scene_file.is_file():
        raise DataError(f"{gt_dir}: no scene.json; not a stratamap ground-truth folder")
    try:
        scene = json.loads(scene_file.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{scene_file}: corrupt JSON ({exc})") from exc
    vocab = Vocabulary.from_dict(scene["vocabulary"]) if "vocabulary" in scene else Vocabulary.default()
    objects = []
    for rec in scene.get("objects", []):
        mesh_path = gt_dir / rec["mesh"]
        if not mesh_path.is_file():
            raise DataError(f"{mesh_path}: mesh of ground-truth object {rec['id']} is missing")
        mesh = trimesh.load(mesh_path, force="mesh", process=False)
        objects.append(
            GroundTruthObject(
                id=int(rec["id"]),
                class_name=rec["class"],
                mesh=mesh,
                pose=np.array(rec["pose"], float),
                model_id=rec.get("model_id", ""),
                family=rec.get("family", ""),
                parent=rec.get("parent", "floor"),
                joints=[Joint.from_dict(j) for j in rec.get("joints", [])],
                params=rec.get("params", {}),
            )
        )
    graph = None
    graph_file = gt_dir / "contact_graph.json"
    if graph_file.is_file():
        graph = ContactGraph(
            support=nx.node_link_graph(json.loads(graph_file.read_text()), directed=True, edges="links")
        )
        graph.proximal.add_nodes_from(graph.support.nodes)
    occupancy = OccupancyMaps()
    from stratamap.core.io.nav2 import read_map

    for name in ("objects", "laser"):
        yml = gt_dir / f"occupancy_{name}.yaml"
        if yml.is_file():
            occupancy[name] = read_map(yml)
    labels = FileLabels(gt_dir, stamps) if (gt_dir / "class").is_dir() else []
    return GroundTruth(
        vocabulary=vocab,
        objects=objects,
        frame_labels=labels,  # type: ignore[arg-type]
        contact_graph=graph,
        layout=dict(scene.get("layout", {})),
        occupancy=occupancy,
    )
