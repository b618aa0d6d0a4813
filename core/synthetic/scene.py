"""Procedural scenes: a room with furniture placed without interpenetration, and its ground truth."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import networkx as nx
import numpy as np
import trimesh
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stratamap.core.errors import ConfigError
from stratamap.core.groundtruth import GroundTruthObject
from stratamap.core.layers import ContactGraph
from stratamap.core.synthetic.models import FAMILIES, Model, ModelPart, make_model
from stratamap.core.transforms import apply, make_pose

WALL_THICKNESS = 0.1


class SceneSpec(BaseModel):
    """A procedural scene: room type and size, what to place, and the seed that fixes it all."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["room"] = Field(default="room", description="Scene type; 'room' is a room with a table and chairs.")
    room_size: tuple[float, float, float] = Field(
        default=(5.0, 4.0, 2.6), description="Interior length (x), width (y) and height (z) of the room, metres."
    )
    tables: int = Field(default=1, ge=0, le=4, description="Number of tables.")
    chairs: int = Field(default=4, ge=0, le=16, description="Number of chairs, pushed partly under the tables.")
    boxes: int = Field(default=2, ge=0, le=12, description="Number of boxes placed on the tables.")
    seed: int = Field(default=0, description="Seed of every random choice; same spec and seed, same scene.")

    @classmethod
    def from_yaml(cls, path: str | Path) -> SceneSpec:
        path = Path(path)
        if not path.is_file():
            raise ConfigError([("", f"scene spec not found: {path}")])
        doc = yaml.safe_load(path.read_text()) or {}
        try:
            return cls.model_validate(doc)
        except ValidationError as exc:
            raise ConfigError(
                [(".".join(map(str, e["loc"])), e["msg"]) for e in exc.errors()], source=str(path)
            ) from None


@dataclass
class PlacedObject:
    id: int
    model: Model
    pose: np.ndarray  # object-to-world
    parent: int | str

    @property
    def class_name(self) -> str:
        return self.model.class_name

    def world_parts(self) -> list[tuple[ModelPart, trimesh.Trimesh]]:
        out = []
        for part in self.model.parts:
            mesh = part.mesh.copy()
            mesh.apply_transform(self.pose)
            out.append((part, mesh))
        return out

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
        )


@dataclass
class LayoutElement:
    name: str  # floor, wall_0.., ceiling
    class_name: str
    mesh: trimesh.Trimesh
    albedo: tuple[float, float, float]


@dataclass
class Scene:
    spec: SceneSpec
    layout: list[LayoutElement]
    objects: list[PlacedObject] = field(default_factory=list)

    @property
    def room_size(self) -> np.ndarray:
        return np.array(self.spec.room_size, dtype=float)

    def ground_truth_objects(self) -> list[GroundTruthObject]:
        return [o.to_ground_truth() for o in self.objects]

    def contact_graph(self) -> ContactGraph:
        g = ContactGraph()
        for el in self.layout:
            g.support.add_node(el.name, kind="layout", class_name=el.class_name)
            g.support.add_edge("scene", el.name, relation="support")
        for obj in self.objects:
            g.support.add_node(obj.id, kind="object", class_name=obj.class_name, model_id=obj.model.id)
        for obj in self.objects:
            z = obj.pose[2, 3]
            g.support.add_edge(obj.parent, obj.id, relation="support", plane=[0.0, 0.0, 1.0, -float(z)])
        g.proximal.add_nodes_from(g.support.nodes)
        return g

    def layout_info(self) -> dict[str, Any]:
        lx, ly, lz = self.spec.room_size
        return {"room_size": [lx, ly, lz], "floor_z": 0.0, "bounds": [[0.0, 0.0, 0.0], [lx, ly, lz]]}


# ------------------------------------------------------------------------------------------


def _part_aabbs(parts: list[ModelPart], pose: np.ndarray) -> np.ndarray:
    """(P, 2, 3) world AABBs of parts (conservative for any yaw)."""
    out = []
    for part in parts:
        corners = trimesh.bounds.corners(part.mesh.bounds)
        w = apply(pose, corners)
        out.append([w.min(0), w.max(0)])
    return np.array(out)


def _overlaps(a: np.ndarray, b: np.ndarray, clearance: float = 0.01) -> bool:
    """Whether any AABB of set ``a`` comes within ``clearance`` of any AABB of set ``b``."""
    lo = np.maximum(a[:, None, 0], b[None, :, 0])
    hi = np.minimum(a[:, None, 1], b[None, :, 1])
    return bool(np.any(np.all(hi - lo > -clearance, axis=-1)))


