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
   points, it stays where it is and is exported static (with the reason); a free body that such a
   static one then penetrates (placed before it: a chair under a table that a box on the table
   reaches into) is kept static too, and the plan made again.

The support in step 1 is the highest surface no higher than the object's centre of mass (one above
it cannot hold it up), of its supporter first. Two kinds of collision geometry are replaced first,
in :attr:`RestPlan.collision` (visuals keep the mapped shapes):

* a static object's convex part that holds what was seen of another object, or a free body's
  convex parts (one hull over a shelf's boards and the book on them, a desk's box around the chair
  seen under it, a desk's apron the coarse hull of a chair's seat and back reaches into), is cut
  into hulls of its own observed points around the other's (:func:`_carved_parts`); only the
  object's supporter keeps the band where the other's underside meets it;
* a movable object known only by its observed surface (no completion, or a rejected one) is open
  underneath, and its centre of mass need not lie over anything it stands on: each of its parts is
  completed down to the surface under it (:func:`_based_parts`), as the issue's "support and rest"
  asks of an unseen base.

Before step 1 the object is turned onto the face it would rest on: a mapped or completed bottom is
rarely flat, and a body dropped on its lowest corner rocks onto the face of its convex hull under
its centre of mass (:func:`resting_normal`), tilting by up to :data:`MAX_TILT_DEG` (an object that
would tip further stays static). Its contact points are then the vertices on that face
(within :data:`CONTACT_BAND`), not every vertex near its bottom: a centre of mass over the hull of
near-bottom vertices can still lie outside the face a simulator lets it stand on (a chair whose
lowest face ends 2 mm from the vertical through its centre of mass rocked 4 cm in PyBullet).

