"""Physical plausibility of a completed scene: supports, interpenetration, settling.

Completed models are rigid unions of convex shells (a chair's legs, seat and back), which is also
how simulators collide them (MuJoCo and PyBullet take the convex hull of each mesh geom). Every
test here works on those same convex shells, as half-space sets ``A x + b <= 0``:

* :func:`resolve_scene` is the min-conflict physical check of the functional-scenes paper: completed
  objects are visited parents first along the contact graph (uncompleted ones are observations:
  obstacles that never move); each is dropped (or lifted) onto the top
  surface of its supporter, then, if it overlaps an object placed before it, moved to the nearest
  horizontal offset without conflict (or with the least penetration if none is free within reach).
  A moved object carries what it supports along.
* :func:`min_conflict` chooses one of each object's placements (a completer's candidates) so that
  no two chosen meshes interpenetrate, independently of object ids; the completers and the physical
  check share it.
* :func:`penetration_volume` is the exact overlap volume of the scene's shells, pair by pair.
* :func:`settle` drops the exported MJCF into MuJoCo and reports how far free bodies move.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstance, ObjectInstances

optimize = lazy_module("scipy.optimize")
spatial = lazy_module("scipy.spatial")

trimesh = lazy_module("trimesh")

#: Overlap depth below this is contact, not penetration (metres).
CONTACT_TOLERANCE = 0.003


@dataclass
class Shell:
    """A convex shell in world coordinates."""

    vertices: np.ndarray  # (V, 3)
    equations: np.ndarray  # (F, 4): outward unit normals and offsets, inside where n.x + d <= 0
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.lo = self.vertices.min(axis=0)
        self.hi = self.vertices.max(axis=0)

    def translated(self, t: np.ndarray) -> Shell:
        eq = self.equations.copy()
        eq[:, 3] -= eq[:, :3] @ t
        return Shell(self.vertices + t, eq)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """How deep each point lies inside the shell (<= 0 outside)."""
        return -(points @ self.equations[:, :3].T + self.equations[:, 3]).max(axis=1)

    def near(self, points: np.ndarray, margin: float, chunk: int = 8) -> np.ndarray:
        """Which points lie inside the shell or less than ``margin`` outside every face plane
        (``depth(points) > -margin``), found ``chunk`` faces at a time: a point is dropped at the
        first face it lies beyond, so far points cost a face or two, not all of them."""
        normals, offsets = self.equations[:, :3], self.equations[:, 3]
        index = np.arange(len(points))
        for start in range(0, len(normals), chunk):
            if not len(index):
                break
            part = slice(start, start + chunk)
            index = index[(points[index] @ normals[part].T + offsets[part]).max(axis=1) < margin]
        keep = np.zeros(len(points), bool)
        keep[index] = True
        return keep

    def top_at(self, xy: np.ndarray) -> np.ndarray:
        """Height of the shell's upper surface above each (x, y); NaN where the vertical line misses it."""
        n, d = self.equations[:, :3], self.equations[:, 3]
        rhs = -(xy @ n[:, :2].T + d)  # n_z z <= rhs
        up, down, side = n[:, 2] > 1e-6, n[:, 2] < -1e-6, np.abs(n[:, 2]) <= 1e-6
        top = (rhs[:, up] / n[up, 2]).min(axis=1) if up.any() else np.full(len(xy), np.inf)
        bottom = (rhs[:, down] / n[down, 2]).max(axis=1) if down.any() else np.full(len(xy), -np.inf)
        ok = (top >= bottom - 1e-9) & ((rhs[:, side] >= -1e-9).all(axis=1) if side.any() else True)
        return np.where(ok, top, np.nan)


def convex_shell(vertices: np.ndarray) -> Shell | None:
    try:
        hull = spatial.ConvexHull(vertices)
    except (spatial.QhullError, ValueError):
        return None
    return Shell(np.asarray(vertices[hull.vertices], dtype=float), np.asarray(hull.equations, dtype=float))


def world_mesh(inst: ObjectInstance) -> trimesh.Trimesh:
    from stratamap.core.simulation.kinematics import object_mesh

    mesh, pose = object_mesh(inst)
    mesh = mesh.copy()
    mesh.apply_transform(pose)
    return mesh