def _layout(spec: SceneSpec) -> list[LayoutElement]:
    lx, ly, lz = spec.room_size
    t = WALL_THICKNESS
    floor_c, wall_c, ceil_c = (0.55, 0.5, 0.45), (0.85, 0.84, 0.8), (0.95, 0.95, 0.95)
    els = [
        LayoutElement("floor", "floor", trimesh.creation.box((lx + 2 * t, ly + 2 * t, t), make_pose((lx / 2, ly / 2, -t / 2))), floor_c),
        LayoutElement("ceiling", "ceiling", trimesh.creation.box((lx + 2 * t, ly + 2 * t, t), make_pose((lx / 2, ly / 2, lz + t / 2))), ceil_c),
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
    """Place tables, chairs around them (pushed partly under) and boxes on them."""
    rng = np.random.default_rng(spec.seed)
    scene = Scene(spec=spec, layout=_layout(spec))
    lx, ly, _ = spec.room_size
    occupied: list[np.ndarray] = []  # part AABBs of floor-standing objects
    next_id = 1
    chair_families = [f for f, (c, _) in FAMILIES.items() if c == "chair"]

    tables: list[PlacedObject] = []
    for k in range(spec.tables):
        model = make_model("rectangular_table", spec.seed, k)
        for _ in range(200):
            yaw = float(rng.choice([0.0, np.pi / 2]) + rng.uniform(-0.15, 0.15))
            margin = 1.0  # room for chairs around the table
            x = rng.uniform(margin + 0.3, lx - margin - 0.3) if spec.tables > 1 else lx / 2 + rng.uniform(-0.3, 0.3)
            y = rng.uniform(margin + 0.3, ly - margin - 0.3) if spec.tables > 1 else ly / 2 + rng.uniform(-0.2, 0.2)
            pose = make_pose((x, y, 0.0), yaw)
            boxes = _part_aabbs(model.parts, pose)
            grown = boxes.copy()
            grown[:, 0, :2] -= 0.7
            grown[:, 1, :2] += 0.7
            if not any(_overlaps(grown, o) for o in occupied):
                obj = PlacedObject(next_id, model, pose, "floor")
                next_id += 1
                scene.objects.append(obj)
                tables.append(obj)
                occupied.append(boxes)
                break

    # Chairs: slots along both long sides of each table, facing it, pushed partly under.
    slots: list[tuple[PlacedObject, float, int]] = []
    for t in tables:
        length = t.model.params["length"]
        n_side = 2 if length < 1.5 else 3
        xs = np.linspace(-length / 2, length / 2, n_side + 2)[1:-1]
        for side in (-1, 1):
            for xo in xs:
                slots.append((t, float(xo), side))
    order = rng.permutation(len(slots)) if slots else []
    placed_chairs = 0
    for idx in order:
        if placed_chairs >= spec.chairs:
            break
        table, xo, side = slots[int(idx)]
        family = chair_families[int(rng.integers(len(chair_families)))]
        model = make_model(family, spec.seed, 100 + placed_chairs)
        depth = model.size[1]
        push = float(rng.uniform(0.05, 0.22))
        local = np.array([xo + rng.uniform(-0.05, 0.05), side * (table.model.params["width"] / 2 + depth / 2 - push), 0.0])
        # The chair's front (-y in its frame) faces the table.
        yaw_local = 0.0 if side > 0 else np.pi
        pose = table.pose @ make_pose(local, yaw_local + rng.uniform(-0.2, 0.2))
        boxes = _part_aabbs(model.parts, pose)
        inside = boxes[:, 0, :2].min(0) > 0.05
        inside &= boxes[:, 1, :2].max(0) < np.array([lx, ly]) - 0.05
        if not inside.all() or any(_overlaps(boxes, o) for o in occupied):
            continue
        scene.objects.append(PlacedObject(next_id, model, pose, "floor"))
        next_id += 1
        occupied.append(boxes)
        placed_chairs += 1

    # Boxes on tabletops.
    on_top: dict[int, list[np.ndarray]] = {t.id: [] for t in tables}
    for k in range(spec.boxes if tables else 0):
        model = make_model("box", spec.seed, 200 + k)
        for _ in range(100):
            table = tables[int(rng.integers(len(tables)))]
            tp = table.model.params
            half = model.size[:2].max() / 2 + 0.03
            local = np.array(
                [rng.uniform(-tp["length"] / 2 + half, tp["length"] / 2 - half), rng.uniform(-tp["width"] / 2 + half, tp["width"] / 2 - half), tp["height"]]
            )
            pose = table.pose @ make_pose(local, rng.uniform(-np.pi, np.pi))
            boxes = _part_aabbs(model.parts, pose)
            if not any(_overlaps(boxes, o) for o in on_top[table.id]):
                scene.objects.append(PlacedObject(next_id, model, pose, table.id))
                next_id += 1
                on_top[table.id].append(boxes)
                break
    return scene


def support_tree_is_valid(graph: nx.DiGraph) -> bool:
    """Every non-root node has exactly one parent."""
    return all(graph.in_degree(n) == 1 for n in graph.nodes if n != "scene")
