"""Start a simulated scene at rest: where each free body goes, and which ones cannot be free.

A simulator collides the convex parts of every mesh (:func:`~stratamap.core.simulation.physics.collision_parts`).
A free body that starts above its support falls, one that starts inside a neighbour is pushed
out (violently, with stiff contacts), and one whose centre of mass is not over what it stands on
tips over. :func:`rest_offsets` plans, for every object of the movable classes, parents first
along the contact graph:

1. drop (or lift) it onto the highest surface under its lowest points, among the static objects,
   the room's slabs and the free bodies already placed, leaving :data:`REST_GAP` of air;
2. if its convex parts still penetrate a neighbour beyond contact, nudge it up by a few
   millimetres, else sideways by up to :data:`MAX_NUDGE`;
3. if it still penetrates, or its centre of mass is not over the convex hull of its contact
   points, it stays where it is and is exported static (with the reason).

Everything is deterministic geometry (no simulation), so the URDF, SDF and MJCF exporters get the
same plan.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstances
from stratamap.core.simulation.physics import (
    Shell,
    collision_parts,
    convex_shell,
    shifted_penetration,
    support_order,
    world_mesh,
)

spatial = lazy_module("scipy.spatial")
trimesh = lazy_module("trimesh")

#: Air left under a free body (metres): it starts just above its support and settles onto it.
REST_GAP = 0.001
#: How far a free body may be moved up, then sideways, out of a neighbour (metres).
MAX_LIFT = 0.006
MAX_NUDGE = 0.03
#: How far below its lowest point a support is looked for, and how far above (metres).
SUPPORT_BELOW = 1.0
SUPPORT_ABOVE = 0.15
#: The centre of mass must lie this far inside the hull of the contact points (metres).
STABILITY_MARGIN = 0.005


@dataclass
class RestPlan:
    """Per free body a world translation; the objects of movable classes kept static, with why."""

    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    static: dict[int, str] = field(default_factory=dict)

    def free_ids(self, instances: ObjectInstances, movable: Iterable[str]) -> set[int]:
        classes = set(movable)
        return {inst.id for inst in instances if inst.class_name in classes and inst.id not in self.static}

    def to_dict(self) -> dict:
        moved = {k: float(np.linalg.norm(v)) for k, v in self.offsets.items()}
        return {
            "free_bodies": len(self.offsets),
            "max_offset_m": round(max(moved.values(), default=0.0), 4),
            "static": {str(k): v for k, v in sorted(self.static.items())},
        }


def _shells(mesh) -> list[Shell]:
    shells = [convex_shell(np.asarray(p.vertices)) for p in collision_parts(mesh)]
    return [s for s in shells if s is not None]


def _slab_shell(box) -> Shell | None:
    return convex_shell(np.asarray(trimesh.creation.box(extents=box.size, transform=box.pose).vertices))


def _footprint(mine: list[Shell], spacing: float = 0.01, most: int = 400) -> tuple[np.ndarray, float]:
    """Points on the object's lowest face (a grid inside the hull of its lowest vertices, with the
    vertices themselves) and the object's lowest height."""
    verts = np.concatenate([s.vertices for s in mine])
    bottom = float(verts[:, 2].min())
    feet = verts[verts[:, 2] <= bottom + 0.01, :2]
    lo, hi = feet.min(0), feet.max(0)
    step = max(spacing, float(np.sqrt(np.prod(np.maximum(hi - lo, 1e-6)) / most)))
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1e-9, step), np.arange(lo[1], hi[1] + 1e-9, step))
    grid = np.c_[gx.ravel(), gy.ravel()]
    try:
        hull = spatial.ConvexHull(feet)
        grid = grid[(grid @ hull.equations[:, :2].T + hull.equations[:, 2]).max(axis=1) <= 1e-9]
    except (spatial.QhullError, ValueError):  # a line or a point of contact: its vertices only
        grid = grid[:0]
    return np.concatenate([feet, grid]), bottom