def mesh_parts(mesh: trimesh.Trimesh, max_parts: int = 64) -> list[trimesh.Trimesh]:
    """The mesh's closed pieces (connected components), largest first, slivers dropped: the
    geoms a simulator gets, since it collides the convex hull of each."""
    parts = [p for p in mesh.split(only_watertight=False) if len(p.faces) >= 4 and p.extents.max() > 1e-3] or [mesh]
    parts.sort(key=lambda p: -p.area)
    return parts[:max_parts]


#: Convex collision parts thinner than this (metres) are replaced by a box this thick: simulators
#: cannot take the hull of a flat piece (MuJoCo: "coplanar vertices, cannot compute convex hull").
MIN_PART_THICKNESS = 0.004


#: Recent collision_parts results by mesh content (the three exporters and the rest plan ask for
#: the same meshes' parts).
_PARTS_CACHE: dict[tuple, list] = {}
_PARTS_CACHE_SIZE = 512


def collision_parts(mesh: trimesh.Trimesh, max_parts: int = 64) -> list[trimesh.Trimesh]:
    """Convex collision geometry of a mesh: the convex hull of each closed piece (what simulators
    collide anyway), a flat or degenerate piece replaced by its oriented bounding box thickened to
    :data:`MIN_PART_THICKNESS`; never empty for a mesh with triangles."""
    vertices, faces = np.ascontiguousarray(mesh.vertices, dtype=float), np.ascontiguousarray(mesh.faces)
    key = (hashlib.sha1(vertices.tobytes()).hexdigest(), hashlib.sha1(faces.tobytes()).hexdigest(), max_parts)
    if key not in _PARTS_CACHE:
        if len(_PARTS_CACHE) >= _PARTS_CACHE_SIZE:
            _PARTS_CACHE.pop(next(iter(_PARTS_CACHE)))
        _PARTS_CACHE[key] = _collision_parts(mesh, max_parts)
    return [part.copy() for part in _PARTS_CACHE[key]]


def _collision_parts(mesh: trimesh.Trimesh, max_parts: int) -> list[trimesh.Trimesh]:
    out: list[trimesh.Trimesh] = []
    for part in mesh_parts(mesh, max_parts):
        vertices = np.unique(np.asarray(part.vertices, dtype=float), axis=0)
        try:
            hull = spatial.ConvexHull(vertices)
        except (spatial.QhullError, ValueError):
            hull = None
        if hull is None or hull.volume <= 1e-9 or _thickness(hull) < MIN_PART_THICKNESS:
            out.append(_thick_box(part))
            continue
        # Faces wound outwards (qhull's equations give each facet's outward normal).
        faces = hull.simplices.copy()
        points = hull.points
        normals = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
        flip = np.einsum("ij,ij->i", normals, hull.equations[:, :3]) < 0
        faces[flip] = faces[flip][:, ::-1]
        out.append(trimesh.Trimesh(points, faces, process=True))
    return out


def _thickness(hull) -> float:
    """Smallest width of a convex hull across its facet normals."""
    widths = np.ptp(hull.points[hull.vertices] @ hull.equations[:, :3].T, axis=0)
    return float(widths.min())


def _thick_box(part: trimesh.Trimesh) -> trimesh.Trimesh:
    """The piece's oriented bounding box, every side at least MIN_PART_THICKNESS."""
    vertices = np.asarray(part.vertices, dtype=float)
    try:
        with np.errstate(divide="ignore", invalid="ignore"):  # a flat piece's hull has no volume
            transform, extents = trimesh.bounds.oriented_bounds(vertices)
        frame = np.linalg.inv(transform)
    except Exception:  # a single point or a line: axis-aligned box
        frame = np.eye(4)
        frame[:3, 3] = (vertices.min(0) + vertices.max(0)) / 2
        extents = vertices.max(0) - vertices.min(0)
    return trimesh.creation.box(extents=np.maximum(extents, MIN_PART_THICKNESS), transform=frame)


def mesh_shells(mesh: trimesh.Trimesh, max_shells: int = 64) -> list[Shell]:
    """The mesh's pieces as convex shells (what a simulator collides), largest first."""
    shells = [convex_shell(np.asarray(p.vertices)) for p in mesh_parts(mesh, max_shells)]
    return [s for s in shells if s is not None]


