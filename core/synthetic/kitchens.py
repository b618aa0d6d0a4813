"""Procedural kitchens as URDF: rows of base, wall and tall units with drawers, doors, flaps and
appliances (oven, dishwasher, fridge), handles and knobs, counter tops, an optional island and a
table. They train and test :mod:`stratamap.plugins.segmenters.plane_crf` through the very path
the real IAI kitchen takes (``read_urdf`` -> ``kitchen_from_urdf`` -> ``virtual_scan``).

Conventions follow real kitchens: fronts 19 mm thick with 3 mm gaps; a door's handle sits near
the edge opposite its hinge; flaps (wider than tall) hinge at the top with the handle at the
bottom; oven and dishwasher doors hinge at the bottom with a centred handle at the top and knobs
on a control strip; some wall doors have no handle (push to open).

    python -c "from stratamap.core.synthetic.kitchens import write_kitchen; write_kitchen(0, 'k0.urdf')"
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

FRONT_T = 0.019  # front thickness
GAP = 0.003  # between neighbouring fronts


@dataclass
class _Urdf:
    name: str
    links: list[str] = field(default_factory=list)
    joints: list[str] = field(default_factory=list)

    def link(self, name: str, visuals: list[tuple[np.ndarray, np.ndarray, str]] = ()) -> None:
        """visuals: (xyz, rpy, geometry xml) in the link frame."""
        body = "".join(
            f'<visual><origin xyz="{_f(x)}" rpy="{_f(r)}"/><geometry>{g}</geometry></visual>' for x, r, g in visuals
        )
        self.links.append(f'<link name="{name}">{body}</link>')

    def joint(
        self, name: str, kind: str, parent: str, child: str, xyz, rpy=(0, 0, 0), axis=(1, 0, 0), limit=(0.0, 0.0)
    ) -> None:
        extra = (
            f'<axis xyz="{_f(axis)}"/><limit lower="{limit[0]:.4f}" upper="{limit[1]:.4f}" effort="10" velocity="1"/>'
            if kind != "fixed"
            else ""
        )
        self.joints.append(
            f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/><origin '
            f'xyz="{_f(xyz)}" '
            f'rpy="{_f(rpy)}"/>{extra}</joint>'
        )

    def text(self) -> str:
        return (
            f'<?xml version="1.0"?>\n<robot name="{self.name}">\n'
            + "\n".join(self.links + self.joints)
            + "\n</robot>\n"
        )


def _f(v) -> str:
    return " ".join(f"{float(x):.5f}" for x in np.asarray(v, float).reshape(-1))


def _box(size) -> str:
    return f'<box size="{_f(size)}"/>'


def _cyl(radius: float, length: float) -> str:
    return f'<cylinder radius="{radius:.4f}" length="{length:.4f}"/>'


class _Kitchen:
    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.u = _Urdf(f"kitchen_{seed}")
        self.u.link("world")
        self.count = 0

    def _id(self, stem: str) -> str:
        self.count += 1
        return f"{stem}{self.count}"

    # -- fixtures ----------------------------------------------------------------------------
    def handle(self, parent: str, center, vertical: bool, length: float | None = None) -> None:
        """A bar handle standing off the front (front's outward side is local -y)."""
        r = self.rng
        length = length or float(r.uniform(0.10, 0.22))
        name = self._id("handle_")
        stand = 0.025
        bar = [length, 0.012, 0.012] if not vertical else [0.012, 0.012, length]
        off = np.array([0.0, -(stand + 0.006), 0.0])
        legs = []
        for s in (-0.4, 0.4):
            p = np.array([s * length, -stand / 2, 0.0]) if not vertical else np.array([0.0, -stand / 2, s * length])
            legs.append((p, np.zeros(3), _box([0.01, stand, 0.01])))
        self.u.link(name, [(off, np.zeros(3), _box(bar)), *legs])
        self.u.joint(f"{name}_joint", "fixed", parent, name, center)

    def knobs(self, parent: str, centers: list[np.ndarray]) -> None:
        for c in centers:
            name = self._id("knob_")
            rad, length = float(self.rng.uniform(0.015, 0.022)), float(self.rng.uniform(0.02, 0.03))
            self.u.link(name, [(np.array([0.0, -length / 2, 0.0]), np.array([np.pi / 2, 0, 0]), _cyl(rad, length))])
            self.u.joint(f"{name}_joint", "fixed", parent, name, c)

    # -- fronts (local frame of the carcass: x along the row, -y outward, z up; front face at y = -FRONT_T)
    def drawer(
        self, carcass: str, x0: float, x1: float, z0: float, z1: float, depth: float, handle: str = "top"
    ) -> None:
        name = self._id("drawer_")
        w, h = x1 - x0 - GAP, z1 - z0 - GAP
        box_d = depth - 0.06
        self.u.link(
            name,
            [
                (np.array([0.0, -FRONT_T / 2, 0.0]), np.zeros(3), _box([w, FRONT_T, h])),
                # the drawer's box behind its front; a front under 4.5 cm tall gets a 5 mm one (never negative)
                (np.array([0.0, box_d / 2, 0.0]), np.zeros(3), _box([w - 0.04, box_d, max(h - 0.04, 0.005)])),
            ],
        )
        c = np.array([(x0 + x1) / 2, 0.0, (z0 + z1) / 2])
        self.u.joint(f"{name}_joint", "prismatic", carcass, name, c, axis=(0, -1, 0), limit=(0.0, 0.4 * depth))
        if handle != "none":
            hz = h * (0.3 if handle == "top" and h > 0.18 else 0.0)
            self.handle(
                name, [0.0, -FRONT_T, hz], vertical=False, length=min(0.6 * w, float(self.rng.uniform(0.12, 0.3)))
            )

    def door(
        self,
        carcass: str,
        x0: float,
        x1: float,
        z0: float,
        z1: float,
        hinge: str,
        handle: str = "auto",
        name_stem: str = "door_",
        knob_count: int = 0,
    ) -> None:
        """hinge: left | right | top | bottom (as seen facing the front)."""
        r = self.rng
        name = self._id(name_stem)
        w, h = x1 - x0 - GAP, z1 - z0 - GAP
        cx, cz = (x0 + x1) / 2, (z0 + z1) / 2
        # joint at the hinge edge; the door's center relative to it
        if hinge == "left":
            j, c, axis = np.array([x0 + GAP / 2, -FRONT_T, cz]), np.array([w / 2, FRONT_T / 2, 0.0]), (0, 0, 1)
        elif hinge == "right":
            j, c, axis = np.array([x1 - GAP / 2, -FRONT_T, cz]), np.array([-w / 2, FRONT_T / 2, 0.0]), (0, 0, -1)
        elif hinge == "top":
            j, c, axis = np.array([cx, -FRONT_T, z1 - GAP / 2]), np.array([0.0, FRONT_T / 2, -h / 2]), (-1, 0, 0)
        else:
            j, c, axis = np.array([cx, -FRONT_T, z0 + GAP / 2]), np.array([0.0, FRONT_T / 2, h / 2]), (1, 0, 0)
        self.u.link(name, [(c, np.zeros(3), _box([w, FRONT_T, h]))])
        self.u.joint(f"{name}_joint", "revolute", carcass, name, j, axis=axis, limit=(0.0, 1.6))
        front = c - [0.0, FRONT_T, 0.0]  # handle positions are relative to the face centre
        if handle == "none":
            return
        if hinge in ("left", "right"):
            side = 1.0 if hinge == "left" else -1.0
            hx = side * (w / 2 - float(r.uniform(0.04, 0.07)))
            vertical = bool(r.random() < 0.6)
            hz = (
                float(r.uniform(0.25, 0.4)) * h * (1 if z1 < 1.2 else -1)
            )  # near the top of base units, bottom of wall units
            length = float(r.uniform(0.1, 0.2)) if vertical else float(r.uniform(0.1, 0.18))
            self.handle(name, front + [hx - (0 if vertical else side * length / 2), 0.0, hz], vertical, length)
        else:
            sign = -1.0 if hinge == "top" else 1.0
            hz = sign * (h / 2 - float(r.uniform(0.04, 0.07)) - (0.09 if knob_count else 0.0))
            self.handle(name, front + [0.0, 0.0, hz], vertical=False, length=min(0.7 * w, float(r.uniform(0.25, 0.45))))
            if knob_count:
                xs = np.linspace(-0.35 * w, 0.35 * w, knob_count)
                self.knobs(name, [front + [x, 0.0, h / 2 - 0.045] for x in xs])

    # -- units ---------------------------------------------------------------------------
    def carcass(self, frame: np.ndarray, x0: float, x1: float, z0: float, z1: float, depth: float, kind: str) -> str:
        name = self._id(f"{kind}_")  # never an appliance's name: the carcass is not the front
        w = x1 - x0
        vis = [(np.array([(x0 + x1) / 2, depth / 2, (z0 + z1) / 2]), np.zeros(3), _box([w, depth, z1 - z0]))]
        if z0 < 0.2 and z0 > 0.0:  # recessed plinth below base units
            vis.append((np.array([(x0 + x1) / 2, depth / 2 + 0.03, z0 / 2]), np.zeros(3), _box([w, depth - 0.06, z0])))
        self.u.link(name, vis)
        self.u.joint(
            f"{name}_joint", "fixed", "world", name, frame[:3, 3], rpy=(0, 0, np.arctan2(frame[1, 0], frame[0, 0]))
        )
        return name

    def base_unit(self, frame, x0, x1, height, depth, kind) -> None:
        r = self.rng
        plinth = 0.1
        c = self.carcass(frame, x0, x1, plinth, height, depth, "base")
        if kind == "drawers":
            n = int(r.integers(2, 5))
            cuts = np.sort(r.uniform(0.2, 0.8, n - 1)) if r.random() < 0.4 else np.linspace(0, 1, n + 1)[1:-1]
            zs = plinth + (height - plinth) * np.r_[0.0, cuts, 1.0]
            for k in range(n):
                self.drawer(c, x0, x1, zs[k], zs[k + 1], depth)
        elif kind == "door":
            self.door(c, x0, x1, plinth, height, "left" if r.random() < 0.5 else "right")
        elif kind == "double":
            mid = (x0 + x1) / 2
            self.door(c, x0, mid, plinth, height, "left")
            self.door(c, mid, x1, plinth, height, "right")
        elif kind == "drawer_door":
            top = height - float(r.uniform(0.14, 0.2))
            self.drawer(c, x0, x1, top, height, depth)
            self.door(c, x0, x1, plinth, top, "left" if r.random() < 0.5 else "right")
        elif kind == "oven":
            self.door(
                c, x0, x1, plinth + 0.1, height, "bottom", name_stem="oven_door_", knob_count=int(r.integers(2, 6))
            )
            self.drawer(c, x0, x1, plinth, plinth + 0.1, depth, handle="none")
        elif kind == "dishwasher":
            self.door(
                c, x0, x1, plinth, height, "bottom", name_stem="dishwasher_door_", knob_count=int(r.integers(0, 3))
            )

    def wall_unit(self, frame, x0, x1, z0, z1, depth) -> None:
        r = self.rng
        c = self.carcass(frame, x0, x1, z0, z1, depth, "wallcab")
        w, h = x1 - x0, z1 - z0
        handle = "none" if r.random() < 0.25 else "auto"
        if w > 1.3 * h:
            self.door(c, x0, x1, z0, z1, "top", handle=handle)
        elif w > 0.7:
            mid = (x0 + x1) / 2
            self.door(c, x0, mid, z0, z1, "left", handle=handle)
            self.door(c, mid, x1, z0, z1, "right", handle=handle)
        else:
            self.door(c, x0, x1, z0, z1, "left" if r.random() < 0.5 else "right", handle=handle)

    def tall_unit(self, frame, x0, x1, height, depth, kind) -> None:
        r = self.rng
        plinth = 0.1
        c = self.carcass(frame, x0, x1, plinth, height, depth, "tall")
        hinge = "left" if r.random() < 0.5 else "right"
        if kind == "fridge":
            split = plinth + float(r.uniform(0.6, 0.8))
            self.door(c, x0, x1, plinth, split, hinge, name_stem="fridge_door_")
            self.door(c, x0, x1, split, height, hinge, name_stem="fridge_door_")
        elif kind == "oven_tower":
            z_oven = float(r.uniform(0.7, 0.85))
            self.drawer(c, x0, x1, plinth, z_oven - 0.25, depth)
            self.drawer(c, x0, x1, z_oven - 0.25, z_oven, depth)
            self.door(
                c, x0, x1, z_oven, z_oven + 0.6, "bottom", name_stem="oven_door_", knob_count=int(r.integers(0, 4))
            )
            self.door(c, x0, x1, z_oven + 0.6, height, hinge)
        else:
            split = plinth + float(r.uniform(0.7, 0.9))
            self.door(c, x0, x1, plinth, split, hinge)
            self.door(c, x0, x1, split, height, hinge)

    def row(self, frame: np.ndarray, length: float, depth: float, wall_units: bool, tall_ok: bool) -> float:
        """Units along a row of ``length`` (row frame: x along the row, -y outward, front plane at
        y = 0); returns the counter height."""
        r = self.rng
        height = float(r.uniform(0.82, 0.9))
        x = 0.0
        base_spans = []
        kinds = ["drawers", "door", "double", "drawer_door", "oven", "dishwasher"]
        probs = np.array([0.3, 0.2, 0.15, 0.15, 0.1, 0.1])
        tall_h = float(r.uniform(2.0, 2.2))
        while x < length - 0.3:
            if tall_ok and r.random() < 0.15:
                w = 0.6
                if x + w > length:
                    break
                self.tall_unit(frame, x, x + w, tall_h, depth, str(r.choice(["fridge", "oven_tower", "tall"])))
                x += w
                continue
            kind = str(r.choice(kinds, p=probs))
            w = (
                0.6
                if kind in ("oven", "dishwasher")
                else float(r.choice([0.4, 0.45, 0.5, 0.6, 0.8, 0.9] if kind != "double" else [0.8, 0.9, 1.0]))
            )
            if x + w > length:
                w = length - x
                if w < 0.3:
                    break
                kind = "drawers" if w < 0.8 else kind
            self.base_unit(frame, x, x + w, height, depth, kind)
            base_spans.append((x, x + w))
            x += w
        # counter tops over runs of base units
        for a, b in _merge_spans(base_spans):
            name = self._id("countertop_")
            t = float(r.uniform(0.03, 0.04))
            self.u.link(
                name,
                [
                    (
                        np.array([(a + b) / 2, depth / 2 - 0.02, height + t / 2]),
                        np.zeros(3),
                        _box([b - a, depth + 0.04, t]),
                    )
                ],
            )
            self.u.joint(
                f"{name}_joint", "fixed", "world", name, frame[:3, 3], rpy=(0, 0, np.arctan2(frame[1, 0], frame[0, 0]))
            )
            if wall_units:
                z0 = height + float(r.uniform(0.5, 0.6))
                z1 = z0 + float(r.uniform(0.55, 0.8))
                xx = a
                while xx < b - 0.3:
                    w = min(float(r.choice([0.4, 0.5, 0.6, 0.8, 1.0])), b - xx)
                    self.wall_unit(frame, xx, xx + w, z0, z1, 0.35)
                    xx += w
            if r.random() < 0.4 and b - a > 0.8:  # an appliance box standing on the counter
                name = self._id("object_")
                s = r.uniform([0.2, 0.2, 0.25], [0.35, 0.3, 0.4])
                px = float(r.uniform(a + 0.2, b - 0.2))
                self.u.link(name, [(np.array([px, depth / 2, height + 0.04 + s[2] / 2]), np.zeros(3), _box(s))])
                self.u.joint(
                    f"{name}_joint",
                    "fixed",
                    "world",
                    name,
                    frame[:3, 3],
                    rpy=(0, 0, np.arctan2(frame[1, 0], frame[0, 0])),
                )
        return height

    def island(self, frame: np.ndarray, length: float, depth: float) -> None:
        height = self.row(frame, length, depth, wall_units=False, tall_ok=False)
        name = self._id("island_back_")
        self.u.link(
            name, [(np.array([length / 2, depth + 0.01, height / 2]), np.zeros(3), _box([length, 0.02, height]))]
        )
        self.u.joint(
            f"{name}_joint", "fixed", "world", name, frame[:3, 3], rpy=(0, 0, np.arctan2(frame[1, 0], frame[0, 0]))
        )

    def table(self, center: np.ndarray, yaw: float) -> None:
        r = self.rng
        size = r.uniform([0.8, 0.7], [1.4, 0.9])
        h = float(r.uniform(0.72, 0.76))
        name = self._id("table_")
        vis = [(np.array([0.0, 0.0, h - 0.015]), np.zeros(3), _box([size[0], size[1], 0.03]))]
        for sx in (-1, 1):
            for sy in (-1, 1):
                vis.append(
                    (
                        np.array([sx * (size[0] / 2 - 0.05), sy * (size[1] / 2 - 0.05), (h - 0.03) / 2]),
                        np.zeros(3),
                        _box([0.04, 0.04, h - 0.03]),
                    )
                )
        self.u.link(name, vis)
        self.u.joint(f"{name}_joint", "fixed", "world", name, [center[0], center[1], 0.0], rpy=(0, 0, yaw))


def _merge_spans(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[list[float]] = []
    for a, b in spans:
        if out and abs(out[-1][1] - a) < 1e-6:
            out[-1][1] = b
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def _frame(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:2, 3] = [x, y]
    return T


@dataclass
class KitchenLayout:
    """What :func:`generate_kitchen` made: the URDF text, the room and where a robot may scan from."""

    urdf: str
    room: tuple[float, float, float, float, float]  # x0, y0, x1, y1, height
    viewpoints: np.ndarray  # (V, 3)


def generate_kitchen(seed: int) -> KitchenLayout:
    """A random kitchen (deterministic for ``seed``): a back row along the wall y = D, sometimes a
    side row along x = 0 (both with wall units above the counter), sometimes an island facing the
    back row or a table, in a room 3.6-6 m by 3.4-5 m; three scan viewpoints in the aisle."""
    k = _Kitchen(seed)
    r = k.rng
    W, D, H = float(r.uniform(3.6, 6.0)), float(r.uniform(3.4, 5.0)), float(r.uniform(2.4, 2.8))
    depth = float(r.uniform(0.55, 0.62))
    side = bool(r.random() < 0.6)
    x_back = depth if side else float(r.uniform(0.0, 0.4))
    back_len = W - x_back - (0.0 if r.random() < 0.5 else float(r.uniform(0.3, 0.8)))
    k.row(_frame(x_back, D - depth, 0.0), back_len, depth, wall_units=True, tall_ok=True)
    if side:  # fronts facing +x; the row runs toward +y and ends where the back row begins
        y0 = float(r.uniform(0.4, 1.2))
        k.row(_frame(depth, y0, np.pi / 2), D - depth - y0, depth, wall_units=bool(r.random() < 0.6), tall_ok=True)
    x_free = depth + 0.9 if side else 0.3
    aisle = float(r.uniform(1.0, 1.3))
    y_views = D - depth - aisle / 2
    if r.random() < 0.5 and W - x_free > 2.4 and D - depth - aisle > 1.5:  # an island facing the back row
        length = float(min(W - x_free - 0.6, r.uniform(1.2, 2.4)))
        x0 = x_free + float(r.uniform(0.0, 0.4))
        k.island(_frame(x0 + length, D - depth - aisle, np.pi), length, float(r.uniform(0.55, 0.62)))
    else:
        y_views = D - depth - float(r.uniform(0.8, 1.1))
        if r.random() < 0.6:
            k.table(
                np.array([float(r.uniform(x_free + 0.6, W - 0.9)), float(r.uniform(0.8, max(0.9, y_views - 0.9)))]),
                float(r.uniform(-0.3, 0.3)),
            )
    views = np.array(
        [[x_free + f * (W - x_free - 0.3), y_views, float(r.uniform(1.2, 1.5))] for f in (0.15, 0.5, 0.85)]
    )
    return KitchenLayout(k.u.text(), (0.0, 0.0, W, D, H), views)


def write_kitchen(seed: int, path: str | Path) -> KitchenLayout:
    layout = generate_kitchen(seed)
    Path(path).write_text(layout.urdf)
    return layout
