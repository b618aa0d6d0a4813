"""Procedural scenes: a room, furniture (generated or from model libraries) placed by the rules of its type, and
the scene's ground truth."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import ContactGraph
from stratamap.core.synthetic.models import Model, ModelPart
from stratamap.core.synthetic.placement import place_objects
from stratamap.core.synthetic.spec import SceneSpec

trimesh = lazy_module("trimesh")

WALL_THICKNESS = 0.1


@dataclass
class PlacedObject:
    id: int
    model: Model
    pose: np.ndarray  # object-to-world
    parent: int | str
    #: The world meshes of the parts and the pose they were made for (see world_parts).
    _world: tuple[bytes, list[tuple[ModelPart, trimesh.Trimesh]]] | None = field(
        default=None, init=False, repr=False, compare=False
    )

    @property
    def class_name(self) -> str:
        return self.model.class_name

    def world_parts(self) -> list[tuple[ModelPart, trimesh.Trimesh]]:
        """Each part with its mesh in world coordinates. The meshes are made once per pose and shared
        by every caller (the renderer, the ground-truth occupancy, the trajectory planner, the
        coverage): read them, do not modify them. Copied and moved on every call, they cost the
        rendered walks of the test suite's eight heaviest files 16 s of CPU."""
        key = np.asarray(self.pose, float).tobytes()
        if self._world is None or self._world[0] != key:
            out = []
            for part in self.model.parts:
                mesh = part.mesh.copy()
                mesh.apply_transform(self.pose)
                out.append((part, mesh))
            self._world = (key, out)
        return list(self._world[1])

    def to_ground_truth(self) -> GroundTruthObject:
        return GroundTruthObject(
            id=self.id,
            class_name=self.class_name,
            mesh=self.model.mesh(),
            pose=self.pose.copy(),
            model_id=self.model.id,
            family=self.model.family,
            parent=self.parent,
            joints=list(self.model.joints),
            params=dict(self.model.params),
            part_boxes=part_boxes(self.model),
        )


def part_boxes(model: Model) -> dict[str, list[list[float]]]:
    """Each joint's child link as a box in the model frame at joint positions 0 (its own parts and
    those of the links below it, a drawer's handle on a fixed joint included): link name ->
    ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``; links without geometry below them are left out."""
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    meshes: dict[str, list] = {}
    for part in model.parts:
        meshes.setdefault(part.link, []).append(part.mesh)
    out: dict[str, list[list[float]]] = {}
    for link in dict.fromkeys(j.child for j in model.joints):
        below, stack = {link}, [link]
        while stack:
            for child in children.get(stack.pop(), []):
                if child not in below:
                    below.add(child)
                    stack.append(child)
        bounds = [m.bounds for name in below for m in meshes.get(name, []) if len(m.vertices)]
        if bounds:
            lo = np.min([b[0] for b in bounds], axis=0)
            hi = np.max([b[1] for b in bounds], axis=0)
            out[link] = [np.round(lo, 9).tolist(), np.round(hi, 9).tolist()]
    return out


@dataclass
class LayoutElement:
    name: str  # floor, ceiling, wall_0..3
    class_name: str
    mesh: trimesh.Trimesh
    albedo: tuple[float, float, float]


@dataclass
class Scene:
    spec: SceneSpec
    layout: list[LayoutElement]
    objects: list[PlacedObject] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)  # requested objects that did not fit

    @property
    def room_size(self) -> np.ndarray:
        return np.array(self.spec.resolved_room_size(), dtype=float)

    def ground_truth_objects(self) -> list[GroundTruthObject]:
        return [o.to_ground_truth() for o in self.objects]

    def contact_graph(self) -> ContactGraph:
        """Support as placed: every object has exactly one parent (the floor or its supporter)."""
        g = ContactGraph()
        for el in self.layout:
            g.support.add_node(el.name, kind="layout", class_name=el.class_name)
            g.support.add_edge("scene", el.name, relation="support")
        for obj in self.objects:
            g.support.add_node(obj.id, kind="object", class_name=obj.class_name, model_id=obj.model.id)
        for obj in self.objects:
            g.support.add_edge(obj.parent, obj.id, relation="support", plane=[0.0, 0.0, 1.0, -float(obj.pose[2, 3])])
        g.proximal.add_nodes_from(g.support.nodes)
        return g

    def layout_info(self) -> dict[str, Any]:
        lx, ly, lz = (float(v) for v in self.room_size)
        walls = [[[0, 0], [lx, 0]], [[lx, 0], [lx, ly]], [[lx, ly], [0, ly]], [[0, ly], [0, 0]]]
        return {"room_size": [lx, ly, lz], "floor_z": 0.0, "bounds": [[0.0, 0.0, 0.0], [lx, ly, lz]], "walls": walls}

    def all_meshes(self) -> list[tuple[str, int, trimesh.Trimesh, tuple[float, float, float]]]:
        """(class, instance id, world mesh, albedo) of every layout element and object part."""
        return [(c, i, mesh, albedo) for c, i, mesh, albedo, _ in self.colored_meshes()]

    def colored_meshes(self) -> list[tuple[str, int, trimesh.Trimesh, tuple[float, float, float], np.ndarray | None]]:
        """As :meth:`all_meshes`, with each part's per-face colours (None where it has one colour)."""
        out = [(el.class_name, 0, el.mesh, el.albedo, None) for el in self.layout]
        for obj in self.objects:
            for part, mesh in obj.world_parts():
                out.append((obj.class_name, obj.id, mesh, part.albedo, part.face_colors))
        return out


def room_layout(room: tuple[float, float, float]) -> list[LayoutElement]:
    lx, ly, lz = room
    t = WALL_THICKNESS
    floor_c, wall_c, ceil_c = (0.55, 0.5, 0.45), (0.85, 0.84, 0.8), (0.95, 0.95, 0.95)
    els = [
        LayoutElement(
            "floor",
            "floor",
            trimesh.creation.box((lx + 2 * t, ly + 2 * t, t), make_pose((lx / 2, ly / 2, -t / 2))),
            floor_c,
        ),
        LayoutElement(
            "ceiling",
            "ceiling",
            trimesh.creation.box((lx + 2 * t, ly + 2 * t, t), make_pose((lx / 2, ly / 2, lz + t / 2))),
            ceil_c,
        ),
    ]
    walls = [
        ((lx + 2 * t, t, lz), (lx / 2, -t / 2, lz / 2)),
        ((t, ly + 2 * t, lz), (lx + t / 2, ly / 2, lz / 2)),
        ((lx + 2 * t, t, lz), (lx / 2, ly + t / 2, lz / 2)),
        ((t, ly + 2 * t, lz), (-t / 2, ly / 2, lz / 2)),
    ]
    for i, (size, center) in enumerate(walls):
        els.append(LayoutElement(f"wall_{i}", "wall", trimesh.creation.box(size, make_pose(center)), wall_c))
    return els


def generate_scene(spec: SceneSpec) -> Scene:
    """Place the spec's objects in its room by the rules of its type (deterministic in the seed)."""
    room = spec.resolved_room_size()
    placer = place_objects(
        spec.type, room, spec.resolved_objects(), spec.seed, spec.resolved_sources(), spec.varied_fixtures
    )
    scene = Scene(spec=spec, layout=room_layout(room), skipped=placer.skipped)
    scene.objects = [PlacedObject(p.id, p.model, p.pose, p.parent) for p in placer.objects]
    return scene