def unique_axes(equations: np.ndarray) -> np.ndarray:
    """Distinct face normals of a hull (triangulated faces repeat them)."""
    n = equations[:, :3] / np.linalg.norm(equations[:, :3], axis=1, keepdims=True)
    _, keep = np.unique(np.round(n, 6), axis=0, return_index=True)
    return n[np.sort(keep)]


def penetration_depths(a: Shell, b: Shell, shifts: np.ndarray) -> np.ndarray:
    """Penetration depth of ``a`` moved by each of ``shifts`` (C, 3) into ``b`` (0 when apart).

    Separating-axis test over both shells' face normals: the depth is the smallest overlap of
    the two projections. Leaving out edge-edge axes can only overstate contact, never miss it.
    """
    axes = np.concatenate([unique_axes(a.equations), unique_axes(b.equations)])
    pa, pb = a.vertices @ axes.T, b.vertices @ axes.T
    offset = shifts @ axes.T  # (C, K)
    overlap = np.minimum(pa.max(axis=0) + offset, pb.max(axis=0)) - np.maximum(pa.min(axis=0) + offset, pb.min(axis=0))
    return np.maximum(overlap.min(axis=1), 0.0)


def shifted_penetration(
    mine: list[Shell], others: list[Shell], shifts: np.ndarray, deepest: bool = False
) -> np.ndarray:
    """Penetration beyond contact between ``mine`` moved by each shift and ``others``: summed over
    shell pairs, or the deepest pair's with ``deepest``."""
    combine = np.maximum if deepest else np.add
    total = np.zeros(len(shifts))
    reach = np.abs(shifts).max(axis=0) if len(shifts) else np.zeros(3)
    for s in mine:
        for o in others:
            if np.any(o.lo > s.hi + reach + CONTACT_TOLERANCE) or np.any(o.hi < s.lo - reach - CONTACT_TOLERANCE):
                continue
            total = combine(total, np.maximum(penetration_depths(s, o, shifts) - CONTACT_TOLERANCE, 0.0))
    return total


def _conflicts(mine: list[Shell], others: list[Shell], shifts: np.ndarray) -> np.ndarray:
    """Summed penetration beyond contact between ``mine`` moved by each shift and ``others``."""
    return shifted_penetration(mine, others, shifts)


@dataclass
class Placement:
    """One way to place an object in the min-conflict search: its convex shells (world frame), what
    choosing it gives up (an alignment error, metres: lower is better), a label ordering equal ones
    (never an object id), and what it stands for (a completer's candidate, a completion)."""

    shells: list[Shell]
    cost: float = 0.0
    label: tuple = ()
    item: Any = None


def shells_penetration(a: list[Shell], b: list[Shell], tolerance: float) -> float:
    """Summed penetration depth (m) beyond ``tolerance`` between two sets of convex shells (the mesh
    pieces a simulator collides): a chair pushed under a table whose meshes do not touch is 0."""
    total = 0.0
    for s in a:
        for o in b:
            if np.any(o.lo > s.hi + tolerance) or np.any(o.hi < s.lo - tolerance):
                continue
            total += max(float(penetration_depths(s, o, np.zeros((1, 3)))[0]) - tolerance, 0.0)
    return total


def min_conflict(options: dict[int, list[Placement]], tolerance: float, iterations: int = 200) -> dict[int, Placement]:
    """One placement per object (each object's first to start) so that no two chosen ones
    interpenetrate (functional-scenes paper, section 4.4). Every step tries every placement of every
    conflicted object and makes the move that removes the most penetration (ties: the least cost
    given up, then the label), until no conflict is left or no move helps. No step looks at object
    ids, so the result is the same whatever ids the objects carry. An object with one placement (an
    observation) is an obstacle that never changes."""
    ids = [i for i, c in options.items() if c]
    choice = {i: options[i][0] for i in ids}
    cache: dict[tuple[int, int], float] = {}

    def pen(a: Placement, b: Placement) -> float:
        key = (id(a), id(b)) if id(a) < id(b) else (id(b), id(a))
        if key not in cache:
            cache[key] = shells_penetration(a.shells, b.shells, tolerance)
        return cache[key]

    def conflict(i: int, cand: Placement) -> float:
        return float(sum(sorted(pen(cand, choice[j]) for j in ids if j != i)))

    for _ in range(iterations):
        best_key, best_move = None, None
        for i in ids:
            now = conflict(i, choice[i])
            if now <= 0.0:
                continue
            for cand in options[i]:
                if cand is choice[i]:
                    continue
                gain = round(now - conflict(i, cand), 9)
                if gain <= 0.0:
                    continue
                key = (-gain, round(cand.cost - choice[i].cost, 9), cand.cost, cand.label)
                if best_key is None or key < best_key:
                    best_key, best_move = key, (i, cand)
        if best_move is None:
            break
        choice[best_move[0]] = best_move[1]
    return choice


