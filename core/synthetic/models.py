"""Parametric model families: clean, watertight part meshes in a canonical frame, with joints.

Canonical frame: +z up, front along -y, origin at the bottom center of the model, metres.

A :class:`Model` is a list of parts (each a closed mesh with an albedo, belonging to a *link*)
and the joints between links (URDF semantics: ``Joint.origin`` is the joint frame in the model
frame at joint position 0; a child link's frame is its joint's frame). Every family samples its
parameters (dimensions, styles, counts) from a seeded generator, so one family spans real
variety and the same (family, seed, index) always gives the same model.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Joint

trimesh = lazy_module("trimesh")

ROOT_LINK = "body"


@dataclass
class ModelPart:
    name: str
    mesh: trimesh.Trimesh  # model frame, at joint positions 0
    albedo: tuple[float, float, float]
    semantic: str = ""  # e.g. "seat", "leg", "door", "handle", "knob", "drawer_front"
    link: str = ROOT_LINK
    #: (F, 3) per-face colours in [0, 1] of models from libraries whose faces differ in colour
    #: (textures, several materials); ``albedo`` is their mean. None: one colour, ``albedo``.
    face_colors: np.ndarray | None = None


@dataclass
class Model:
    """A complete object model of a family, with its sampled parameters."""

    id: str
    class_name: str
    family: str
    params: dict[str, Any]
    parts: list[ModelPart]
    joints: list[Joint] = field(default_factory=list)
    #: Horizontal rectangles other objects may rest on: (xmin, ymin, xmax, ymax, z) in the model frame.
    support_surfaces: list[tuple[float, float, float, float, float]] = field(default_factory=list)

    def mesh(self) -> trimesh.Trimesh:
        """All parts as one mesh (each part is closed, so the union of shells is watertight)."""
        return trimesh.util.concatenate([p.mesh for p in self.parts])

    @property
    def bounds(self) -> np.ndarray:
        return np.array(
            [np.min([p.mesh.bounds[0] for p in self.parts], 0), np.max([p.mesh.bounds[1] for p in self.parts], 0)]
        )

    @property
    def size(self) -> np.ndarray:
        lo, hi = self.bounds
        return hi - lo

    def links(self) -> list[str]:
        names = [ROOT_LINK]
        for p in self.parts:
            if p.link not in names:
                names.append(p.link)
        return names


# ------------------------------------------------------------------------------------------
# A small builder that families use


@dataclass(frozen=True)
class FixtureStyle:
    """How a model's handles and knobs are made: a bar's square section and standoff (m), its
    length as a share of the front's default, its colour, and the knobs' size as a share of the
    default."""

    section: float = 0.012
    standoff: float = 0.03
    length_scale: float = 1.0
    albedo: tuple[float, float, float] = (0.75, 0.75, 0.78)
    knob_scale: float = 1.0

    @classmethod
    def sample(cls, rng: np.random.Generator) -> FixtureStyle:
        """A style of its own: thin to thick bars, close to far off the front, short to long (at
        most 1.8 times the default, which keeps a bar within its front), light metal or dark."""
        grey = rng.uniform(0.55, 0.9) if rng.random() < 0.5 else rng.uniform(0.03, 0.25)
        return cls(
            section=float(rng.uniform(0.008, 0.02)),
            standoff=float(rng.uniform(0.015, 0.04)),
            length_scale=float(rng.uniform(0.8, 1.8)),
            albedo=(float(grey), float(grey), float(min(1.0, grey + 0.03))),
            knob_scale=float(rng.uniform(0.7, 1.4)),
        )


class Builder:
    def __init__(self, rng: np.random.Generator, fixtures: FixtureStyle | None = None):
        self.rng = rng
        #: Handles' and knobs' style: None, the default (every benchmark scene's).
        self.fixtures = fixtures
        self.params: dict[str, Any] = {}
        self.parts: list[ModelPart] = []
        self.joints: list[Joint] = []
        self.surfaces: list[tuple[float, float, float, float, float]] = []

    def u(self, name: str, lo: float, hi: float) -> float:
        value = float(np.round(self.rng.uniform(lo, hi), 4))
        self.params[name] = value
        return value

    def choice(self, name: str, options: list[Any]) -> Any:
        value = options[int(self.rng.integers(len(options)))]
        self.params[name] = value
        return value

    def integer(self, name: str, lo: int, hi: int) -> int:
        value = int(self.rng.integers(lo, hi + 1))
        self.params[name] = value
        return value

    def color(self, lo=(0.1, 0.1, 0.1), hi=(0.9, 0.9, 0.9)) -> tuple[float, float, float]:
        return tuple(float(v) for v in np.round(self.rng.uniform(lo, hi), 3))  # type: ignore[return-value]

    def box(self, name, size, center, albedo, semantic="", link=ROOT_LINK) -> ModelPart:
        mesh = trimesh.creation.box(extents=np.maximum(size, 1e-3), transform=make_pose(center))
        part = ModelPart(name, mesh, albedo, semantic or name, link)
        self.parts.append(part)
        return part

    def cylinder(
        self, name, radius, height, center, albedo, semantic="", link=ROOT_LINK, axis="z", sections=20
    ) -> ModelPart:
        mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
        if axis == "x":
            mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        elif axis == "y":
            mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        mesh.apply_translation(center)
        part = ModelPart(name, mesh, albedo, semantic or name, link)
        self.parts.append(part)
        return part

    def frustum(
        self, name, r_bottom, r_top, height, center_bottom, albedo, semantic="", link=ROOT_LINK, sections=20
    ) -> ModelPart:
        """A closed truncated cone (cups, pots)."""
        a = np.linspace(0, 2 * np.pi, sections, endpoint=False)
        ring = np.stack([np.cos(a), np.sin(a)], 1)
        verts = np.vstack(
            [
                np.c_[ring * r_bottom, np.zeros(sections)],
                np.c_[ring * r_top, np.full(sections, height)],
                [[0, 0, 0], [0, 0, height]],
            ]
        )
        faces = []
        for i in range(sections):
            j = (i + 1) % sections
            faces += [
                [i, j, sections + j],
                [i, sections + j, sections + i],
                [2 * sections, j, i],
                [2 * sections + 1, sections + i, sections + j],
            ]
        mesh = trimesh.Trimesh(verts + np.asarray(center_bottom), np.array(faces), process=True)
        part = ModelPart(name, mesh, albedo, semantic or name, link)
        self.parts.append(part)
        return part

    def joint(self, name, jtype, child, origin_xyz, axis, lower, upper, parent=ROOT_LINK) -> None:
        self.joints.append(
            Joint(name, jtype, parent, child, make_pose(origin_xyz), np.asarray(axis, float), lower, upper)
        )

    def surface(self, xmin, ymin, xmax, ymax, z) -> None:
        self.surfaces.append(tuple(float(v) for v in (xmin, ymin, xmax, ymax, z)))  # type: ignore[arg-type]

    # ---- composite helpers -----------------------------------------------------------------

    def handle(self, name, center, length, link, vertical=True, albedo=(0.75, 0.75, 0.78)) -> None:
        """A bar handle standing off a front face (which faces -y) at ``center`` (on the face)."""
        cx, cy, cz = center
        t, stand, post = 0.012, 0.03, 0.024
        if self.fixtures is not None:
            t, stand, albedo = self.fixtures.section, self.fixtures.standoff, self.fixtures.albedo
            length, post = length * self.fixtures.length_scale, stand - t / 2
        bar = (t, t, length) if vertical else (length, t, t)
        self.box(f"{name}_bar", bar, (cx, cy - stand, cz), albedo, "handle", link)
        off = (0, 0, length / 2 - 0.008) if vertical else (length / 2 - 0.008, 0, 0)
        for k, sign in enumerate((-1, 1)):
            c = (cx + sign * off[0], cy - post / 2, cz + sign * off[2])
            self.box(f"{name}_post{k}", (0.01, post, 0.01), c, albedo, "handle", link)

    def knob(self, name, center, link, albedo=(0.7, 0.7, 0.72)) -> None:
        cx, cy, cz = center
        radius, length = 0.015, 0.025
        if self.fixtures is not None:
            radius, length = radius * self.fixtures.knob_scale, length * self.fixtures.knob_scale
            albedo = self.fixtures.albedo
        self.cylinder(f"{name}", radius, length, (cx, cy - length / 2, cz), albedo, "knob", link, axis="y", sections=12)

    def door(self, name, x0, x1, z0, z1, y_front, thickness, albedo, hinge: str, fixture: str = "handle") -> None:
        """A revolute door covering x0..x1, z0..z1 on a front face at y_front (opening outwards)."""
        w = x1 - x0
        link = name
        self.box(
            f"{name}_panel",
            (w - 0.004, thickness, z1 - z0 - 0.004),
            ((x0 + x1) / 2, y_front - thickness / 2, (z0 + z1) / 2),
            albedo,
            "door",
            link,
        )
        fx = x1 - 0.05 if hinge == "left" else x0 + 0.05
        fz = (z0 + z1) / 2 if z1 - z0 < 0.5 else min(z1 - 0.15, z0 + 0.9)
        if fixture == "handle":
            self.handle(f"{name}_handle", (fx, y_front - thickness, fz), min(0.15, (z1 - z0) * 0.5), link)
        else:
            self.knob(f"{name}_knob", (fx, y_front - thickness, fz), link)
        hx = x0 if hinge == "left" else x1
        axis = (0, 0, -1) if hinge == "left" else (0, 0, 1)
        self.joint(
            f"{name}_hinge",
            "revolute",
            link,
            (hx, y_front - thickness, (z0 + z1) / 2),
            axis,
            0.0,
            float(np.radians(100)),
        )
        self.params.setdefault("hinges", []).append(hinge)

    def drawer(self, name, x0, x1, z0, z1, y_front, depth, albedo, fixture: str = "handle") -> None:
        """A prismatic drawer: front panel plus an open box behind it, sliding out along -y."""
        w, h = x1 - x0, z1 - z0
        link = name
        t = 0.018
        cx = (x0 + x1) / 2
        self.box(
            f"{name}_front",
            (w - 0.004, t, h - 0.004),
            (cx, y_front - t / 2, (z0 + z1) / 2),
            albedo,
            "drawer_front",
            link,
        )
        inner_w, inner_h, d = w - 0.06, max(h - 0.06, 0.03), depth - 0.04
        yb = y_front + d / 2
        self.box(f"{name}_bottom", (inner_w, d, 0.012), (cx, yb, z0 + 0.03), albedo, "drawer", link)
        for k, sx in enumerate((-1, 1)):
            self.box(
                f"{name}_side{k}",
                (0.012, d, inner_h),
                (cx + sx * (inner_w / 2 - 0.006), yb, z0 + 0.03 + inner_h / 2),
                albedo,
                "drawer",
                link,
            )
        self.box(
            f"{name}_back",
            (inner_w, 0.012, inner_h),
            (cx, y_front + d - 0.006, z0 + 0.03 + inner_h / 2),
            albedo,
            "drawer",
            link,
        )
        if fixture == "handle":
            self.handle(f"{name}_handle", (cx, y_front - t, (z0 + z1) / 2), min(0.3, w * 0.5), link, vertical=False)
        else:
            self.knob(f"{name}_knob", (cx, y_front - t, (z0 + z1) / 2), link)
        self.joint(
            f"{name}_slide", "prismatic", link, (cx, y_front, (z0 + z1) / 2), (0, -1, 0), 0.0, float(round(d * 0.8, 4))
        )

    def carcass(self, w, d, h, t, albedo, z0=0.0, back=True, plinth=0.0) -> None:
        """An open-front box of panels: sides, top, bottom, back (the body of cabinets)."""
        self.box("side_left", (t, d, h - z0), (-w / 2 + t / 2, 0, z0 + (h - z0) / 2), albedo, "panel")
        self.box("side_right", (t, d, h - z0), (w / 2 - t / 2, 0, z0 + (h - z0) / 2), albedo, "panel")
        self.box("top", (w - 2 * t, d, t), (0, 0, h - t / 2), albedo, "panel")
        self.box("bottom", (w - 2 * t, d, t), (0, 0, z0 + plinth + t / 2), albedo, "panel")
        if plinth > 0:
            self.box("plinth", (w - 2 * t, t, plinth), (0, -d / 2 + 0.05, z0 + plinth / 2), albedo, "panel")
        if back:
            self.box(
                "back",
                (w - 2 * t, t, h - z0 - 2 * t - plinth),
                (0, d / 2 - t / 2, z0 + plinth + (h - z0 - plinth) / 2),
                albedo,
                "panel",
            )


WOOD_LO, WOOD_HI = (0.35, 0.2, 0.1), (0.75, 0.55, 0.35)
METAL = (0.6, 0.6, 0.62)
DARK = (0.12, 0.12, 0.13)


# ------------------------------------------------------------------------------------------
# Chairs


def four_leg_chair(b: Builder) -> None:
    w, d = b.u("seat_width", 0.40, 0.50), b.u("seat_depth", 0.40, 0.48)
    h, t = b.u("seat_height", 0.42, 0.48), b.u("seat_thickness", 0.03, 0.06)
    bh, lw = b.u("back_height", 0.35, 0.50), b.u("leg_width", 0.03, 0.045)
    arms = b.choice("arms", [False, False, True])
    wood, fabric = b.color(WOOD_LO, WOOD_HI), b.color()
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        b.box(f"leg_{i}", (lw, lw, h - t), (sx * (w / 2 - lw / 2), sy * (d / 2 - lw / 2), (h - t) / 2), wood, "leg")
    b.box("seat", (w, d, t), (0, 0, h - t / 2), fabric, "seat")
    b.box("back", (w, 0.03, bh), (0, d / 2 - 0.015, h + bh / 2), fabric, "back")
    if arms:
        for k, sx in enumerate((-1, 1)):
            b.box(f"arm_{k}", (0.04, d * 0.8, 0.03), (sx * (w / 2 - 0.02), 0.02, h + 0.2), wood, "arm")
            b.box(f"arm_post_{k}", (0.03, 0.03, 0.2), (sx * (w / 2 - 0.02), -d / 2 + 0.08, h + 0.1), wood, "arm")


def office_chair(b: Builder) -> None:
    """Swivel office chair: five-star base with casters, gas stem, seat, back (seat swivels)."""
    r = b.u("base_radius", 0.28, 0.34)
    h = b.u("seat_height", 0.44, 0.52)
    w, d = b.u("seat_width", 0.46, 0.52), b.u("seat_depth", 0.44, 0.50)
    bh = b.u("back_height", 0.40, 0.62)
    arms = b.choice("arms", [True, False])
    fabric = b.color((0.05, 0.05, 0.05), (0.4, 0.4, 0.5))
    caster_r = 0.025
    hub_z = 2 * caster_r + 0.03
    for i in range(5):
        a = 2 * np.pi * i / 5 + np.pi / 2
        mid = np.array([np.cos(a), np.sin(a)]) * r / 2
        spoke = trimesh.creation.box(extents=(r, 0.045, 0.03))
        spoke.apply_transform(make_pose((mid[0], mid[1], hub_z), float(a)))
        b.parts.append(ModelPart(f"spoke_{i}", spoke, DARK, "base"))
        tip = np.array([np.cos(a), np.sin(a)]) * (r - 0.02)
        b.cylinder(f"caster_{i}", caster_r, 0.02, (tip[0], tip[1], caster_r), DARK, "caster", axis="x", sections=12)
        b.box(
            f"caster_fork_{i}",
            (0.02, 0.02, hub_z - 2 * caster_r + 0.002),
            (tip[0], tip[1], 2 * caster_r + (hub_z - 2 * caster_r) / 2 - 0.016),
            DARK,
            "caster",
        )
    b.cylinder("hub", 0.04, 0.05, (0, 0, hub_z), DARK, "base")
    stem_h = h - 0.06 - hub_z - 0.025
    b.cylinder("gas_stem", 0.022, stem_h, (0, 0, hub_z + 0.025 + stem_h / 2), METAL, "stem")
    # The seat, back and arms swivel about the stem: a continuous joint.
    s = "swivel"
    b.box("seat", (w, d, 0.06), (0, 0, h - 0.03), fabric, "seat", link=s)
    b.box("back_post", (0.05, 0.03, 0.2), (0, d / 2 - 0.015, h + 0.06), DARK, "back", link=s)
    b.box("back", (w * 0.95, 0.05, bh), (0, d / 2 - 0.01, h + 0.14 + bh / 2), fabric, "back", link=s)
    if arms:
        for k, sx in enumerate((-1, 1)):
            b.box(f"arm_{k}", (0.05, d * 0.55, 0.025), (sx * (w / 2 + 0.025), 0.0, h + 0.2), DARK, "arm", link=s)
            b.box(f"arm_post_{k}", (0.025, 0.04, 0.19), (sx * (w / 2 + 0.025), 0.0, h + 0.095), DARK, "arm", link=s)
    b.joint("swivel", "continuous", s, (0, 0, h - 0.06), (0, 0, 1), 0.0, 0.0)


def stool(b: Builder) -> None:
    r, h = b.u("radius", 0.15, 0.2), b.u("height", 0.45, 0.75)
    legs = b.integer("legs", 3, 4)
    top = b.color()
    b.cylinder("seat", r, 0.04, (0, 0, h - 0.02), top, "seat")
    for i in range(legs):
        a = 2 * np.pi * i / legs
        b.cylinder(
            f"leg_{i}",
            0.015,
            h - 0.04,
            (0.75 * r * np.cos(a), 0.75 * r * np.sin(a), (h - 0.04) / 2),
            METAL,
            "leg",
            sections=10,
        )


def armchair(b: Builder) -> None:
    w, d = b.u("width", 0.75, 0.95), b.u("depth", 0.75, 0.9)
    sh, bh = b.u("seat_height", 0.38, 0.45), b.u("back_height", 0.75, 0.95)
    ah = b.u("arm_height", 0.55, 0.65)
    arm_w = b.u("arm_width", 0.12, 0.2)
    fabric = b.color()
    b.box("base", (w, d, sh - 0.12), (0, 0, 0.05 + (sh - 0.12) / 2), fabric, "base")
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        b.box(f"foot_{i}", (0.05, 0.05, 0.05), (sx * (w / 2 - 0.05), sy * (d / 2 - 0.05), 0.025), DARK, "leg")
    b.box("cushion", (w - 2 * arm_w, d - 0.18, 0.12), (0, -0.09 + 0.0, sh - 0.06), fabric, "seat")
    b.box("back", (w, 0.18, bh - sh + 0.12), (0, d / 2 - 0.09, sh - 0.12 + (bh - sh + 0.12) / 2), fabric, "back")
    for k, sx in enumerate((-1, 1)):
        b.box(
            f"arm_{k}",
            (arm_w, d - 0.18, ah - sh + 0.12),
            (sx * (w / 2 - arm_w / 2), -0.09, sh - 0.12 + (ah - sh + 0.12) / 2),
            fabric,
            "arm",
        )


def bench(b: Builder) -> None:
    L, d, h = b.u("length", 1.0, 1.8), b.u("depth", 0.32, 0.45), b.u("height", 0.42, 0.47)
    backrest = b.choice("backrest", [False, True])
    wood = b.color(WOOD_LO, WOOD_HI)
    b.box("seat", (L, d, 0.04), (0, 0, h - 0.02), wood, "seat")
    for k, sx in enumerate((-1, 1)):
        b.box(f"leg_{k}", (0.05, d - 0.04, h - 0.04), (sx * (L / 2 - 0.08), 0, (h - 0.04) / 2), METAL, "leg")
    if backrest:
        b.box("back", (L, 0.03, 0.35), (0, d / 2 - 0.015, h + 0.2), wood, "back")
        for k, sx in enumerate((-1, 1)):
            b.box(f"back_post_{k}", (0.04, 0.03, 0.06), (sx * (L / 2 - 0.08), d / 2 - 0.015, h + 0.02), METAL, "back")


# ------------------------------------------------------------------------------------------
# Tables and desks


def rectangular_table(b: Builder) -> None:
    L, W = b.u("length", 1.2, 2.2), b.u("width", 0.7, 1.0)
    H, t, lw = b.u("height", 0.72, 0.76), b.u("top_thickness", 0.025, 0.04), b.u("leg_width", 0.04, 0.07)
    top_c, leg_c = b.color(WOOD_LO, WOOD_HI), b.color((0.1, 0.1, 0.1), (0.6, 0.6, 0.6))
    inset = 0.05
    b.box("top", (L, W, t), (0, 0, H - t / 2), top_c, "top")
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        b.box(
            f"leg_{i}",
            (lw, lw, H - t),
            (sx * (L / 2 - inset - lw / 2), sy * (W / 2 - inset - lw / 2), (H - t) / 2),
            leg_c,
            "leg",
        )
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def round_table(b: Builder) -> None:
    r, H = b.u("radius", 0.4, 0.6), b.u("height", 0.72, 0.76)
    top_c = b.color(WOOD_LO, WOOD_HI)
    b.cylinder("top", r, 0.03, (0, 0, H - 0.015), top_c, "top", sections=32)
    b.cylinder("pedestal", 0.045, H - 0.05, (0, 0, 0.02 + (H - 0.05) / 2), DARK, "leg")
    b.cylinder("foot", r * 0.55, 0.02, (0, 0, 0.01), DARK, "leg", sections=24)
    s = r / np.sqrt(2)
    b.surface(-s, -s, s, s, H)


def coffee_table(b: Builder) -> None:
    L, W, H = b.u("length", 0.8, 1.3), b.u("width", 0.45, 0.7), b.u("height", 0.35, 0.48)
    shelf = b.choice("lower_shelf", [True, False])
    c = b.color(WOOD_LO, WOOD_HI)
    b.box("top", (L, W, 0.04), (0, 0, H - 0.02), c, "top")
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        b.box(f"leg_{i}", (0.05, 0.05, H - 0.04), (sx * (L / 2 - 0.05), sy * (W / 2 - 0.05), (H - 0.04) / 2), c, "leg")
    if shelf:
        b.box("shelf", (L - 0.15, W - 0.1, 0.02), (0, 0, 0.12), c, "shelf")
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def desk(b: Builder) -> None:
    """A desk with a drawer unit under one side (prismatic drawers) and a panel leg on the other."""
    L, W, H = b.u("length", 1.2, 1.8), b.u("width", 0.6, 0.8), b.u("height", 0.72, 0.76)
    side = b.choice("drawer_side", ["left", "right"])
    n = b.integer("drawers", 2, 4)
    unit_w = b.u("unit_width", 0.38, 0.45)
    c, front = b.color(WOOD_LO, WOOD_HI), b.color()
    t = 0.03
    b.box("top", (L, W, t), (0, 0, H - t / 2), c, "top")
    sx = -1 if side == "left" else 1
    ux = sx * (L / 2 - unit_w / 2)
    uh = H - t
    # Drawer unit carcass.
    b.box("unit_side_outer", (0.018, W - 0.02, uh), (ux + sx * (unit_w / 2 - 0.009), 0.01, uh / 2), c, "panel")
    b.box("unit_side_inner", (0.018, W - 0.02, uh), (ux - sx * (unit_w / 2 - 0.009), 0.01, uh / 2), c, "panel")
    b.box("unit_back", (unit_w - 0.036, 0.018, uh), (ux, W / 2 - 0.009, uh / 2), c, "panel")
    b.box("unit_bottom", (unit_w - 0.036, W - 0.04, 0.018), (ux, 0.02, 0.05), c, "panel")
    y_front = -W / 2 + 0.02
    dh = (uh - 0.06) / n
    for k in range(n):
        z0 = 0.06 + k * dh
        b.drawer(f"drawer_{k}", ux - unit_w / 2 + 0.02, ux + unit_w / 2 - 0.02, z0, z0 + dh, y_front, W - 0.08, front)
    # Panel leg on the other side and a modesty panel.
    b.box("leg_panel", (0.03, W - 0.04, uh), (-sx * (L / 2 - 0.015), 0, uh / 2), c, "leg")
    b.box("modesty", (L - unit_w - 0.04, 0.018, 0.35), (-sx * unit_w / 2, W / 2 - 0.05, uh - 0.175), c, "panel")
    b.params["knee_center_x"] = float(-sx * unit_w / 2)
    b.params["knee_width"] = float(L - unit_w - 0.03)
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


# ------------------------------------------------------------------------------------------
# Storage


def cabinet(b: Builder) -> None:
    """Cabinet with revolute doors and/or prismatic drawers; handles or knobs as separate parts."""
    w, d, h = b.u("width", 0.5, 1.0), b.u("depth", 0.4, 0.6), b.u("height", 0.7, 1.9)
    layout = b.choice(
        "layout", ["doors", "drawers", "drawers_over_doors"] if h < 1.2 else ["doors", "drawers_over_doors"]
    )
    fixture = b.choice("fixture", ["handle", "knob"])
    c, front = b.color(WOOD_LO, WOOD_HI), b.color()
    t = 0.018
    plinth = 0.06
    b.carcass(w, d, h, t, c, plinth=plinth)
    shelves = b.integer("shelves", 0, 3 if h > 1.2 else 1)
    for k in range(shelves):
        z = plinth + (h - plinth) * (k + 1) / (shelves + 1)
        b.box(f"shelf_{k}", (w - 2 * t, d - 0.04, t), (0, 0.01, z), c, "shelf")
    y_front = -d / 2
    z_lo, z_hi = plinth + t, h - t
    if layout in ("drawers", "drawers_over_doors"):
        n = b.integer("drawers", 1 if layout == "drawers_over_doors" else 2, 2 if layout == "drawers_over_doors" else 4)
        dh = 0.18 if layout == "drawers_over_doors" else (z_hi - z_lo) / n
        top = z_hi
        for k in range(n):
            b.drawer(
                f"drawer_{k}",
                -w / 2 + t,
                w / 2 - t,
                top - (k + 1) * dh,
                top - k * dh,
                y_front,
                d - 0.04,
                front,
                fixture,
            )
        z_hi = top - n * dh
    if layout in ("doors", "drawers_over_doors"):
        two = w > 0.7
        if two:
            b.door("door_left", -w / 2 + t, 0, z_lo, z_hi, y_front, 0.018, front, "left", fixture)
            b.door("door_right", 0, w / 2 - t, z_lo, z_hi, y_front, 0.018, front, "right", fixture)
        else:
            hinge = b.choice("hinge", ["left", "right"])
            b.door("door", -w / 2 + t, w / 2 - t, z_lo, z_hi, y_front, 0.018, front, hinge, fixture)
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def shelf(b: Builder) -> None:
    w, d, h = b.u("width", 0.6, 1.2), b.u("depth", 0.28, 0.4), b.u("height", 0.8, 2.0)
    n = b.integer("boards", 2, 5)
    c = b.color(WOOD_LO, WOOD_HI)
    t = 0.02
    b.carcass(w, d, h, t, c)
    for k in range(n - 1):
        z = t + (h - 2 * t) * (k + 1) / n
        b.box(f"board_{k}", (w - 2 * t, d - 0.02, t), (0, -0.01, z), c, "shelf")
        b.surface(-w / 2 + t, -d / 2, w / 2 - t, d / 2 - t, z + t / 2)
    b.surface(-w / 2 + t, -d / 2, w / 2 - t, d / 2 - t, 1.5 * t)
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def kitchen_counter(b: Builder) -> None:
    """Base units under a countertop: cupboards (revolute doors) and drawer stacks."""
    modules = b.integer("modules", 2, 4)
    mw = b.u("module_width", 0.45, 0.6)
    d, h = b.u("depth", 0.58, 0.64), b.u("height", 0.86, 0.92)
    fixture = b.choice("fixture", ["handle", "knob"])
    c, front, top_c = b.color(WOOD_LO, WOOD_HI), b.color(), b.color((0.1, 0.1, 0.1), (0.9, 0.9, 0.9))
    w = modules * mw
    t = 0.018
    plinth = 0.1
    ct = 0.03
    body_h = h - ct
    b.box("countertop", (w + 0.02, d + 0.02, ct), (0, -0.01, h - ct / 2), top_c, "top")
    b.box("plinth", (w, 0.02, plinth), (0, -d / 2 + 0.06, plinth / 2), DARK, "panel")
    b.box("back", (w, t, body_h - plinth), (0, d / 2 - t / 2, plinth + (body_h - plinth) / 2), c, "panel")
    b.box("bottom", (w, d - t, t), (0, -t / 2, plinth + t / 2), c, "panel")
    for k in range(modules + 1):
        x = -w / 2 + k * mw
        x = min(max(x, -w / 2 + t / 2), w / 2 - t / 2)
        b.box(
            f"divider_{k}",
            (t, d - t, body_h - plinth - t),
            (x, -t / 2, plinth + t + (body_h - plinth - t) / 2),
            c,
            "panel",
        )
    kinds = []
    for k in range(modules):
        x0, x1 = -w / 2 + k * mw + t / 2, -w / 2 + (k + 1) * mw - t / 2
        kind = b.rng.choice(["cupboard", "drawers"], p=[0.6, 0.4])
        kinds.append(str(kind))
        if kind == "cupboard":
            b.door(
                f"door_{k}",
                x0,
                x1,
                plinth + t,
                body_h,
                -d / 2,
                0.018,
                front,
                "left" if k % 2 == 0 else "right",
                fixture,
            )
        else:
            n = 3
            dh = (body_h - plinth - t) / n
            for j in range(n):
                z1 = body_h - j * dh
                b.drawer(f"drawer_{k}_{j}", x0, x1, z1 - dh, z1, -d / 2, d - 0.04, front, fixture)
    b.params["module_kinds"] = kinds
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


# ------------------------------------------------------------------------------------------
# Appliances


def fridge(b: Builder) -> None:
    w, d, h = b.u("width", 0.55, 0.75), b.u("depth", 0.6, 0.72), b.u("height", 1.4, 1.9)
    hinge = b.choice("hinge", ["left", "right"])
    c = b.color((0.75, 0.75, 0.75), (0.98, 0.98, 0.98))
    t = 0.04
    b.carcass(w, d - 0.05, h, t, c, z0=0.0)
    for p in b.parts:
        p.mesh.apply_translation((0, 0.025, 0))
    b.door("door", -w / 2, w / 2, 0.02, h - 0.01, -d / 2 + 0.05, 0.05, c, hinge)
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def microwave(b: Builder) -> None:
    w, d, h = b.u("width", 0.45, 0.55), b.u("depth", 0.32, 0.4), b.u("height", 0.26, 0.32)
    c = b.color((0.05, 0.05, 0.05), (0.9, 0.9, 0.9))
    t = 0.015
    b.carcass(w, d, h, t, c)
    panel = 0.12
    b.box("control_panel", (panel, 0.02, h - 2 * t), (w / 2 - t - panel / 2, -d / 2 + 0.01, h / 2), DARK, "panel")
    b.door("door", -w / 2 + t, w / 2 - t - panel, t, h - t, -d / 2, 0.02, DARK, "left")
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def oven(b: Builder) -> None:
    w, d, h = b.u("width", 0.55, 0.62), b.u("depth", 0.55, 0.62), b.u("height", 0.84, 0.9)
    c = b.color((0.1, 0.1, 0.1), (0.85, 0.85, 0.85))
    t = 0.02
    b.carcass(w, d, h, t, c)
    b.box("hob", (w - 0.02, d - 0.02, 0.01), (0, 0, h + 0.005), DARK, "top")
    b.box("control_panel", (w - 2 * t, 0.02, 0.12), (0, -d / 2 + 0.01, h - t - 0.06), DARK, "panel")
    door_top = h - t - 0.12
    link = "door"
    b.box(
        "door_panel",
        (w - 2 * t - 0.004, 0.03, door_top - t - 0.004),
        (0, -d / 2 - 0.015, (door_top + t) / 2),
        DARK,
        "door",
        link,
    )
    b.handle("door_handle", (0, -d / 2 - 0.03, door_top - 0.05), w * 0.6, link, vertical=False)
    b.joint("door_hinge", "revolute", link, (0, -d / 2 - 0.03, t), (1, 0, 0), 0.0, float(np.radians(90)))
    b.params["hinges"] = ["bottom"]
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h + 0.01)


# ------------------------------------------------------------------------------------------
# Others


def sofa(b: Builder) -> None:
    seats = b.integer("seats", 2, 3)
    w, d = b.u("seat_width", 0.55, 0.7) * seats + 0.4, b.u("depth", 0.8, 0.95)
    sh, bh = b.u("seat_height", 0.4, 0.45), b.u("back_height", 0.75, 0.9)
    fabric = b.color()
    b.box("base", (w, d, sh - 0.17), (0, 0, 0.05 + (sh - 0.17) / 2), fabric, "base")
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        b.box(f"foot_{i}", (0.05, 0.05, 0.05), (sx * (w / 2 - 0.05), sy * (d / 2 - 0.05), 0.025), DARK, "leg")
    cw = (w - 0.4) / seats
    for k in range(seats):
        b.box(
            f"cushion_{k}",
            (cw - 0.01, d - 0.22, 0.12),
            (-w / 2 + 0.2 + cw * (k + 0.5), -0.11, sh - 0.06),
            fabric,
            "seat",
        )
    b.box("back", (w, 0.2, bh - sh + 0.17), (0, d / 2 - 0.1, sh - 0.17 + (bh - sh + 0.17) / 2), fabric, "back")
    for k, sx in enumerate((-1, 1)):
        b.box(
            f"arm_{k}",
            (0.2, d - 0.2, 0.6 - sh + 0.17),
            (sx * (w / 2 - 0.1), -0.1, sh - 0.17 + (0.6 - sh + 0.17) / 2),
            fabric,
            "arm",
        )


def monitor(b: Builder) -> None:
    w, h = b.u("width", 0.48, 0.7), b.u("height", 0.3, 0.42)
    stand_h = b.u("stand_height", 0.08, 0.15)
    b.box("foot", (0.22, 0.18, 0.015), (0, 0.02, 0.0075), DARK, "base")
    b.box("neck", (0.05, 0.03, stand_h + h / 2), (0, 0.06, 0.015 + (stand_h + h / 2) / 2), DARK, "stand")
    b.box("screen", (w, 0.03, h), (0, 0.03, 0.015 + stand_h + h / 2), DARK, "screen")


def laptop(b: Builder) -> None:
    w, d = b.u("width", 0.3, 0.38), b.u("depth", 0.21, 0.26)
    angle = b.u("lid_angle_deg", 95.0, 115.0)
    c = b.color((0.2, 0.2, 0.2), (0.8, 0.8, 0.8))
    b.box("base", (w, d, 0.018), (0, 0, 0.009), c, "base")
    # The lid rotates about the hinge at the back edge; modelled open at the sampled angle (its
    # front edge swung up and a little past vertical: a rotation by -angle about +x).
    lid = trimesh.creation.box(extents=(w, d, 0.008))
    lid.apply_translation((0, -d / 2, 0.004))
    rot = trimesh.transformations.rotation_matrix(-np.radians(angle), [1, 0, 0])
    lid.apply_transform(rot)
    lid.apply_translation((0, d / 2, 0.018))
    b.parts.append(ModelPart("lid", lid, c, "lid", "lid"))
    # q = +angle closes the lid onto the base; q < 0 opens it further, up to 135 degrees.
    b.joint(
        "lid_hinge",
        "revolute",
        "lid",
        (0, d / 2, 0.018),
        (1, 0, 0),
        float(np.radians(angle - 135)),
        float(np.radians(angle)),
    )


def box(b: Builder) -> None:
    L, W, H = b.u("length", 0.15, 0.45), b.u("width", 0.12, 0.35), b.u("height", 0.08, 0.3)
    b.box("body", (L, W, H), (0, 0, H / 2), b.color((0.5, 0.3, 0.1), (0.85, 0.6, 0.35)), "body")
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def book(b: Builder) -> None:
    L, W, H = b.u("length", 0.15, 0.25), b.u("width", 0.2, 0.3), b.u("thickness", 0.015, 0.05)
    b.box("cover", (L, W, H), (0, 0, H / 2), b.color(), "cover")


def cup(b: Builder) -> None:
    r, h = b.u("radius", 0.035, 0.045), b.u("height", 0.08, 0.11)
    c = b.color()
    b.frustum("body", r * 0.85, r, h, (0, 0, 0), c, "body")
    b.box("handle", (0.01, 0.04, h * 0.55), (r + 0.012, 0, h * 0.5), c, "handle")


def bottle(b: Builder) -> None:
    r, h = b.u("radius", 0.03, 0.045), b.u("height", 0.2, 0.32)
    c = b.color((0.1, 0.3, 0.1), (0.5, 0.9, 0.6))
    b.cylinder("body", r, h * 0.7, (0, 0, h * 0.35), c, "body")
    b.frustum("shoulder", r, 0.014, h * 0.15, (0, 0, h * 0.7), c, "body")
    b.cylinder("neck", 0.014, h * 0.15, (0, 0, h * 0.925), c, "neck")


def plant_pot(b: Builder) -> None:
    r, h = b.u("radius", 0.1, 0.2), b.u("pot_height", 0.15, 0.3)
    fh = b.u("foliage_height", 0.2, 0.6)
    b.frustum("pot", r * 0.75, r, h, (0, 0, 0), b.color((0.5, 0.25, 0.15), (0.8, 0.45, 0.3)), "pot")
    foliage = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    foliage.apply_scale((r * 1.3, r * 1.3, fh / 2))
    foliage.apply_translation((0, 0, h + fh / 2 - 0.02))
    b.parts.append(ModelPart("foliage", foliage, b.color((0.1, 0.35, 0.1), (0.3, 0.6, 0.25)), "foliage"))


Family = Callable[[Builder], None]

#: family name -> (class name, generator).
FAMILIES: dict[str, tuple[str, Family]] = {
    "four_leg_chair": ("chair", four_leg_chair),
    "office_chair": ("chair", office_chair),
    "stool": ("chair", stool),
    "armchair": ("chair", armchair),
    "bench": ("bench", bench),
    "rectangular_table": ("table", rectangular_table),
    "round_table": ("table", round_table),
    "coffee_table": ("table", coffee_table),
    "desk": ("desk", desk),
    "cabinet": ("cabinet", cabinet),
    "shelf": ("shelf", shelf),
    "kitchen_counter": ("counter", kitchen_counter),
    "fridge": ("fridge", fridge),
    "microwave": ("microwave", microwave),
    "oven": ("oven", oven),
    "sofa": ("sofa", sofa),
    "monitor": ("monitor", monitor),
    "laptop": ("laptop", laptop),
    "box": ("box", box),
    "book": ("book", book),
    "cup": ("cup", cup),
    "bottle": ("bottle", bottle),
    "plant_pot": ("plant", plant_pot),
}


def make_model(family: str, seed: int, index: int = 0, varied_fixtures: bool = False) -> Model:
    """Sample one model of ``family`` deterministically from ``seed`` and ``index`` (its handles
    and knobs of a style of their own with ``varied_fixtures``, drawn apart from the model's other
    choices so that the model is otherwise the same)."""
    if family not in FAMILIES:
        raise KeyError(f"unknown model family {family!r}; families are {sorted(FAMILIES)}")
    class_name, fn = FAMILIES[family]
    rng = np.random.default_rng([seed, index, sum(map(ord, family))])
    style = FixtureStyle.sample(np.random.default_rng([seed, index, 104729])) if varied_fixtures else None
    b = Builder(rng, style)
    fn(b)
    # Canonical frame: origin at the bottom center of the model's box (x, y centered, z = 0 at the bottom).
    lo = np.min([p.mesh.bounds[0] for p in b.parts], 0)
    hi = np.max([p.mesh.bounds[1] for p in b.parts], 0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    if np.abs(shift).max() > 1e-12:
        for p in b.parts:
            p.mesh.apply_translation(shift)
        for j in b.joints:
            if j.parent == ROOT_LINK:
                j.origin[:3, 3] += shift
        b.surfaces = [
            (s[0] + shift[0], s[1] + shift[1], s[2] + shift[0], s[3] + shift[1], s[4] + shift[2]) for s in b.surfaces
        ]
    return Model(f"{family}_{seed:04d}_{index:03d}", class_name, family, b.params, b.parts, b.joints, b.surfaces)