Everything is deterministic geometry (no simulation), so the URDF, SDF and MJCF exporters get the
same plan.
"""

from __future__ import annotations

import copy
import hashlib
import pickle
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.geometry.hulls import convex_hull
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstances
from stratamap.core.simulation.physics import (
    CONTACT_TOLERANCE,
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
#: Vertices this close to the face an object rests on touch its support (metres): about what a
#: simulator's contact margin lets through, far less than a centimetre of rocking.
CONTACT_BAND = 0.001
#: An object is turned onto the face it rests on by at most this much (degrees); one that would tip
#: further is kept static (a free body would fall over, not settle).
MAX_TILT_DEG = 15.0
#: A partially observed free body's parts are completed down to the highest surface under it no
#: more than this above its lowest point (metres): what it stands on, not a shelf board it reaches.
BASE_ABOVE = 0.02


#: A static object's convex part with at least CARVE_MIN_FOREIGN observed points of another object
#: inside it or within CARVE_MARGIN (metres) of it is cut into the hulls of its own points around
#: them (:func:`_cut_around`), pieces of at least CARVE_MIN_POINTS points, for up to CARVE_ROUNDS
#: rounds over its neighbours; the lowest CARVE_QUANTILE of a neighbour's points (where it meets
#: its own support) do not count.
CARVE_MIN_FOREIGN = 3
CARVE_MARGIN = 0.01
CARVE_MIN_POINTS = 8
CARVE_ROUNDS = 4
CARVE_QUANTILE = 0.02


@dataclass
class RestPlan:
    """Per free body a world translation; the objects of movable classes kept static, with why."""

    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    static: dict[int, str] = field(default_factory=dict)
    #: World rotations applied before ``offsets`` (x -> R x + offset), for objects turned onto the
    #: face they rest on; absent means no rotation.
    rotations: dict[int, np.ndarray] = field(default_factory=dict)
    #: The centre of mass each turned object was turned about (for reporting how far it moved).
    pivots: dict[int, np.ndarray] = field(default_factory=dict)
    #: Convex collision parts (object frame) of objects whose collision shape is not their mesh's:
    #: a free, partially observed object's parts completed down to its support (:func:`_based_parts`),
    #: a static object's parts cut around what was seen of others inside them (:func:`_carved_parts`).
    collision: dict[int, list] = field(default_factory=dict)

    def free_ids(self, instances: ObjectInstances, movable: Iterable[str]) -> set[int]:
        classes = set(movable)
        return {inst.id for inst in instances if inst.class_name in classes and inst.id not in self.static}

    def to_dict(self) -> dict:
        # How far each centre of mass moves (a turned object's offset also holds its turn about the origin).
        moved = {
            k: float(np.linalg.norm(v + (self.rotations[k] - np.eye(3)) @ self.pivots[k] if k in self.rotations else v))
            for k, v in self.offsets.items()
        }
        return {
            "free_bodies": len(self.offsets),
            "max_offset_m": round(max(moved.values(), default=0.0), 4),
            "max_tilt_deg": round(max((_angle_deg(r) for r in self.rotations.values()), default=0.0), 2),
            "static": {str(k): v for k, v in sorted(self.static.items())},
            "collision_replaced": sorted(int(k) for k in self.collision),
        }


def _shells(mesh) -> list[Shell]:
    shells = [convex_shell(np.asarray(p.vertices)) for p in collision_parts(mesh)]
    return [s for s in shells if s is not None]


def _slab_shell(box) -> Shell | None:
    return convex_shell(np.asarray(trimesh.creation.box(extents=box.size, transform=box.pose).vertices))


def _near(mine: list[Shell], others: list[tuple[np.ndarray, bool]]) -> list[tuple[np.ndarray, bool]]:
    """Each other object's points inside the box around ``mine`` (but the lowest
    :data:`CARVE_QUANTILE` of those ``mine`` supports), for those that have any, with whether
    ``mine`` supports it."""
    lo = np.min([s.lo for s in mine], axis=0) - CONTACT_TOLERANCE
    hi = np.max([s.hi for s in mine], axis=0) + CONTACT_TOLERANCE
    near = []
    for p, supported in others:
        if len(p) < CARVE_MIN_FOREIGN:
            continue
        # Its lowest points mix with what it stands on (see _cut_around): left to the supporter.
        body = p[p[:, 2] >= np.quantile(p[:, 2], CARVE_QUANTILE)] if supported else p
        body = body[np.all((body >= lo) & (body <= hi), axis=1)]
        if len(body) >= CARVE_MIN_FOREIGN:
            near.append((body, supported))
    return near


def _cut_around(points: np.ndarray, foreign: np.ndarray, supports: bool) -> list[np.ndarray]:
    """``points`` cut into the (overlapping) pieces that lie wholly on one side of the box around
    the ``foreign`` points, :data:`CARVE_MARGIN` wider (room for the rest plan's small moves), but
    as much higher at its bottom when ``points`` are its supporter's (an object's underside meets
    its support, where the two observations mix: the support keeps that band; a desk's feet beside
    a chair standing on the floor are no such band): below, above and beside it along each axis.
    The points inside that box (where two objects' observations interleave) are left out.
    ``[points]`` when the points lie wholly on one side already, or every piece would be too small."""
    lo, hi = foreign.min(axis=0) - CARVE_MARGIN, foreign.max(axis=0) + CARVE_MARGIN
    if supports:
        lo[2] = foreign[:, 2].min() + CARVE_MARGIN
    pieces = []
    for axis in range(3):
        for side in (points[points[:, axis] < lo[axis]], points[points[:, axis] > hi[axis]]):
            if len(side) == len(points):  # wholly on one side already: nothing to cut
                return [points]
            if len(side) >= CARVE_MIN_POINTS:
                pieces.append(side)
    return pieces or [points]


def _surface_points(shell: Shell, spacing: float = 0.02) -> np.ndarray:
    """Points on a convex shell's surface no more than about ``spacing`` apart (its vertices and a
    barycentric grid on each face; deterministic)."""
    try:
        faces = spatial.ConvexHull(shell.vertices).simplices
    except (spatial.QhullError, ValueError):
        return shell.vertices
    out = [shell.vertices]
    for a, b, c in shell.vertices[faces]:
        n = int(np.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)) / spacing))
        if n < 2:
            continue
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        u, v = i[keep][:, None] / n, j[keep][:, None] / n
        out.append(a + u * (b - a) + v * (c - a))
    return np.concatenate(out)


def _carved_parts(inst, mine: list[Shell], others: list[tuple[np.ndarray, bool]]) -> list | None:
    """A static object's convex parts with every part that holds another object's observed points
    (a hull spanning a shelf's boards, or a desk's box around the chair seen under it) replaced by
    the hulls of its own observed points in it, cut around each such object's points there
    (:func:`_cut_around`); None when no part holds any. What was seen there is not inside the
    object, so a free body there need not be pushed out of it."""
    own = np.asarray(inst.points, dtype=float).reshape(-1, 3)
    if len(own) < CARVE_MIN_POINTS:
        return None
    hulls, changed = [], False
    for shell in mine:
        pieces, cut_any = [own[shell.depth(own) >= -CONTACT_TOLERANCE]], False
        # A piece cut around one object may still hold another, or one tried before: cut until none does.
        for _ in range(CARVE_ROUNDS if len(pieces[0]) >= CARVE_MIN_POINTS else 0):
            cut_now = False
            for points, supports in others:
                cut = []
                for piece in pieces:
                    hull = convex_shell(piece)
                    near = points[hull.near(points, CARVE_MARGIN)] if hull is not None else points
                    split = _cut_around(piece, near, supports) if len(near) >= CARVE_MIN_FOREIGN else [piece]
                    cut_now |= split[0] is not piece
                    cut.extend(split)
                pieces = cut
            cut_any |= cut_now
            if not cut_now:
                break
        if not cut_any:
            hulls.append(convex_hull(shell.vertices))
            continue
        changed = True
        for piece in pieces:
            try:
                hulls.append(convex_hull(piece))
            except Exception:  # a flat or tiny piece: its neighbours cover it
                continue
    return collision_parts(trimesh.util.concatenate(hulls)) if changed and hulls else None


def _based_parts(mine: list[Shell], below: list[Shell]) -> list:
    """Each convex part together with its projection onto the highest surface of ``below`` under
    it, no more than :data:`BASE_ABOVE` above its own lowest point (world frame): an object seen
    only from above or from one side is a shell open underneath, whose centre of mass need not lie
    over anything it stands on; completed down to what is under it, every part has a base and so
    has the whole body. Parts stay separate (a chair's seat and back do not fill the space beside
    it), and each stops at what is under that part (a table's foot under the chair's seat)."""
    hulls = []
    for shell in mine:
        feet, bottom = _footprint([shell], band=np.inf)
        tops = _tops(feet, bottom, below, ceiling=bottom + BASE_ABOVE)
        tops = tops[np.isfinite(tops)]
        vertices = shell.vertices
        if len(tops):
            # Down to the surface, and no further: points seen below it are its noise, not the body.
            base = float(tops.max())
            floor = vertices.copy()
            floor[:, 2] = base
            vertices = np.concatenate([np.c_[vertices[:, :2], np.maximum(vertices[:, 2], base)], floor])
        hulls.append(convex_hull(vertices))
    return collision_parts(trimesh.util.concatenate(hulls))


def _parent(graph: ContactGraph | None, object_id: int):
    """The object's supporter in the contact graph (an object id, or a slab's name), None if unknown."""
    if graph is None or object_id not in graph.support:
        return None
    parent = graph.parent(object_id)
    return int(parent) if isinstance(parent, (int, np.integer)) else parent


def _one_link(inst) -> bool:
    """Whether the object is exported as one link with its mesh (not a front on a joint, not an
    articulated model's parts): only then can its collision parts be replaced."""
    from stratamap.core.simulation.kinematics import front_joint

    c = inst.completion
    return front_joint(inst) is None and not (c is not None and c.joints and c.parts)


def _shells_of(parts: list) -> list[Shell]:
    return [s for p in parts if (s := convex_shell(np.asarray(p.vertices))) is not None]


def _in_object_frame(inst, parts: list) -> list:
    """World-frame meshes in the frame of the object's mesh (what an exporter's link carries)."""
    from stratamap.core.simulation.kinematics import object_mesh

    inverse = np.linalg.inv(object_mesh(inst)[1])
    out = []
    for part in parts:
        local = part.copy()
        local.apply_transform(inverse)
        out.append(local)
    return out


def _angle_deg(rotation: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))