def conflicted(choice: dict[int, Placement], tolerance: float) -> list[int]:
    """The objects whose chosen placement still penetrates another's beyond ``tolerance``."""
    ids = sorted(choice)
    return [
        i
        for i in ids
        if any(j != i and shells_penetration(choice[i].shells, choice[j].shells, tolerance) > 0 for j in ids)
    ]


@dataclass
class Resolution:
    """What the physical check changed: per-object translation and the conflict left, if any."""

    shifts: dict[int, list[float]] = field(default_factory=dict)
    residual: dict[int, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        moved = {k: v for k, v in self.shifts.items() if np.linalg.norm(v) > 1e-4}
        return {
            "moved": len(moved),
            "max_shift_m": max((float(np.linalg.norm(v)) for v in moved.values()), default=0.0),
            "unresolved": sorted(k for k, v in self.residual.items() if v > 0),
        }


def support_order(instances: ObjectInstances, graph: ContactGraph | None) -> list[ObjectInstance]:
    """Parents before children; among siblings the larger footprint first."""
    by_id = {inst.id: inst for inst in instances}
    children: dict[Any, list[int]] = {}
    for inst in instances:
        parent = graph.parent(inst.id) if graph is not None and inst.id in graph.support else None
        parent = int(parent) if isinstance(parent, (int, np.integer)) and int(parent) in by_id else None
        children.setdefault(parent, []).append(inst.id)
    order: list[ObjectInstance] = []
    queue = sorted(children.get(None, []), key=lambda i: -float(by_id[i].box.size[0] * by_id[i].box.size[1]))
    seen: set[int] = set()
    while queue:
        i = queue.pop(0)
        if i in seen:
            continue
        seen.add(i)
        order.append(by_id[i])
        queue.extend(sorted(children.get(i, []), key=lambda c: -float(by_id[c].box.size[0] * by_id[c].box.size[1])))
    order.extend(inst for inst in instances if inst.id not in seen)  # cycles: keep everyone
    return order


def translate_instance(inst: ObjectInstance, t: np.ndarray) -> None:
    """Move an object by ``t`` with fresh arrays (copies of a map share poses and boxes)."""
    import dataclasses

    if inst.completion is not None:
        pose = inst.completion.pose.copy()
        pose[:3, 3] += t
        inst.completion = dataclasses.replace(inst.completion, pose=pose)
    else:
        inst.points = inst.points + t
        inst.box = type(inst.box)(inst.box.center + t, inst.box.yaw, inst.box.size)


def resolve_scene(
    instances: ObjectInstances,
    graph: ContactGraph | None,
    floor_z: float = 0.0,
    max_shift: float = 0.3,
    step: float = 0.01,
    directions: int = 16,
    snap_distance: float = 0.1,
) -> Resolution:
    """Min-conflict placement (in place): rest every object on its supporter, then remove overlaps."""
    order = support_order(instances, graph)
    by_id = {inst.id: inst for inst in instances}
    descendants: dict[int, list[int]] = {inst.id: [] for inst in instances}
    if graph is not None:
        import networkx as nx

        for inst in instances:
            if inst.id in graph.support:
                descendants[inst.id] = [
                    int(n)
                    for n in nx.descendants(graph.support, inst.id)
                    if isinstance(n, (int, np.integer)) and int(n) in by_id
                ]
    shells: dict[int, list[Shell]] = {inst.id: mesh_shells(world_mesh(inst)) for inst in instances}
    result = Resolution({inst.id: [0.0, 0.0, 0.0] for inst in instances})

    def move(i: int, t: np.ndarray) -> None:
        for j in [i, *(d for d in descendants[i] if by_id[d].completion is not None)]:
            translate_instance(by_id[j], t)
            shells[j] = [s.translated(t) for s in shells[j]]
            result.shifts[j] = (np.asarray(result.shifts[j]) + t).tolist()

    angles = np.linspace(0.0, 2 * np.pi, directions, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(directions)], axis=1)
    placed: list[int] = []
    for inst in order:
        mine = shells[inst.id]
        if not mine:
            continue
        if inst.completion is None:  # observed points are data: an obstacle to others, never moved
            placed.append(inst.id)
            continue
        verts = np.concatenate([s.vertices for s in mine])
        bottom = float(verts[:, 2].min())
        parent = graph.parent(inst.id) if graph is not None and inst.id in graph.support else None
        surface = floor_z
        if isinstance(parent, (int, np.integer)) and int(parent) in shells:
            feet = verts[verts[:, 2] <= bottom + 0.01, :2]
            tops = np.array([s.top_at(feet) for s in shells[int(parent)]])  # (shells, feet)
            tops = np.where(tops <= bottom + snap_distance, tops, np.nan)
            surface = float(np.nanmax(tops)) if np.isfinite(tops).any() else bottom
        dz = surface + 0.5 * CONTACT_TOLERANCE - bottom
        if abs(dz) <= snap_distance:
            move(inst.id, np.array([0.0, 0.0, dz]))
        mine = shells[inst.id]
        others = [s for j in placed for s in shells[j]]
        best_t, best_c = np.zeros(3), float(_conflicts(mine, others, np.zeros((1, 3)))[0])
        if best_c > 0:
            radii = np.arange(1, int(np.floor(max_shift / step + 1e-9)) + 1) * step
            candidates = (radii[:, None, None] * ring[None]).reshape(-1, 3)
            costs = _conflicts(mine, others, candidates)
            free = np.flatnonzero(costs == 0)
            # Candidates go outward ring by ring: the first free one is the nearest.
            k = int(free[0]) if len(free) else int(np.argmin(costs))
            if costs[k] < best_c:
                best_t, best_c = candidates[k], float(costs[k])
        if np.any(best_t):
            move(inst.id, best_t)
        result.residual[inst.id] = best_c
        placed.append(inst.id)
    return result


