"""Placement rules: where each class of object goes in a room, without interpenetration.

* ``wall`` -- back against a wall, front facing into the room (cabinets, shelves, desks, counters);
* ``center`` -- free-standing with room around it for chairs (tables);
* ``seat`` -- at a table or desk, facing it, pushed partly under (the occlusion of real offices),
  or around a coffee table; elsewhere along a wall;
* ``top`` -- resting on a support surface of another object (monitors on desks, cups on tables,
  books on shelves, a microwave on a counter);
* ``floor`` -- free-standing small objects, preferably near a wall (plants, boxes).

Collision checks use the world AABBs of every part (conservative at any yaw), so parts of one
object may interlock with another's (a seat under a tabletop) but never overlap it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.geometry.transforms import apply, make_pose
from stratamap.core.synthetic.models import FAMILIES, Model, make_model
from stratamap.core.synthetic.spec import LibrarySource

#: class -> placement rule
PLACEMENT = {
    "desk": "wall",
    "cabinet": "wall",
    "shelf": "wall",
    "counter": "wall",
    "fridge": "wall",
    "oven": "wall",
    "sofa": "wall",
    "bench": "wall",
    "table": "center",
    "chair": "seat",
    "monitor": "top",
    "laptop": "top",
    "microwave": "top",
    "cup": "top",
    "bottle": "top",
    "book": "top",
    "box": "top",
    "plant": "floor",
}

#: Wall furniture whose doors or drawers need the floor in front of them kept clear.
KEEP_CLEAR = {"cabinet", "counter", "fridge", "oven", "shelf"}

#: class -> supporting classes in order of preference (for ``top`` objects).
SUPPORTERS = {
    "monitor": ["desk", "table", "cabinet"],
    "laptop": ["desk", "table"],
    "microwave": ["counter", "cabinet", "table"],
    "cup": ["table", "desk", "counter"],
    "bottle": ["table", "counter", "desk"],
    "book": ["shelf", "table", "desk"],
    "box": ["shelf", "table", "desk", "cabinet"],
}

#: scene type -> class -> {family: weight}
FAMILY_WEIGHTS = {
    "room": {"chair": {"four_leg_chair": 0.7, "stool": 0.3}, "table": {"rectangular_table": 1.0}},
    "office": {
        "chair": {"office_chair": 0.8, "four_leg_chair": 0.2},
        "table": {"round_table": 0.5, "rectangular_table": 0.5},
    },
    "meeting_room": {"chair": {"four_leg_chair": 0.5, "office_chair": 0.5}, "table": {"rectangular_table": 1.0}},
    "kitchen": {
        "chair": {"four_leg_chair": 0.7, "stool": 0.3},
        "table": {"rectangular_table": 0.5, "round_table": 0.5},
    },
    "lounge": {"chair": {"armchair": 1.0}, "table": {"coffee_table": 1.0}},
    "corridor": {"chair": {"four_leg_chair": 0.5, "stool": 0.5}, "table": {"round_table": 1.0}},
}

# Placement order: big wall furniture first, then tables, seats, things on top, floor objects.
ORDER = ["counter", "fridge", "oven", "sofa", "desk", "cabinet", "shelf", "bench", "table", "chair",
         "monitor", "microwave", "laptop", "book", "box", "bottle", "cup", "plant"]  # fmt: skip


@dataclass
class Placed:
    id: int
    model: Model
    pose: np.ndarray
    parent: int | str
    aabbs: np.ndarray  # (P, 2, 3) world AABBs of parts


def part_aabbs(model: Model, pose: np.ndarray) -> np.ndarray:
    out = []
    for part in model.parts:
        lo, hi = part.mesh.bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        w = apply(pose, corners)
        out.append([w.min(0), w.max(0)])
    return np.array(out)


def overlaps(a: np.ndarray, b: np.ndarray, clearance: float = 0.01) -> bool:
    """Whether any AABB of ``a`` comes within ``clearance`` of any AABB of ``b``."""
    lo = np.maximum(a[:, None, 0], b[None, :, 0])
    hi = np.minimum(a[:, None, 1], b[None, :, 1])
    return bool(np.any(np.all(hi - lo > -clearance, axis=-1)))


class Placer:
    def __init__(
        self,
        scene_type: str,
        room: tuple[float, float, float],
        seed: int,
        sources: dict[str, list[LibrarySource]] | None = None,
        varied_fixtures: bool = False,
    ):
        self.type = scene_type
        self.varied_fixtures = varied_fixtures
        self.room = np.asarray(room, float)
        self.seed = seed
        self.rng = np.random.default_rng([seed, 7919])
        #: class -> the model libraries its objects come from (classes absent are generated).
        self.sources = sources or {}
        #: class -> (library, model) pairs its objects take in turn, from a random start.
        self._library_models: dict[str, list] = {}
        self._library_turn: dict[str, int] = {}
        self.objects: list[Placed] = []
        self._model_index = 0
        self.skipped: dict[str, int] = {}
        #: Floor areas in front of doors and drawers that must stay clear so they can open.
        self.keepout: list[np.ndarray] = []

    # ---- models ------------------------------------------------------------------------

    def model_for(self, class_name: str, family: str | None = None) -> Model:
        if class_name in self.sources and family is None:
            from stratamap.core.synthetic.library_objects import candidates, to_scene_model

            if class_name not in self._library_models:
                sources = self.sources[class_name]
                self._library_models[class_name] = [
                    (source, model)
                    for k, source in enumerate(sources)
                    for model in candidates(
                        source, class_name, f"objects.{class_name}.library" + (f"[{k}]" if len(sources) > 1 else "")
                    )
                ]
                self._library_turn[class_name] = int(self.rng.integers(len(self._library_models[class_name])))
            options = self._library_models[class_name]
            source, model = options[self._library_turn[class_name] % len(options)]
            self._library_turn[class_name] += 1
            self._model_index += 1
            return to_scene_model(model, class_name, source, self.rng)
        if family is None:
            weights = FAMILY_WEIGHTS.get(self.type, {}).get(class_name)
            if weights:
                names = sorted(weights)
                p = np.array([weights[n] for n in names], float)
                family = names[int(self.rng.choice(len(names), p=p / p.sum()))]
            else:
                options = sorted(f for f, (c, _) in FAMILIES.items() if c == class_name)
                family = options[int(self.rng.integers(len(options)))]
        self._model_index += 1
        return make_model(family, self.seed, self._model_index, self.varied_fixtures)

    # ---- checks ------------------------------------------------------------------------

    def inside_room(self, aabbs: np.ndarray, margin: float = 0.02) -> bool:
        return bool(
            (aabbs[:, 0, :2].min(0) >= margin).all() and (aabbs[:, 1, :2].max(0) <= self.room[:2] - margin).all()
        )

    def free(self, aabbs: np.ndarray, ignore: dict[int, float] | None = None, clearance: float = 0.01) -> bool:
        """No overlap with placed objects; ``ignore`` maps an object id to a support height whose
        resting parts (top at that height) do not count."""
        for obj in self.objects:
            other = obj.aabbs
            if ignore and obj.id in ignore:
                z = ignore[obj.id]
                other = other[np.abs(other[:, 1, 2] - z) > 2e-3]
                if len(other) == 0:
                    continue
            if overlaps(aabbs, other, clearance):
                return False
        return True

    def add(self, model: Model, pose: np.ndarray, parent: int | str) -> Placed:
        placed = Placed(len(self.objects) + 1, model, pose, parent, part_aabbs(model, pose))
        self.objects.append(placed)
        return placed

    # ---- rules -------------------------------------------------------------------------

    def walls(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
        """(origin, direction along the wall, inward normal, length) per wall."""
        lx, ly = self.room[:2]
        return [
            (np.array([0.0, 0.0]), np.array([1.0, 0.0]), np.array([0.0, 1.0]), lx),
            (np.array([lx, 0.0]), np.array([0.0, 1.0]), np.array([-1.0, 0.0]), ly),
            (np.array([lx, ly]), np.array([-1.0, 0.0]), np.array([0.0, -1.0]), lx),
            (np.array([0.0, ly]), np.array([0.0, -1.0]), np.array([1.0, 0.0]), ly),
        ]

    @staticmethod
    def facing(normal: np.ndarray) -> float:
        """Yaw that turns a model's front (-y) to ``normal``."""
        return float(np.arctan2(normal[0], -normal[1]))

    def place_wall(self, model: Model, tries: int = 300) -> Placed | None:
        walls = self.walls()
        lengths = np.array([w[3] for w in walls])
        size = model.size
        for _ in range(tries):
            k = int(self.rng.choice(4, p=lengths / lengths.sum()))
            origin, direction, normal, length = walls[k]
            half = size[0] / 2 + 0.05
            if length < 2 * half:
                continue
            s = self.rng.uniform(half, length - half)
            xy = origin + direction * s + normal * (size[1] / 2 + 0.01)
            pose = make_pose((xy[0], xy[1], 0.0), self.facing(normal))
            aabbs = part_aabbs(model, pose)
            lo, hi = aabbs[:, 0].min(0), aabbs[:, 1].max(0)
            zone = np.array(
                [
                    [
                        np.minimum(lo[:2], lo[:2] + normal * 0.6).tolist() + [0.0],
                        np.maximum(hi[:2], hi[:2] + normal * 0.6).tolist() + [2.0],
                    ]
                ]
            )
            needs_zone = model.class_name in KEEP_CLEAR
            if (
                self.inside_room(aabbs, 0.0)
                and self.free(aabbs)
                and self.clear_of_keepout(aabbs)
                and (not needs_zone or self.free(zone, clearance=0.0))
            ):
                if needs_zone:
                    self.keepout.append(zone)
                return self.add(model, pose, "floor")
        return None

    def clear_of_keepout(self, aabbs: np.ndarray) -> bool:
        return not any(overlaps(aabbs, zone, clearance=0.0) for zone in self.keepout)

    def place_center(self, model: Model, space: float = 0.85, tries: int = 300) -> Placed | None:
        lx, ly = self.room[:2]
        size = model.size
        for _ in range(tries):
            yaw = float(self.rng.choice([0.0, np.pi / 2]) + self.rng.uniform(-0.1, 0.1))
            if lx > ly and size[0] > size[1]:
                yaw = float(self.rng.uniform(-0.1, 0.1))
            r = np.hypot(*size[:2]) / 2 + space
            lo = np.array([min(r, lx / 2), min(r, ly / 2)])
            hi = np.array([max(lx - r, lx / 2), max(ly - r, ly / 2)])
            xy = self.rng.uniform(lo, hi)
            pose = make_pose((xy[0], xy[1], 0.0), yaw)
            aabbs = part_aabbs(model, pose)
            grown = aabbs.copy()
            grown[:, 0, :2] -= space
            grown[:, 1, :2] += space
            if self.inside_room(aabbs, 0.3) and self.free(grown, clearance=0.0) and self.clear_of_keepout(grown):
                return self.add(model, pose, "floor")
        return None

    def seat_slots(self) -> list[tuple[Placed, np.ndarray, float, float]]:
        """(host, local xy of the host's edge where a chair sits, the chair's yaw in the host frame
        (its front, -y, toward the host), push bias). A chair's front faces the host when
        R(yaw) (0, -1) points from the slot toward the host."""
        slots = []
        for host in self.objects:
            c, p = host.model.class_name, host.model.params
            if c == "desk" and "knee_center_x" in p:
                slots.append((host, np.array([p["knee_center_x"], -p["width"] / 2]), np.pi, 1.0))
            elif c == "desk":
                # A desk from a model library has no knee-space parameters, and its parts' boxes may fill
                # the space under its top: one seat at the middle of its front (-y), 10 cm out, not pushed in.
                slots.append((host, np.array([0.0, -host.model.size[1] / 2 - 0.1]), np.pi, 0.0))
            elif c == "table" and host.model.family == "round_table":
                n = 4 if p["radius"] > 0.45 else 3
                for k in range(n):
                    a = 2 * np.pi * k / n + np.pi / 4
                    slots.append((host, np.array([np.cos(a), np.sin(a)]) * p["radius"], float(a - np.pi / 2), 1.0))
            elif c == "table" and host.model.family == "rectangular_table":
                L, W = p["length"], p["width"]
                n_side = max(1, int((L - 0.2) // 0.65))
                xs = (np.arange(n_side) - (n_side - 1) / 2) * (L - 0.2) / n_side
                for x in xs:
                    slots.append((host, np.array([x, -W / 2]), np.pi, 1.0))
                    slots.append((host, np.array([x, W / 2]), 0.0, 1.0))
                slots.append((host, np.array([-L / 2, 0.0]), np.pi / 2, 0.6))
                slots.append((host, np.array([L / 2, 0.0]), -np.pi / 2, 0.6))
            elif c == "table" and host.model.family == "coffee_table":
                L, W = p["length"], p["width"]
                slots.append((host, np.array([-L / 2 - 0.25, 0.0]), np.pi / 2, 0.0))
                slots.append((host, np.array([L / 2 + 0.25, 0.0]), -np.pi / 2, 0.0))
                slots.append((host, np.array([0.0, -W / 2 - 0.3]), np.pi, 0.0))
            elif c == "table" and host.model.family not in FAMILIES:
                # A table from a model library: seats along the sides of its box, as at a rectangular table.
                L, W = host.model.size[:2]
                n_side = max(1, int((L - 0.2) // 0.65))
                for x in (np.arange(n_side) - (n_side - 1) / 2) * (L - 0.2) / n_side:
                    slots.append((host, np.array([x, -W / 2]), np.pi, 1.0))
                    slots.append((host, np.array([x, W / 2]), 0.0, 1.0))
                if W > 0.5:
                    slots.append((host, np.array([-L / 2, 0.0]), np.pi / 2, 0.6))
                    slots.append((host, np.array([L / 2, 0.0]), -np.pi / 2, 0.6))
        return slots

    def place_seat(self, model: Model, slots: list, tries: int = 2) -> Placed | None:
        depth = model.size[1]
        order = self.rng.permutation(len(slots))
        for idx in order:
            host, local, yaw_local, bias = slots[int(idx)]
            outward = np.array([-np.sin(yaw_local), np.cos(yaw_local)])  # the chair's back direction
            for _ in range(tries):
                # Pushed partly under: the chair's front edge goes past the host's edge by `push`.
                push = bias * self.rng.uniform(0.05, 0.25)
                yaw = yaw_local + self.rng.uniform(-0.25, 0.25)
                placed = self._seat(model, slots, int(idx), local + outward * (depth / 2 - push + 0.02), yaw)
                if placed is not None:
                    return placed
        # At a library table, pulled out instead, up to 30 cm: its model is one part, whose box fills
        # the space under its top (a seat pushed in overlaps it), and a turned table's box is wider than
        # the table. Tried only where no slot took the seat pushed in, so the rooms that did, and every
        # room of generated furniture, come out as before.
        for idx in order:
            host, local, yaw_local, bias = slots[int(idx)]
            if bias == 0 or host.model.family in FAMILIES:
                continue
            outward = np.array([-np.sin(yaw_local), np.cos(yaw_local)])
            for gap in np.arange(0.02, 0.31, 0.04):
                placed = self._seat(model, slots, int(idx), local + outward * (depth / 2 + gap), yaw_local)
                if placed is not None:
                    return placed
        return None

    def _seat(self, model: Model, slots: list, idx: int, center: np.ndarray, yaw: float) -> Placed | None:
        """The chair at ``center`` (the host's frame of slot ``idx``) turned by ``yaw``, if it fits
        there; the slot is then taken."""
        host = slots[idx][0]
        pose = host.pose @ make_pose((center[0], center[1], 0.0), yaw)
        aabbs = part_aabbs(model, pose)
        if self.inside_room(aabbs) and self.free(aabbs) and self.clear_of_keepout(aabbs):
            slots.pop(idx)
            return self.add(model, pose, "floor")
        return None

    def support_surfaces(self, supporter_class: str) -> list[tuple[Placed, tuple[float, ...]]]:
        return [
            (obj, sfc)
            for obj in self.objects
            if obj.model.class_name == supporter_class
            for sfc in obj.model.support_surfaces
        ]

    def place_top(self, model: Model, tries: int = 120) -> Placed | None:
        """On a support surface, trying the preferred supporting classes first."""
        for supporter in SUPPORTERS.get(model.class_name, []):
            surfaces = self.support_surfaces(supporter)
            if surfaces:
                placed = self._place_on(model, surfaces, tries)
                if placed is not None:
                    return placed
        return None

    def _place_on(self, model: Model, surfaces: list[tuple[Placed, tuple[float, ...]]], tries: int) -> Placed | None:
        size = model.size
        facing_front = model.class_name in ("monitor", "laptop", "microwave")
        for _ in range(tries):
            host, (x0, y0, x1, y1, z) = surfaces[int(self.rng.integers(len(surfaces)))]
            if z + size[2] > self.room[2] - 0.05:
                continue
            if facing_front:
                # Facing the host's front; monitors toward the back of a desk.
                yaw = float(self.rng.uniform(-0.2, 0.2))
                hx, hy = size[0] / 2 + 0.02, size[1] / 2 + 0.02
                y_lo = y0 + hy if model.class_name != "monitor" else max(y0 + hy, y1 - hy - 0.15)
                if x1 - hx <= x0 + hx or y1 - hy < y_lo:
                    continue
                local = np.array([self.rng.uniform(x0 + hx, x1 - hx), self.rng.uniform(y_lo, y1 - hy)])
            else:
                r = np.hypot(size[0], size[1]) / 2 + 0.01
                if x1 - x0 < 2 * r or y1 - y0 < 2 * r:
                    continue
                yaw = float(self.rng.uniform(-np.pi, np.pi))
                local = self.rng.uniform([x0 + r, y0 + r], [x1 - r, y1 - r])
            pose = host.pose @ make_pose((local[0], local[1], z), yaw)
            aabbs = part_aabbs(model, pose)
            if self.free(aabbs, ignore={host.id: pose[2, 3]}, clearance=0.005):
                return self.add(model, pose, host.id)
        return None

    def place_floor(self, model: Model, tries: int = 300) -> Placed | None:
        lx, ly = self.room[:2]
        r = np.hypot(*model.size[:2]) / 2 + 0.05
        for _ in range(tries):
            # Near a wall or a corner: plants and boxes stand out of the way.
            xy = self.rng.uniform([r, r], [lx - r, ly - r])
            axis = int(self.rng.integers(2))
            xy[axis] = r if self.rng.random() < 0.5 else self.room[axis] - r
            pose = make_pose((xy[0], xy[1], 0.0), float(self.rng.uniform(-np.pi, np.pi)))
            aabbs = part_aabbs(model, pose)
            if self.inside_room(aabbs) and self.free(aabbs, clearance=0.05) and self.clear_of_keepout(aabbs):
                return self.add(model, pose, "floor")
        return None

    def place(self, class_name: str, count: int) -> None:
        rule = PLACEMENT[class_name]
        slots = self.seat_slots() if rule == "seat" else []
        for _ in range(count):
            model = self.model_for(class_name)
            placed = None
            if rule == "wall":
                placed = self.place_wall(model)
            elif rule == "center":
                if self.type == "lounge" and any(o.model.class_name == "sofa" for o in self.objects):
                    placed = self.place_in_front_of_sofa(model)
                placed = placed or self.place_center(model) or self.place_center(model, space=0.6)
            elif rule == "seat":
                placed = self.place_seat(model, slots) if slots else None
                placed = placed or self.place_wall(model)
            elif rule == "top":
                placed = self.place_top(model)
                if placed is None and class_name == "box":
                    placed = self.place_floor(model)
            elif rule == "floor":
                placed = self.place_floor(model)
            if placed is None:
                self.skipped[class_name] = self.skipped.get(class_name, 0) + 1

    def place_in_front_of_sofa(self, model: Model) -> Placed | None:
        sofa = next(o for o in self.objects if o.model.class_name == "sofa")
        depth = sofa.model.size[1]
        for _ in range(50):
            gap = self.rng.uniform(0.35, 0.55)
            local = np.array([self.rng.uniform(-0.2, 0.2), -depth / 2 - gap - model.size[1] / 2])
            pose = sofa.pose @ make_pose((local[0], local[1], 0.0), float(self.rng.uniform(-0.1, 0.1)))
            aabbs = part_aabbs(model, pose)
            if self.inside_room(aabbs, 0.2) and self.free(aabbs, clearance=0.2) and self.clear_of_keepout(aabbs):
                return self.add(model, pose, "floor")
        return None


def place_objects(
    scene_type: str,
    room: tuple[float, float, float],
    objects: dict[str, int],
    seed: int,
    sources: dict[str, list[LibrarySource]] | None = None,
    varied_fixtures: bool = False,
) -> Placer:
    """Place ``objects`` (counts by class) by the rules; classes in ``sources`` come from those libraries."""
    placer = Placer(scene_type, room, seed, sources, varied_fixtures)
    for cls in ORDER:
        if objects.get(cls, 0) > 0:
            placer.place(cls, objects[cls])
    for cls in sorted(set(objects) - set(ORDER)):
        placer.place(cls, objects[cls])
    return placer