def resting_normal(vertices: np.ndarray, center: np.ndarray, most: int = 50) -> np.ndarray:
    """Outward normal of the convex-hull face a rigid body rests on when set down upright on a
    horizontal plane: starting straight down, the face the line from the centre of mass along the
    current down direction leaves the hull through, until that face is the one below the centre of
    mass along its own normal (quasi-static rocking; (0, 0, -1) for a flat bottom)."""
    down = np.array([0.0, 0.0, -1.0])
    try:
        eq = spatial.ConvexHull(vertices).equations
    except (spatial.QhullError, ValueError):
        return down
    normals, offsets = eq[:, :3], eq[:, 3]
    inside = -(normals @ center + offsets)  # distance from the centre of mass to each face's plane
    if inside.min() < -1e-9:  # centre of mass outside the hull (not a solid): nothing to rock on
        return down
    for _ in range(most):
        along = normals @ down
        hit = np.where(along > 1e-9, inside / np.where(along > 1e-9, along, 1.0), np.inf)
        normal = normals[int(np.argmin(hit))]
        if np.allclose(normal, down, atol=1e-6):
            break
        down = normal
    return down


def rocking_angle(mesh) -> float:
    """How far (degrees) a body set down as it is rocks before it rests on a face of its convex
    collision parts' hull (:func:`resting_normal`): 0 for a flat bottom, about 9 for a 20-sided cup
    lying on its side, 90 or more for one that falls over."""
    from stratamap.core.simulation.kinematics import inertial_of

    parts = collision_parts(mesh)
    if not parts:
        return 0.0
    vertices = np.concatenate([np.asarray(p.vertices, dtype=float) for p in parts])
    return _angle_deg(_turn_down(resting_normal(vertices, inertial_of(mesh, 1.0).center)))