def conflicting(
    instances: ObjectInstances,
    ids: Iterable[int],
    against: Iterable[int] | None = None,
    exempt: set[tuple[int, int]] = frozenset(),
) -> list[int]:
    """Those of ``ids`` whose mesh, as it stands, conflicts with another object's (of ``against``
    only, when given; never ``j`` for ``(i, j)`` in ``exempt``): the measure ``resolve_scene``
    leaves as residual."""
    shells = {inst.id: mesh_shells(world_mesh(inst)) for inst in instances}
    among = set(shells) if against is None else set(against)
    out = []
    for i in sorted(set(ids) & set(shells)):
        others = [s for j, part in shells.items() if j != i and j in among and (i, j) not in exempt for s in part]
        if shells[i] and others and float(_conflicts(shells[i], others, np.zeros((1, 3)))[0]) > 0:
            out.append(i)
    return out


#: Observed points lie this deep in a model before they contradict it (m): the fused map's voxel and
#: the depth noise put a neighbour's surface points a centimetre or two into a model that only touches it.
SEEN_DEPTH = 0.02
#: Fewer of a neighbour's observed points than this in a model are noise, not a contradiction.
SEEN_POINTS = 10


def seen_inside(shells: list[Shell], points: np.ndarray) -> int:
    """How many of ``points`` lie deeper than :data:`SEEN_DEPTH` inside any of ``shells``."""
    points = np.asarray(points, float)
    inside = np.zeros(len(points), bool)
    for s in shells:
        near = np.flatnonzero(np.all((points > s.lo + SEEN_DEPTH) & (points < s.hi - SEEN_DEPTH), axis=1) & ~inside)
        if len(near):
            inside[near[s.depth(points[near]) > SEEN_DEPTH]] = True
    return int(inside.sum())