def _tops(feet: np.ndarray, bottom: float, others: list[Shell]) -> np.ndarray:
    """Per footprint point, the highest surface of ``others`` under it (no higher than a little
    above the object's bottom); -inf where there is none."""
    best = np.full(len(feet), -np.inf)
    for o in others:
        if o.hi[2] < bottom - SUPPORT_BELOW or o.lo[2] > bottom + SUPPORT_ABOVE:
            continue
        if np.any(o.lo[:2] > feet.max(0)) or np.any(o.hi[:2] < feet.min(0)):
            continue
        tops = o.top_at(feet)
        ok = np.isfinite(tops) & (tops <= bottom + SUPPORT_ABOVE)
        best[ok] = np.maximum(best[ok], tops[ok])
    return best


def _stable(feet: np.ndarray, tops: np.ndarray, surface: float, center: np.ndarray) -> bool:
    """Whether the centre of mass is over the hull of the footprint points that the surface holds up."""
    contact = feet[tops >= surface - 0.005]
    if len(contact) < 3:
        return False
    try:
        hull = spatial.ConvexHull(contact)
    except (spatial.QhullError, ValueError):
        return False
    inside = hull.equations[:, :2] @ center[:2] + hull.equations[:, 2]
    return bool(inside.max() <= -STABILITY_MARGIN)


def rest_offsets(
    instances: ObjectInstances,
    graph: ContactGraph | None,
    movable: Iterable[str],
    statics: list | None = None,
) -> RestPlan:
    """Plan where each object of a ``movable`` class starts so that it rests (see the module doc)."""
    from stratamap.core.simulation.kinematics import inertial_of

    movable = set(movable)
    plan = RestPlan()
    meshes = {inst.id: world_mesh(inst) for inst in instances}
    shells = {inst.id: _shells(mesh) for inst, mesh in zip(instances, meshes.values(), strict=True)}
    slabs: list[Shell] = [s for b in statics or [] if (s := _slab_shell(b)) is not None]
    fixed = list(slabs)
    for inst in instances:
        if inst.class_name not in movable:
            fixed.extend(shells[inst.id])
    placed: list[Shell] = []
    lifts = np.arange(1, int(round(MAX_LIFT / 0.002)) + 1)[:, None] * np.array([[0.0, 0.0, 0.002]])
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(8)], axis=1)
    radii = np.arange(1, int(round(MAX_NUDGE / 0.005)) + 1) * 0.005
    sideways = (radii[:, None, None] * ring[None]).reshape(-1, 3)
    for inst in support_order(instances, graph):
        if inst.class_name not in movable:
            continue
        mine = shells[inst.id]
        if not mine:
            plan.static[inst.id] = "no collision geometry"
            continue
        others = fixed + placed
        feet, bottom = _footprint(mine)
        # The supporter the contact graph names holds the object up; any other surface is a neighbour.
        parent = graph.parent(inst.id) if graph is not None and inst.id in graph.support else None
        supporters = shells.get(int(parent), []) if isinstance(parent, (int, np.integer)) else slabs
        if isinstance(parent, (int, np.integer)) and int(parent) in plan.offsets:  # a free body placed before
            supporters = [s.translated(plan.offsets[int(parent)]) for s in supporters]
        tops = _tops(feet, bottom, supporters)
        if not np.isfinite(tops).any():
            tops = _tops(feet, bottom, others)
        if not np.isfinite(tops).any():
            plan.static[inst.id] = "nothing under it to rest on"
            fixed.extend(mine)
            continue
        surface = float(tops.max())
        offset = np.array([0.0, 0.0, surface + REST_GAP - bottom])
        depth = float(shifted_penetration(mine, others, offset[None], deepest=True)[0])
        if depth > 0:
            candidates = np.concatenate([offset + lifts, offset + sideways])
            depths = shifted_penetration(mine, others, candidates, deepest=True)
            free = np.flatnonzero(depths <= 0)
            if len(free):
                offset, depth = candidates[free[0]], 0.0
        if depth > 0:
            plan.static[inst.id] = f"its convex parts penetrate a neighbour by {depth * 1000:.0f} mm"
        elif not _stable(feet, tops, surface, inertial_of(meshes[inst.id], 1.0).center):
            plan.static[inst.id] = "its centre of mass is not over what it stands on"
        if inst.id in plan.static:
            fixed.extend(mine)
            continue
        plan.offsets[inst.id] = offset
        placed.extend(s.translated(offset) for s in mine)
    return plan