def _turn_down(normal: np.ndarray) -> np.ndarray:
    """The smallest rotation taking ``normal`` to straight down."""
    axis = np.cross(normal, [0.0, 0.0, -1.0])
    s, c = float(np.linalg.norm(axis)), float(-normal[2])
    if s < 1e-12:
        return np.eye(3)
    k = axis / s
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * cross + (1.0 - c) * cross @ cross


def _rotated(shell: Shell, rotation: np.ndarray, pivot: np.ndarray) -> Shell:
    """``shell`` turned by ``rotation`` about ``pivot`` (x -> R (x - p) + p)."""
    normals = shell.equations[:, :3] @ rotation.T
    offsets = shell.equations[:, 3] + shell.equations[:, :3] @ pivot - normals @ pivot
    return Shell((shell.vertices - pivot) @ rotation.T + pivot, np.c_[normals, offsets])


def _footprint(
    mine: list[Shell], spacing: float = 0.01, most: int = 400, band: float = 0.01
) -> tuple[np.ndarray, float]:
    """Points on the object's lowest face (a grid inside the hull of its vertices within ``band``
    of its bottom, with the vertices themselves) and the object's lowest height."""
    verts = np.concatenate([s.vertices for s in mine])
    bottom = float(verts[:, 2].min())
    feet = verts[verts[:, 2] <= bottom + band, :2]
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


def _tops(feet: np.ndarray, bottom: float, others: list[Shell], ceiling: float = np.inf) -> np.ndarray:
    """Per footprint point, the highest surface of ``others`` under it (no higher than a little
    above the object's bottom, nor than ``ceiling``); -inf where there is none."""
    best = np.full(len(feet), -np.inf)
    ceiling = min(bottom + SUPPORT_ABOVE, ceiling)
    for o in others:
        if o.hi[2] < bottom - SUPPORT_BELOW or o.lo[2] > bottom + SUPPORT_ABOVE:
            continue
        if np.any(o.lo[:2] > feet.max(0)) or np.any(o.hi[:2] < feet.min(0)):
            continue
        tops = o.top_at(feet)
        ok = np.isfinite(tops) & (tops <= ceiling)
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


#: The last plans made, by a digest of their inputs: the URDF, SDF and MJCF exporters of one run
#: plan the same scene, and a plan takes seconds on a room.
_PLANS: OrderedDict[str, RestPlan] = OrderedDict()
_PLANS_KEPT = 4


class _ContentPickler(pickle.Pickler):
    """Pickles a mesh as its vertices and faces only: trimesh pickles the values it has cached
    (normals, areas), which an exporter fills in, so the same scene would digest differently before
    and after the URDF exporter ran."""

    def reducer_override(self, obj):
        if isinstance(obj, trimesh.Trimesh):
            return tuple, ((np.asarray(obj.vertices).tobytes(), np.asarray(obj.faces).tobytes()),)
        return NotImplemented


