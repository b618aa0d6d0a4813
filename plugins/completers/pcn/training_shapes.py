"""Training-only shape families of the ``pcn`` completer.

None of these is registered in :data:`stratamap.core.synthetic.models.FAMILIES`, so no generated
scene (benchmark or demo) can draw them: every family the benchmarks use stays out of training
(leave families out). Each family uses the model :class:`~stratamap.core.synthetic.models.Builder`
and the canonical frame of the generated models (+z up, front along -y, origin at the bottom centre).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from stratamap.core.geometry.transforms import make_pose
from stratamap.core.lazy import lazy_module
from stratamap.core.synthetic.models import DARK, METAL, ROOT_LINK, WOOD_HI, WOOD_LO, Builder, Model, ModelPart

trimesh = lazy_module("trimesh")


def _legs(b: Builder, w: float, d: float, h: float, lw: float, albedo, inset: float = 0.0, prefix: str = "leg") -> None:
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        center = (sx * (w / 2 - inset - lw / 2), sy * (d / 2 - inset - lw / 2), h / 2)
        b.box(f"{prefix}_{i}", (lw, lw, h), center, albedo, "leg")


# ------------------------------------------------------------------------------------------ chairs


def ladder_back_chair(b: Builder) -> None:
    """Four legs, the back legs rising into posts joined by horizontal slats."""
    w, d = b.u("seat_width", 0.42, 0.52), b.u("seat_depth", 0.40, 0.50)
    h, bh = b.u("seat_height", 0.43, 0.50), b.u("back_height", 0.45, 0.65)
    slats = b.integer("slats", 2, 4)
    lw = b.u("leg_width", 0.03, 0.05)
    wood = b.color(WOOD_LO, WOOD_HI)
    for i, sx in enumerate((-1, 1)):
        b.box(f"front_leg_{i}", (lw, lw, h - 0.03), (sx * (w / 2 - lw / 2), -d / 2 + lw / 2, (h - 0.03) / 2), wood)
        b.box(f"back_post_{i}", (lw, lw, h + bh), (sx * (w / 2 - lw / 2), d / 2 - lw / 2, (h + bh) / 2), wood)
    b.box("seat", (w, d, 0.03), (0, 0, h - 0.015), wood, "seat")
    for k in range(slats):
        z = h + bh * (k + 1) / (slats + 1)
        b.box(f"slat_{k}", (w - 2 * lw, 0.02, 0.05), (0, d / 2 - lw / 2, z), wood, "back")
    b.box("stretcher", (w - 2 * lw, 0.02, 0.02), (0, 0, 0.15), wood, "leg")


def cantilever_chair(b: Builder) -> None:
    """Tubular frame: floor runners, front uprights and a seat that hangs free at the back."""
    w, d = b.u("seat_width", 0.44, 0.52), b.u("seat_depth", 0.42, 0.50)
    h, bh = b.u("seat_height", 0.44, 0.48), b.u("back_height", 0.35, 0.50)
    r = 0.012
    shell = b.color()
    for i, sx in enumerate((-1, 1)):
        x = sx * (w / 2 - 0.02)
        b.cylinder(f"runner_{i}", r, d + 0.05, (x, 0.0, r), METAL, "base", axis="y", sections=10)
        b.cylinder(f"upright_{i}", r, h - 0.03, (x, -d / 2 - 0.02, (h - 0.03) / 2), METAL, "base", sections=10)
        b.cylinder(f"back_tube_{i}", r, bh, (x, d / 2, h + bh / 2), METAL, "back", sections=10)
    b.box("seat", (w, d, 0.05), (0, 0, h - 0.025), shell, "seat")
    b.box("back", (w, 0.04, bh * 0.7), (0, d / 2 + 0.01, h + bh * 0.6), shell, "back")


def bar_chair(b: Builder) -> None:
    """Tall chair: four splayed-looking legs, a foot ring of bars and a low back."""
    w = b.u("seat_width", 0.38, 0.46)
    h, bh = b.u("seat_height", 0.62, 0.80), b.u("back_height", 0.15, 0.35)
    c = b.color()
    _legs(b, w, w, h - 0.04, 0.03, METAL)
    b.box("seat", (w + 0.02, w + 0.02, 0.04), (0, 0, h - 0.02), c, "seat")
    fz = b.u("foot_height", 0.22, 0.32)
    for k, (sx, sy) in enumerate([(0, -1), (0, 1), (-1, 0), (1, 0)]):
        size = (w, 0.02, 0.02) if sx == 0 else (0.02, w, 0.02)
        b.box(f"foot_bar_{k}", size, (sx * (w / 2 - 0.015), sy * (w / 2 - 0.015), fz), METAL, "leg")
    b.box("back", (w, 0.03, bh), (0, w / 2 - 0.015, h + bh / 2), c, "back")


# ------------------------------------------------------------------------------------------ tables and desks


def pedestal_table(b: Builder) -> None:
    """A rectangular top on one central column with a cross-shaped foot."""
    L, W, H = b.u("length", 0.9, 1.6), b.u("width", 0.6, 0.95), b.u("height", 0.70, 0.78)
    c = b.color(WOOD_LO, WOOD_HI)
    b.box("top", (L, W, 0.035), (0, 0, H - 0.0175), c, "top")
    b.box("column", (0.12, 0.12, H - 0.08), (0, 0, 0.045 + (H - 0.08) / 2), DARK, "leg")
    b.box("foot_x", (L * 0.6, 0.08, 0.05), (0, 0, 0.025), DARK, "leg")
    b.box("foot_y", (0.08, W * 0.7, 0.05), (0, 0, 0.025), DARK, "leg")
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def trestle_table(b: Builder) -> None:
    """A long top on two end trestles (post, foot and head rail) joined by a stretcher."""
    L, W, H = b.u("length", 1.4, 2.4), b.u("width", 0.7, 1.0), b.u("height", 0.72, 0.77)
    c = b.color(WOOD_LO, WOOD_HI)
    t = 0.04
    b.box("top", (L, W, t), (0, 0, H - t / 2), c, "top")
    for k, sx in enumerate((-1, 1)):
        x = sx * (L / 2 - 0.25)
        b.box(f"trestle_post_{k}", (0.08, 0.1, H - t - 0.1), (x, 0, 0.06 + (H - t - 0.1) / 2), c, "leg")
        b.box(f"trestle_foot_{k}", (0.09, W * 0.85, 0.06), (x, 0, 0.03), c, "leg")
        b.box(f"trestle_head_{k}", (0.08, W * 0.8, 0.05), (x, 0, H - t - 0.025), c, "leg")
    b.box("stretcher", (L - 0.5, 0.05, 0.08), (0, 0, 0.3), c, "leg")
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def standing_desk(b: Builder) -> None:
    """A top on two T-shaped steel frames (column and foot bar), with a cross beam."""
    L, W, H = b.u("length", 1.2, 1.8), b.u("width", 0.6, 0.8), b.u("height", 0.70, 1.10)
    c = b.color()
    b.box("top", (L, W, 0.025), (0, 0, H - 0.0125), c, "top")
    for k, sx in enumerate((-1, 1)):
        x = sx * (L / 2 - 0.12)
        b.box(f"column_{k}", (0.07, 0.07, H - 0.05), (x, 0, 0.025 + (H - 0.05) / 2), METAL, "leg")
        b.box(f"foot_{k}", (0.07, W * 0.9, 0.04), (x, 0, 0.02), METAL, "leg")
    b.box("beam", (L - 0.3, 0.05, 0.06), (0, 0.05, H - 0.06), METAL, "leg")
    b.surface(-L / 2, -W / 2, L / 2, W / 2, H)


def hutch_desk(b: Builder) -> None:
    """A desk on four legs with a shelf hutch standing on the back of its top."""
    L, W, H = b.u("length", 1.0, 1.5), b.u("width", 0.5, 0.7), b.u("height", 0.72, 0.76)
    hh = b.u("hutch_height", 0.3, 0.6)
    c = b.color(WOOD_LO, WOOD_HI)
    _legs(b, L, W, H - 0.03, 0.045, c)
    b.box("top", (L, W, 0.03), (0, 0, H - 0.015), c, "top")
    hd = 0.25
    y = W / 2 - hd / 2
    for k, sx in enumerate((-1, 1)):
        b.box(f"hutch_side_{k}", (0.02, hd, hh), (sx * (L / 2 - 0.01), y, H + hh / 2), c, "panel")
    b.box("hutch_top", (L, hd, 0.02), (0, y, H + hh - 0.01), c, "shelf")
    b.box("hutch_shelf", (L - 0.04, hd, 0.02), (0, y, H + hh / 2), c, "shelf")
    b.box("hutch_back", (L - 0.04, 0.01, hh), (0, W / 2 - 0.005, H + hh / 2), c, "panel")
    b.surface(-L / 2, -W / 2, L / 2, W / 2 - hd, H)


# ------------------------------------------------------------------------------------------ storage


def sideboard(b: Builder) -> None:
    """A long low closed body on four tall legs, its front split into flat doors."""
    w, d, h = b.u("width", 1.2, 2.0), b.u("depth", 0.4, 0.5), b.u("height", 0.6, 0.9)
    lh = b.u("leg_height", 0.12, 0.25)
    c = b.color(WOOD_LO, WOOD_HI)
    _legs(b, w - 0.06, d - 0.06, lh, 0.04, DARK)
    b.box("body", (w, d, h - lh), (0, 0, lh + (h - lh) / 2), c, "panel")
    doors = b.integer("doors", 2, 4)
    for k in range(doors):
        x = -w / 2 + w * (k + 0.5) / doors
        b.box(f"door_{k}", (w / doors - 0.01, 0.015, h - lh - 0.04), (x, -d / 2 - 0.0075, lh + (h - lh) / 2), c, "door")
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def locker(b: Builder) -> None:
    """A tall narrow steel locker (one to three columns) with a sloped-free flat top and a plinth."""
    cols = b.integer("columns", 1, 3)
    cw, d, h = b.u("column_width", 0.3, 0.45), b.u("depth", 0.4, 0.55), b.u("height", 1.6, 1.95)
    c = b.color((0.3, 0.3, 0.35), (0.7, 0.7, 0.75))
    w = cols * cw
    b.box("plinth", (w - 0.04, d - 0.04, 0.08), (0, 0, 0.04), DARK, "panel")
    b.box("body", (w, d, h - 0.08), (0, 0, 0.08 + (h - 0.08) / 2), c, "panel")
    for k in range(cols):
        x = -w / 2 + cw * (k + 0.5)
        b.box(f"handle_{k}", (0.02, 0.03, 0.12), (x + cw / 2 - 0.05, -d / 2 - 0.015, h * 0.55), METAL, "handle")
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


def ladder_shelf(b: Builder) -> None:
    """Two leaning side rails and boards that get shallower towards the top."""
    w, d, h = b.u("width", 0.5, 0.9), b.u("depth", 0.35, 0.5), b.u("height", 1.4, 1.9)
    n = b.integer("boards", 3, 5)
    c = b.color(WOOD_LO, WOOD_HI)
    for k, sx in enumerate((-1, 1)):
        rail = trimesh.creation.box(extents=(0.03, 0.04, float(np.hypot(h, d - 0.1))))
        tilt = float(np.arctan2(d - 0.1, h))
        pose = make_pose((sx * (w / 2 - 0.015), 0.0, h / 2)) @ trimesh.transformations.rotation_matrix(tilt, [1, 0, 0])
        rail.apply_transform(pose)
        b.parts.append(ModelPart(f"rail_{k}", rail, c, "panel"))
    for k in range(n):
        z = 0.15 + (h - 0.3) * k / max(n - 1, 1)
        depth = (d - 0.05) * (1 - z / h) + 0.08
        y = (d - 0.1) / 2 - (d - 0.1) * (1 - z / h) + depth / 2 - 0.04
        b.box(f"board_{k}", (w - 0.06, depth, 0.02), (0, y, z), c, "shelf")


def cube_shelf(b: Builder) -> None:
    """A grid of open cubbies (2-4 columns, 1-4 rows), no back panel."""
    cols, rows = b.integer("columns", 2, 4), b.integer("rows", 1, 4)
    cell, d = b.u("cell", 0.3, 0.38), b.u("depth", 0.3, 0.4)
    c = b.color()
    t = 0.02
    w, h = cols * cell + t, rows * cell + t
    for k in range(cols + 1):
        b.box(f"upright_{k}", (t, d, h), (-w / 2 + t / 2 + k * cell, 0, h / 2), c, "panel")
    for k in range(rows + 1):
        b.box(f"board_{k}", (w, d, t), (0, 0, t / 2 + k * cell), c, "shelf")
    b.surface(-w / 2, -d / 2, w / 2, d / 2, h)


# ------------------------------------------------------------------------------------------ seating


def daybed(b: Builder) -> None:
    """A long mattress on a low frame with a back rail and two end boards."""
    L, d = b.u("length", 1.8, 2.1), b.u("depth", 0.8, 1.0)
    fh, eh = b.u("frame_height", 0.3, 0.4), b.u("end_height", 0.7, 0.95)
    c, fabric = b.color(WOOD_LO, WOOD_HI), b.color()
    b.box("frame", (L, d, fh), (0, 0, fh / 2), c, "base")
    b.box("mattress", (L - 0.08, d - 0.05, 0.15), (0, 0, fh + 0.075), fabric, "seat")
    for k, sx in enumerate((-1, 1)):
        b.box(f"end_{k}", (0.05, d, eh), (sx * (L / 2 + 0.025), 0, eh / 2), c, "arm")
    b.box("back_rail", (L, 0.05, eh - 0.1), (0, d / 2 + 0.025, (eh - 0.1) / 2), c, "back")


def slim_loveseat(b: Builder) -> None:
    """A two-seater on tall thin legs with a thin back and slim arms."""
    w, d = b.u("width", 1.2, 1.6), b.u("depth", 0.7, 0.85)
    lh, sh, bh = b.u("leg_height", 0.12, 0.22), b.u("seat_height", 0.42, 0.48), b.u("back_height", 0.75, 0.9)
    fabric = b.color()
    _legs(b, w - 0.05, d - 0.05, lh, 0.035, DARK)
    b.box("base", (w, d, sh - lh), (0, 0, lh + (sh - lh) / 2), fabric, "seat")
    b.box("back", (w, 0.1, bh - sh), (0, d / 2 - 0.05, sh + (bh - sh) / 2), fabric, "back")
    for k, sx in enumerate((-1, 1)):
        b.box(f"arm_{k}", (0.08, d - 0.1, 0.2), (sx * (w / 2 - 0.04), -0.05, sh + 0.1), fabric, "arm")


def storage_bench(b: Builder) -> None:
    """A closed box bench with a cushion on its lid."""
    L, d, h = b.u("length", 0.8, 1.4), b.u("depth", 0.35, 0.5), b.u("height", 0.4, 0.48)
    c, fabric = b.color(WOOD_LO, WOOD_HI), b.color()
    b.box("box", (L, d, h - 0.05), (0, 0, (h - 0.05) / 2), c, "base")
    b.box("cushion", (L - 0.02, d - 0.02, 0.05), (0, 0, h - 0.025), fabric, "seat")


def picnic_bench(b: Builder) -> None:
    """Plank seat on two A-frames (two slanted legs each) with a lower stretcher."""
    L, d, h = b.u("length", 1.0, 1.8), b.u("depth", 0.25, 0.35), b.u("height", 0.42, 0.47)
    c = b.color(WOOD_LO, WOOD_HI)
    b.box("seat", (L, d, 0.04), (0, 0, h - 0.02), c, "seat")
    spread = d * 0.9
    for k, sx in enumerate((-1, 1)):
        for j, sy in enumerate((-1, 1)):
            leg = trimesh.creation.box(extents=(0.04, 0.04, float(np.hypot(h - 0.04, spread / 2))))
            tilt = float(np.arctan2(spread / 2, h - 0.04)) * sy
            pose = make_pose((sx * (L / 2 - 0.15), sy * spread / 4, (h - 0.04) / 2))
            leg.apply_transform(pose @ trimesh.transformations.rotation_matrix(-tilt, [1, 0, 0]))
            b.parts.append(ModelPart(f"leg_{k}_{j}", leg, c, "leg"))
    b.box("stretcher", (L - 0.3, 0.04, 0.04), (0, 0, 0.15), c, "leg")


# ------------------------------------------------------------------------------------------ counters


def kitchen_island(b: Builder) -> None:
    """A free-standing block with a worktop overhanging one long side (seating side)."""
    w, d, h = b.u("width", 1.2, 2.2), b.u("depth", 0.6, 0.9), b.u("height", 0.88, 0.94)
    over = b.u("overhang", 0.2, 0.35)
    body, top = b.color(), b.color((0.6, 0.6, 0.6), (0.95, 0.95, 0.95))
    b.box("plinth", (w - 0.1, d - 0.1, 0.1), (0, -over / 2, 0.05), DARK, "panel")
    b.box("body", (w, d, h - 0.14), (0, -over / 2, 0.1 + (h - 0.14) / 2), body, "panel")
    b.box("worktop", (w + 0.04, d + over, 0.04), (0, 0, h - 0.02), top, "top")
    b.surface(-w / 2, -(d + over) / 2, w / 2, (d + over) / 2, h)


def bar_counter(b: Builder) -> None:
    """A counter with a raised bar shelf along its back edge."""
    w, d, h = b.u("width", 1.0, 2.0), b.u("depth", 0.5, 0.65), b.u("height", 0.88, 0.94)
    bar = b.u("bar_height", 0.15, 0.25)
    body, top = b.color(), b.color()
    b.box("body", (w, d, h - 0.04), (0, 0, (h - 0.04) / 2), body, "panel")
    b.box("worktop", (w, d + 0.02, 0.04), (0, -0.01, h - 0.02), top, "top")
    b.box("bar_riser", (w, 0.08, bar), (0, d / 2 - 0.04, h + bar / 2), body, "panel")
    b.box("bar_top", (w + 0.04, 0.3, 0.03), (0, d / 2 - 0.04, h + bar + 0.015), top, "top")
    b.surface(-w / 2, -d / 2, w / 2, d / 2 - 0.08, h)


# ------------------------------------------------------------------------------------------ class-agnostic


def primitive_stack(b: Builder) -> None:
    """Two to four boxes and cylinders stacked and side by side: small-object shape variety for the
    class-agnostic ``other`` slot (appliances, screens, cups and plants are never drawn)."""
    n = b.integer("pieces", 2, 4)
    scale = b.u("scale", 0.08, 0.6)
    z = 0.0
    for k in range(n):
        kind = b.choice(f"kind_{k}", ["box", "cylinder"])
        sx, sy, sz = (scale * b.u(f"s{k}{a}", 0.3, 1.0) for a in "xyz")
        x, y = scale * b.u(f"x{k}", -0.3, 0.3), scale * b.u(f"y{k}", -0.3, 0.3)
        if kind == "box":
            b.box(f"piece_{k}", (sx, sy, sz), (x, y, z + sz / 2), b.color(), "body")
        else:
            b.cylinder(f"piece_{k}", min(sx, sy) / 2, sz, (x, y, z + sz / 2), b.color(), "body", sections=16)
        z += sz * b.u(f"stack_{k}", 0.0, 1.0)


#: family -> (class it teaches, generator). Never part of ``core.synthetic.models.FAMILIES``.
TRAINING_FAMILIES: dict[str, tuple[str, Callable[[Builder], None]]] = {
    "ladder_back_chair": ("chair", ladder_back_chair),
    "cantilever_chair": ("chair", cantilever_chair),
    "bar_chair": ("chair", bar_chair),
    "pedestal_table": ("table", pedestal_table),
    "trestle_table": ("table", trestle_table),
    "standing_desk": ("desk", standing_desk),
    "hutch_desk": ("desk", hutch_desk),
    "sideboard": ("cabinet", sideboard),
    "locker": ("cabinet", locker),
    "ladder_shelf": ("shelf", ladder_shelf),
    "cube_shelf": ("shelf", cube_shelf),
    "daybed": ("sofa", daybed),
    "slim_loveseat": ("sofa", slim_loveseat),
    "storage_bench": ("bench", storage_bench),
    "picnic_bench": ("bench", picnic_bench),
    "kitchen_island": ("counter", kitchen_island),
    "bar_counter": ("counter", bar_counter),
    "primitive_stack": ("other", primitive_stack),
}


def make_training_model(family: str, seed: int, index: int = 0) -> Model:
    """One model of a training family, deterministic in (family, seed, index), in the canonical frame."""
    if family not in TRAINING_FAMILIES:
        raise KeyError(f"unknown training family {family!r}; families are {sorted(TRAINING_FAMILIES)}")
    class_name, fn = TRAINING_FAMILIES[family]
    b = Builder(np.random.default_rng([seed, index, sum(map(ord, family)), 32]))
    fn(b)
    lo = np.min([p.mesh.bounds[0] for p in b.parts], 0)
    hi = np.max([p.mesh.bounds[1] for p in b.parts], 0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    for p in b.parts:
        p.mesh.apply_translation(shift)
        p.link = ROOT_LINK
    return Model(f"{family}_{seed:04d}_{index:03d}", class_name, family, b.params, b.parts)