def contradicting(instances: ObjectInstances, ids: Iterable[int], against: Iterable[int]) -> list[int]:
    """Those of ``ids`` (completed objects) whose model holds at least :data:`SEEN_POINTS` of the
    observed points of an object of ``against`` deeper than :data:`SEEN_DEPTH`: the model fills space
    where a neighbour was seen. Observed points, not the convex pieces around them: a neighbour's hull
    fills space nobody saw (the things on a counter whose black worktop the sensor missed reach down
    into the counter's box in their hull, not in their points)."""
    by_id = {inst.id: inst for inst in instances}
    out = []
    for i in sorted(set(ids) & set(by_id)):
        if by_id[i].completion is None:
            continue
        # The pieces a simulator collides: a carcass's boards, not the storage space they close
        # (a sink's dishes, books on a shelf lie in there).
        shells = mesh_shells(by_id[i].completion.world_mesh())
        if not shells:
            continue
        lo, hi = np.min([s.lo for s in shells], axis=0), np.max([s.hi for s in shells], axis=0)
        for j in sorted(set(against) & set(by_id) - {i}):
            points = np.asarray(by_id[j].points, float)
            points = points[np.all((points > lo) & (points < hi), axis=1)]
            if len(points) >= SEEN_POINTS and seen_inside(shells, points) >= SEEN_POINTS:
                out.append(i)
                break
    return out


def _overlap_volume(a: Shell, b: Shell) -> float:
    if np.any(a.lo >= b.hi) or np.any(b.lo >= a.hi):
        return 0.0
    halfspaces = np.concatenate([a.equations, b.equations])
    # An interior point: the Chebyshev center of the intersection (linear program).
    norm = np.linalg.norm(halfspaces[:, :3], axis=1, keepdims=True)
    res = optimize.linprog(
        np.r_[0, 0, 0, -1.0],
        A_ub=np.hstack([halfspaces[:, :3], norm]),
        b_ub=-halfspaces[:, 3],
        bounds=[(None, None)] * 3 + [(0, None)],
        method="highs",
    )
    if not res.success or res.x[3] <= 1e-5:
        return 0.0
    try:
        pts = spatial.HalfspaceIntersection(halfspaces, res.x[:3]).intersections
        return float(spatial.ConvexHull(pts).volume)
    except (spatial.QhullError, ValueError):
        return 0.0


def penetration_volume(instances: ObjectInstances) -> float:
    """Total overlap volume (m^3) between the convex shells of different objects."""
    shells = [(inst.id, s) for inst in instances for s in mesh_shells(world_mesh(inst))]
    total = 0.0
    for k, (i, a) in enumerate(shells):
        for j, b in shells[k + 1 :]:
            if i != j:
                total += _overlap_volume(a, b)
    return total


#: MuJoCo's warnings that the simulation diverged. On each, MuJoCo resets the state to the model's
#: initial pose and goes on, so the poses at the end say nothing of what happened before.
DIVERGENCE_WARNINGS = ("mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC")


def settle(mjcf_path: str | Path, seconds: float = 2.0) -> dict[str, Any]:
    """Simulate the exported MJCF under gravity; how far each free body moved (needs ``mujoco``): the
    farther of its frame's origin and its centre of mass (a body framed at its base that tips over
    an edge of it moves its centre of mass far more than its origin).

    A simulation that diverged (``diverged``: MuJoCo's warning -> times, else empty) has every
    displacement infinite: MuJoCo restarted it from the initial pose, so a scene that exploded would
    otherwise look at rest. MuJoCo's own printout of the warnings is held back while it runs."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(mjcf_path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    bodies = [int(model.jnt_bodyid[j]) for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    start = {b: (data.xpos[b].copy(), data.xipos[b].copy()) for b in bodies}
    printer = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda message: None)  # counted in data.warning below
    try:
        for _ in range(int(round(seconds / model.opt.timestep))):
            mujoco.mj_step(model, data)
    finally:
        mujoco.set_mju_user_warning(printer)
    counts = {name: int(data.warning[getattr(mujoco.mjtWarning, name)].number) for name in DIVERGENCE_WARNINGS}
    diverged = {name: n for name, n in counts.items() if n}
    moved = {
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b): np.inf
        if diverged
        else max(float(np.linalg.norm(data.xpos[b] - start[b][0])), float(np.linalg.norm(data.xipos[b] - start[b][1])))
        for b in bodies
    }
    return {
        "free_bodies": len(bodies),
        "max_displacement_m": max(moved.values(), default=0.0),
        "displacement_m": moved,
        "diverged": diverged,
    }