def content_digest(value) -> str | None:
    """A digest of what ``value`` holds (None where it cannot be pickled)."""
    digest = hashlib.blake2b(digest_size=20)

    class _Sink:
        write = digest.update

    try:
        _ContentPickler(_Sink(), protocol=pickle.HIGHEST_PROTOCOL).dump(value)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None
    return digest.hexdigest()


def rest_offsets(
    instances: ObjectInstances,
    graph: ContactGraph | None,
    movable: Iterable[str],
    statics: list | None = None,
) -> RestPlan:
    """Plan where each object of a ``movable`` class starts so that it rests (see the module doc).
    The same inputs give the same plan (a copy of the one made first)."""
    movable = set(movable)
    key = content_digest((instances, graph, sorted(movable), statics))
    if key is not None and key in _PLANS:
        _PLANS.move_to_end(key)
        return copy.deepcopy(_PLANS[key])
    # A body kept static where it was mapped may hold a free body placed before it (a box on a table
    # reaching into a chair pushed under it): that one cannot rest either, and the plan is made again
    # with it static, until no static body holds a free one.
    scene = _scene(instances, graph, movable, statics)
    kept: dict[int, str] = {}
    for _ in range(len(instances) + 1):
        plan, held = _plan_rest(instances, graph, movable, scene, kept)
        if not held:
            break
        kept.update(held)
    if key is not None:
        _PLANS[key] = copy.deepcopy(plan)
        while len(_PLANS) > _PLANS_KEPT:
            _PLANS.popitem(last=False)
    return plan


@dataclass
class _Scene:
    """What the rest plan starts from, made once per scene however often the placement is redone:
    every object's world mesh and convex collision shells (a static object's cut around its
    neighbours), the room's slabs, and the replaced collision parts."""

    meshes: dict
    shells: dict[int, list[Shell]]
    slabs: list[Shell]
    collision: dict[int, list]


def _scene(instances: ObjectInstances, graph: ContactGraph | None, movable: set[str], statics: list | None) -> _Scene:
    meshes = {inst.id: world_mesh(inst) for inst in instances}
    shells = {inst.id: _shells(mesh) for inst, mesh in zip(instances, meshes.values(), strict=True)}
    slabs: list[Shell] = [s for b in statics or [] if (s := _slab_shell(b)) is not None]
    collision: dict[int, list] = {}
    # What a static object's collision is cut around: what was seen of each neighbour and, of a free
    # body, its convex parts too (a hull over a partly seen chair reaches where none of its points
    # are, such as under a desk's apron it was pushed under).
    seen = {}
    for inst in instances:
        observed = np.asarray(inst.points, dtype=float).reshape(-1, 3)
        if inst.class_name in movable and shells[inst.id]:
            observed = np.concatenate([observed, *(_surface_points(s) for s in shells[inst.id])])
        seen[inst.id] = observed
    for inst in instances:
        # Static objects only are cut: a free body cut around its neighbour's points would lose what
        # it rests on (a book whose edge mixes with the shelf's rail), while the neighbour only
        # loses the space the free body was seen in.
        if inst.class_name in movable or not (_one_link(inst) and shells[inst.id]):
            continue
        near = _near(shells[inst.id], [(p, _parent(graph, k) == inst.id) for k, p in seen.items() if k != inst.id])
        carved = _carved_parts(inst, shells[inst.id], near) if near else None
        if carved is not None:
            shells[inst.id] = _shells_of(carved)
            collision[inst.id] = _in_object_frame(inst, carved)
    return _Scene(meshes, shells, slabs, collision)


