"""Parametric model families: clean, watertight part meshes in a canonical frame.

Canonical frame: +z up, front along -y, origin at the bottom center of the model, metres.
A :class:`Model` is a list of named parts (each a closed mesh with an albedo) plus joints.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from stratamap.core.layers import Joint


@dataclass
class ModelPart:
    name: str
    mesh: trimesh.Trimesh  # model frame
    albedo: tuple[float, float, float]
    semantic: str = ""  # e.g. "seat", "leg", "door", "handle"


@dataclass
class Model:
    """A complete object model of a family, with its sampled parameters."""

    id: str
    class_name: str
    family: str
    params: dict[str, Any]
    parts: list[ModelPart]
    joints: list[Joint] = field(default_factory=list)

    def mesh(self) -> trimesh.Trimesh:
        """All parts as one mesh (each part is closed, so the union of shells is watertight)."""
        mesh = trimesh.util.concatenate([p.mesh for p in self.parts])
        return mesh

    @property
    def bounds(self) -> np.ndarray:
        return self.mesh().bounds

    @property
    def size(self) -> np.ndarray:
        lo, hi = self.bounds
        return hi - lo


def _box(size, center) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=size, transform=trimesh.transformations.translation_matrix(center))


def _cylinder(radius, height, center, sections: int = 16) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    m.apply_translation(center)
    return m


def _rng_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.round(rng.uniform(lo, hi), 4))


# ------------------------------------------------------------------------------------------
# Families. Each takes an rng and returns (params, parts, joints).

Family = Callable[[np.random.Generator], tuple[dict[str, Any], list[ModelPart], list[Joint]]]


def four_leg_chair(rng: np.random.Generator) -> tuple[dict[str, Any], list[ModelPart], list[Joint]]:
    p = {
        "seat_width": _rng_uniform(rng, 0.40, 0.50),
        "seat_depth": _rng_uniform(rng, 0.40, 0.48),
        "seat_height": _rng_uniform(rng, 0.42, 0.48),
        "seat_thickness": _rng_uniform(rng, 0.03, 0.06),
        "back_height": _rng_uniform(rng, 0.35, 0.50),
        "leg_width": _rng_uniform(rng, 0.03, 0.045),
    }
    wood = tuple(np.round(rng.uniform([0.35, 0.2, 0.1], [0.65, 0.45, 0.25]), 3))
    fabric = tuple(np.round(rng.uniform(0.1, 0.8, 3), 3))
    w, d, h, t, lw = p["seat_width"], p["seat_depth"], p["seat_height"], p["seat_thickness"], p["leg_width"]
    leg_h = h - t
    parts = []
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        center = (sx * (w / 2 - lw / 2), sy * (d / 2 - lw / 2), leg_h / 2)
        parts.append(ModelPart(f"leg_{i}", _box((lw, lw, leg_h), center), wood, "leg"))
    parts.append(ModelPart("seat", _box((w, d, t), (0, 0, h - t / 2)), fabric, "seat"))
    bt = 0.03
    parts.append(
        ModelPart("back", _box((w, bt, p["back_height"]), (0, d / 2 - bt / 2, h + p["back_height"] / 2)), fabric, "back")
    )
    return p, parts, []


def stool(rng: np.random.Generator) -> tuple[dict[str, Any], list[ModelPart], list[Joint]]:
    p = {"radius": _rng_uniform(rng, 0.15, 0.2), "height": _rng_uniform(rng, 0.45, 0.7), "leg_radius": 0.015}
    metal = (0.6, 0.6, 0.62)
    top = tuple(np.round(rng.uniform(0.1, 0.8, 3), 3))
    r, h = p["radius"], p["height"]
    parts = [ModelPart("seat", _cylinder(r, 0.04, (0, 0, h - 0.02)), top, "seat")]
    for i in range(3):
        a = 2 * np.pi * i / 3
        c = (0.75 * r * np.cos(a), 0.75 * r * np.sin(a), (h - 0.04) / 2)
        parts.append(ModelPart(f"leg_{i}", _cylinder(p["leg_radius"], h - 0.04, c, 8), metal, "leg"))
    return p, parts, []


def rectangular_table(rng: np.random.Generator) -> tuple[dict[str, Any], list[ModelPart], list[Joint]]:
    p = {
        "length": _rng_uniform(rng, 1.2, 1.8),
        "width": _rng_uniform(rng, 0.7, 0.9),
        "height": _rng_uniform(rng, 0.72, 0.76),
        "top_thickness": _rng_uniform(rng, 0.025, 0.04),
        "leg_width": _rng_uniform(rng, 0.04, 0.06),
    }
    top_c = tuple(np.round(rng.uniform([0.5, 0.35, 0.2], [0.9, 0.7, 0.5]), 3))
    leg_c = tuple(np.round(rng.uniform(0.2, 0.5, 3), 3))
    L, W, H, t, lw = p["length"], p["width"], p["height"], p["top_thickness"], p["leg_width"]
    inset = 0.05
    parts = [ModelPart("top", _box((L, W, t), (0, 0, H - t / 2)), top_c, "top")]
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        c = (sx * (L / 2 - inset - lw / 2), sy * (W / 2 - inset - lw / 2), (H - t) / 2)
        parts.append(ModelPart(f"leg_{i}", _box((lw, lw, H - t), c), leg_c, "leg"))
    return p, parts, []


def box(rng: np.random.Generator) -> tuple[dict[str, Any], list[ModelPart], list[Joint]]:
    p = {
        "length": _rng_uniform(rng, 0.15, 0.4),
        "width": _rng_uniform(rng, 0.12, 0.3),
        "height": _rng_uniform(rng, 0.08, 0.25),
    }
    color = tuple(np.round(rng.uniform([0.5, 0.3, 0.1], [0.85, 0.6, 0.35]), 3))
    parts = [ModelPart("body", _box((p["length"], p["width"], p["height"]), (0, 0, p["height"] / 2)), color, "body")]
    return p, parts, []


#: family name -> (class name, generator). Issue "Synthetic worlds" grows this table.
FAMILIES: dict[str, tuple[str, Family]] = {
    "four_leg_chair": ("chair", four_leg_chair),
    "stool": ("chair", stool),
    "rectangular_table": ("table", rectangular_table),
    "box": ("box", box),
}


def make_model(family: str, seed: int, index: int = 0) -> Model:
    """Sample one model of ``family`` deterministically from ``seed`` and ``index``."""
    if family not in FAMILIES:
        raise KeyError(f"unknown model family {family!r}; families are {sorted(FAMILIES)}")
    class_name, fn = FAMILIES[family]
    rng = np.random.default_rng([seed, index, sum(map(ord, family))])
    params, parts, joints = fn(rng)
    return Model(f"{family}_{seed:04d}_{index:03d}", class_name, family, params, parts, joints)