def _plan_rest(
    instances: ObjectInstances,
    graph: ContactGraph | None,
    movable: set[str],
    scene: _Scene,
    kept: dict[int, str],
) -> tuple[RestPlan, dict[int, str]]:
    """The plan with the objects of ``kept`` static (with their reasons), and the free bodies that a
    body kept static penetrates where it was mapped (with why they cannot be free)."""
    from stratamap.core.simulation.kinematics import inertial_of

    plan = RestPlan(collision=dict(scene.collision))
    meshes, shells, slabs = scene.meshes, scene.shells, scene.slabs
    fixed = list(slabs)
    for inst in instances:
        if inst.class_name not in movable:
            fixed.extend(shells[inst.id])
    for k, reason in kept.items():
        plan.static[k] = reason
        fixed.extend(shells.get(k, []))
    placed: list[Shell] = []
    placed_by_id: dict[int, list[Shell]] = {}  # free bodies already placed, where they start
    lifts = np.arange(1, int(round(MAX_LIFT / 0.002)) + 1)[:, None] * np.array([[0.0, 0.0, 0.002]])
    angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(8)], axis=1)
    radii = np.arange(1, int(round(MAX_NUDGE / 0.005)) + 1) * 0.005
    sideways = (radii[:, None, None] * ring[None]).reshape(-1, 3)
    for inst in support_order(instances, graph):
        if inst.class_name not in movable or inst.id in kept:
            continue
        mine = shells[inst.id]
        if not mine:
            plan.static[inst.id] = "no collision geometry"
            continue
        # The supporter the contact graph names holds the object up; any other surface is a neighbour.
        parent = _parent(graph, inst.id)
        supporters = shells.get(int(parent), []) if isinstance(parent, (int, np.integer)) else slabs
        if isinstance(parent, (int, np.integer)) and int(parent) in placed_by_id:  # a free body placed before
            supporters = placed_by_id[int(parent)]
        based: list[trimesh.Trimesh] | None = None
        if inst.completion is None:
            # Only its observed surface (no completion, or one rejected): its unseen underside is
            # completed down to what it stands on, so it rests on a base under its centre of mass.
            based = _based_parts(mine, fixed + placed)
            mine = _shells_of(based) or mine
        own = mine  # where the body's collision parts are before it is turned and moved
        # Turned (about its centre of mass) onto the face it would rock onto, before it is dropped.
        center = inertial_of(meshes[inst.id], 1.0).center
        rotation = _turn_down(resting_normal(np.concatenate([s.vertices for s in mine]), center))
        tilt = _angle_deg(rotation)
        if tilt > MAX_TILT_DEG:
            plan.static[inst.id] = f"it would tip by {tilt:.0f} degrees onto the face under its centre of mass"
            fixed.extend(mine)
            continue
        turned = tilt > 1e-6
        if turned:
            mine = [_rotated(s, rotation, center) for s in mine]
        others = fixed + placed
        feet, bottom = _footprint(mine)
        # Its supporter's surfaces, else any; a surface above its centre of mass cannot hold it up
        # (the slanted edge of a hull over its footprint), unless there is no other.
        for under, ceiling in ((supporters, center[2]), (others, center[2]), (supporters, np.inf), (others, np.inf)):
            tops = _tops(feet, bottom, under, ceiling)
            if np.isfinite(tops).any():
                break
        if not np.isfinite(tops).any():
            plan.static[inst.id] = "nothing under it to rest on"
            fixed.extend(shells[inst.id])
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
        else:
            # Only the face it rests on touches the support, not every vertex near its bottom; both
            # that face and the centre of mass where the (nudged) body starts.
            contact, _ = _footprint(mine, band=CONTACT_BAND)
            contact = contact + offset[:2]
            if not _stable(contact, _tops(contact, bottom, under, ceiling), surface, center + offset):
                plan.static[inst.id] = "its centre of mass is not over what it stands on"
        if inst.id in plan.static:
            fixed.extend(shells[inst.id])  # a static body is exported where it was mapped, unturned
            continue
        if turned:
            plan.rotations[inst.id], plan.pivots[inst.id] = rotation, center
            offset = offset + center - rotation @ center  # turn about the centre, then drop: x -> R x + offset
        plan.offsets[inst.id] = offset
        if based is not None:
            plan.collision[inst.id] = _in_object_frame(inst, based)
        start = [_rotated(s, rotation, np.zeros(3)) for s in own] if turned else own
        placed_by_id[inst.id] = [s.translated(offset) for s in start]
        placed.extend(placed_by_id[inst.id])
    names = {inst.id: f"{inst.class_name} {inst.id}" for inst in instances}
    held: dict[int, str] = {}
    for k in sorted(set(plan.static) - set(kept)):
        for free, start in placed_by_id.items():
            if free in held or not shells[k]:
                continue
            depth = float(shifted_penetration(start, shells[k], np.zeros((1, 3)), deepest=True)[0])
            if depth > 0:
                held[free] = f"{names[k]}, kept static, penetrates it by {depth * 1000:.0f} mm"
    return plan, held
