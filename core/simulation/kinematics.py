"""From the contact graph and completed instances to a kinematic tree of links and joints.

Every object becomes a link (in its object frame: origin at the bottom center, +z up) attached to
its supporter by a joint; the root link is ``world``. Objects of movable classes get a floating
joint (a free body), the others a fixed one. A completion from an articulated model adds a link
per moving part (door, drawer, lid, swivel seat) with the model's revolute, prismatic or continuous
joint and limits, geometry-less helper links included (PartNet-Mobility chains a prismatic and a
revolute joint through one). A furniture front found by a segmenter (``attributes["joint"]`` and
``attributes["hinge"]``, as ``plane_crf`` writes them) becomes a panel link on a revolute joint
about its hinge side, or a prismatic joint for a drawer. Shared by the URDF, MJCF and SDF exporters.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.geometry.hulls import convex_hull
from stratamap.core.geometry.transforms import invert
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstance, ObjectInstances
from stratamap.core.map.priors import MOVABLE, class_body, material_volume

trimesh = lazy_module("trimesh")

ROOT_LINK = "world"


@dataclass
class Inertial:
    mass: float
    center: np.ndarray  # in the link frame
    inertia: np.ndarray  # (3, 3) about the center, link axes


#: Classes exported as free bodies by default (the class facts' movable things).
DEFAULT_MOVABLE_CLASSES = MOVABLE

#: How far a door or flap found on a scan opens (radians) and a drawer slides out (metres).
FRONT_OPENING = float(np.pi / 2)
DRAWER_TRAVEL = 0.4

#: Mass and inertia of a link without geometry (a helper frame between two joints).
HELPER_MASS = 0.01


@dataclass
class Link:
    name: str
    mesh: trimesh.Trimesh | None  # link frame; None for a helper link without geometry
    inertial: Inertial
    instance_id: int | None = None
    class_name: str = ""
    #: Convex collision parts in the link frame when they differ from the mesh's own
    #: (:func:`link_collision`): a rest plan's support-completed base of a partially observed object.
    collision: list[trimesh.Trimesh] | None = None


@dataclass
class KinematicJoint:
    name: str
    type: str  # fixed | floating | revolute | prismatic
    parent: str
    child: str
    origin: np.ndarray  # child frame in the parent frame
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float = 0.0
    upper: float = 0.0


@dataclass
class KinematicTree:
    links: list[Link]
    joints: list[KinematicJoint]
    #: Floor, walls and ceiling (:func:`stratamap.core.simulation.structure.room_structure`).
    statics: list = field(default_factory=list)

    def link_names(self) -> list[str]:
        return [ROOT_LINK] + [link.name for link in self.links]


def link_collision(link: Link) -> list[trimesh.Trimesh]:
    """The convex parts a simulator collides for ``link``: its own collision parts if it has them,
    else those of its mesh (none for a helper link)."""
    from stratamap.core.simulation.physics import collision_parts

    if link.collision is not None:
        return [part.copy() for part in link.collision]
    return collision_parts(link.mesh) if link.mesh is not None else []


def safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", text)


def link_name(inst: ObjectInstance) -> str:
    return safe_name(f"{inst.class_name}_{inst.id}")


def inertial_of(mesh: trimesh.Trimesh, density: float, fill: float = 1.0) -> Inertial:
    """Mass of the material in ``mesh`` (link frame, gravity-aligned), ``density`` kg/m^3 times its
    solid volume (convex hull if not watertight) but at most ``fill`` of its box
    (:func:`stratamap.core.map.priors.material_volume`: a box completion of a table is mostly air),
    and the inertia tensor of the solid for that mass."""
    # A flat mesh has no volume, and trimesh divides by it: the flat case is handled below.
    with np.errstate(divide="ignore", invalid="ignore"):
        solid = mesh if mesh.is_volume else mesh.convex_hull
        raw_volume = float(solid.volume)
        moment = np.asarray(solid.moment_inertia, dtype=float)
        center_mass = np.asarray(solid.center_mass, dtype=float)
    volume = max(raw_volume, 1e-9)
    extents = tuple(float(e) for e in np.asarray(mesh.extents, dtype=float))
    mass = max(max(material_volume(volume, extents, fill), 1e-9) * density, 1e-3)
    if raw_volume <= 1e-9:  # flat: the box guard below gives it an inertia
        inertia = np.zeros((3, 3))
        center = np.asarray(mesh.bounds.mean(axis=0), dtype=float)
        ext = np.maximum(np.asarray(mesh.extents, dtype=float), 1e-3)
        return Inertial(mass, center, np.diag(mass / 12.0 * (ext[[1, 0, 0]] ** 2 + ext[[2, 2, 1]] ** 2)))
    # The solid's shape at the material's mass: a framed or hollow object's mass sits farther out,
    # which only the real parts could say.
    inertia = moment / max(raw_volume, 1e-12) * mass
    # Guard against degenerate hulls: keep the tensor positive definite and physically valid.
    evals = np.linalg.eigvalsh(inertia)
    if not np.all(np.isfinite(inertia)) or evals.min() <= 1e-9:
        ext = np.maximum(solid.extents, 1e-3)
        inertia = np.diag(mass / 12.0 * (ext[[1, 0, 0]] ** 2 + ext[[2, 2, 1]] ** 2))
    return Inertial(mass, center_mass, inertia)


def helper_inertial() -> Inertial:
    return Inertial(HELPER_MASS, np.zeros(3), np.eye(3) * 1e-6)


def front_joint(inst: ObjectInstance) -> tuple[str, np.ndarray, np.ndarray, float, float] | None:
    """A segmented front's articulation: (type, hinge frame in the world, axis in that frame, lower,
    upper), or None when the object is no front. The hinge frame has the front's axes (x along its
    width, -y out of the furniture) and its origin on the hinge line at the face: the vertical edge
    on the hinge side (``left``/``right`` as seen facing the front), the top or bottom edge for flaps,
    the face's centre for a drawer (which slides out along -y)."""
    kind = inst.attributes.get("joint")
    if kind not in ("revolute", "prismatic") or inst.completion is not None:
        return None
    pose = inst.box.pose
    half = np.asarray(inst.box.size, float) / 2
    face = np.array([0.0, -half[1], 0.0])  # the front face, in the box frame
    if kind == "prismatic":
        offset, axis, upper = face, np.array([0.0, -1.0, 0.0]), DRAWER_TRAVEL
    else:
        hinge = inst.attributes.get("hinge") or "left"
        # Opening swings the free edge out of the furniture (towards -y).
        offset, axis = {
            "right": (face + [half[0], 0.0, 0.0], np.array([0.0, 0.0, 1.0])),
            "left": (face + [-half[0], 0.0, 0.0], np.array([0.0, 0.0, -1.0])),
            "top": (face + [0.0, 0.0, half[2]], np.array([-1.0, 0.0, 0.0])),
            "bottom": (face + [0.0, 0.0, -half[2]], np.array([1.0, 0.0, 0.0])),
        }.get(hinge, (face + [-half[0], 0.0, 0.0], np.array([0.0, 0.0, -1.0])))
        upper = FRONT_OPENING
    frame = pose.copy()
    frame[:3, 3] = pose[:3, :3] @ offset + pose[:3, 3]
    return kind, frame, axis, 0.0, upper


def front_panel(inst: ObjectInstance, frame: np.ndarray) -> trimesh.Trimesh:
    """The front's box as a panel mesh in its hinge frame."""
    panel = trimesh.creation.box(extents=np.maximum(np.asarray(inst.box.size, float), 1e-3))
    panel.apply_transform(invert(frame) @ inst.box.pose)
    return panel


#: Observed points of an uncompleted object are cut into horizontal bands this tall (metres) and
#: each band into pieces connected at this voxel size; each piece's hull is one convex part.
OBSERVED_BAND = 0.1
OBSERVED_VOXEL = 0.04


_OBSERVED_CACHE: dict[tuple, list] = {}


def observed_parts(points: np.ndarray, band: float = OBSERVED_BAND, voxel: float = OBSERVED_VOXEL) -> list:
    """A convex decomposition of observed points: per horizontal band, the hull of each connected
    piece (a table's top and each leg; one hull of the whole table would fill the space under it,
    where chairs are pushed). Bands overlap by a voxel so the pieces meet."""
    points = np.ascontiguousarray(points, dtype=float)
    key = (hashlib.sha1(points.tobytes()).hexdigest(), band, voxel)
    if key not in _OBSERVED_CACHE:
        if len(_OBSERVED_CACHE) >= 256:
            _OBSERVED_CACHE.pop(next(iter(_OBSERVED_CACHE)))
        _OBSERVED_CACHE[key] = _observed_parts(points, band, voxel)
    return [part.copy() for part in _OBSERVED_CACHE[key]]


def _observed_parts(points: np.ndarray, band: float, voxel: float) -> list:
    from scipy import ndimage

    parts = []
    z0, z1 = float(points[:, 2].min()), float(points[:, 2].max())
    edges = np.arange(z0, z1 + band, band)
    for lo in edges[:-1] if len(edges) > 1 else [z0]:
        sel = points[(points[:, 2] >= lo - voxel / 2) & (points[:, 2] <= lo + band + voxel / 2)]
        if len(sel) < 4:
            continue
        keys = np.floor((sel[:, :2] - sel[:, :2].min(0)) / voxel).astype(int)
        grid = np.zeros(keys.max(0) + 1, bool)
        grid[keys[:, 0], keys[:, 1]] = True
        labels, count = ndimage.label(grid, structure=np.ones((3, 3)))
        piece_of = labels[keys[:, 0], keys[:, 1]]
        for k in range(1, count + 1):
            piece = sel[piece_of == k]
            if len(piece) < 4:
                continue
            try:
                hull = convex_hull(piece)
                if hull.volume > 1e-7:
                    parts.append(hull)
            except Exception:  # a flat or tiny piece: left out (its neighbours cover it)
                continue
    return parts


def object_mesh(inst: ObjectInstance) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh of an object in its object frame and the object-to-world pose.

    A completed object uses its completion; an uncompleted one a convex decomposition of its
    observed points (:func:`observed_parts`; their hull, or its box, when the points are too few or
    degenerate), framed at its box's bottom center.
    """
    if inst.completion is not None:
        return inst.completion.mesh, inst.completion.pose
    pose = inst.box.pose
    pose[2, 3] = inst.box.bottom_z
    local = (inst.points - pose[:3, 3]) @ pose[:3, :3]
    try:
        parts = observed_parts(local) if len(local) >= 8 else []
        mesh = trimesh.util.concatenate(parts) if parts else convex_hull(local)
        if mesh.volume <= 1e-9:
            raise ValueError("flat hull")
    except Exception:
        mesh = trimesh.creation.box(extents=np.maximum(inst.box.size, 1e-3))
        mesh.apply_translation((0, 0, max(inst.box.size[2], 1e-3) / 2))
    return mesh, pose


def build_tree(
    instances: ObjectInstances,
    graph: ContactGraph | None,
    density: dict[str, float] | None = None,
    floating_classes: set[str] | frozenset[str] = frozenset(),
    offsets: dict[int, np.ndarray] | None = None,
    statics: list | None = None,
    floating_ids: set[int] | None = None,
    rotations: dict[int, np.ndarray] | None = None,
    collision: dict[int, list[trimesh.Trimesh]] | None = None,
) -> KinematicTree:
    """Links for every object; joints to the supporting object (or the world) from the contact graph.

    Objects of ``floating_classes`` hang from the world by floating joints (free bodies, whatever
    supports them); ``offsets`` moves objects by a world translation first, after turning them by the
    world rotation in ``rotations`` if any (x -> R x + offset: a rest plan's settling,
    :func:`stratamap.core.simulation.rest.rest_offsets`); ``statics`` are the room's slabs;
    ``floating_ids``, when given, names the free objects instead of ``floating_classes``;
    ``collision`` gives an object's convex collision parts in its object frame (a rest plan's
    support-completed base) instead of its mesh's."""
    density = dict(density or {})
    collision = collision or {}
    offsets = offsets or {}
    rotations = rotations or {}
    poses: dict[int, np.ndarray] = {}
    links: list[Link] = []
    names: dict[int, str] = {}
    joints: list[KinematicJoint] = []
    fronts: set[int] = set()
    for inst in instances:
        mesh, pose = object_mesh(inst)
        settle = np.eye(4)
        settle[:3, :3] = np.asarray(rotations.get(inst.id, np.eye(3)), float)
        settle[:3, 3] = np.asarray(offsets.get(inst.id, np.zeros(3)), float)
        pose = settle @ pose
        poses[inst.id] = pose
        names[inst.id] = link_name(inst)
        facts = class_body(inst.class_name, density.get(inst.class_name))
        rho, fill = facts.density, facts.fill
        c = inst.completion
        front = front_joint(inst)
        if front is not None:
            kind, frame, axis, lower, upper = front
            panel = front_panel(inst, frame)
            links.append(Link(names[inst.id], panel, inertial_of(panel, rho, fill), inst.id, inst.class_name))
            # The joint's name says what the segmenter estimated: which side a door hinges on.
            label = f"hinge_{inst.attributes.get('hinge') or 'left'}" if kind == "revolute" else "slide"
            joints.append(
                KinematicJoint(f"{names[inst.id]}_{label}", kind, ROOT_LINK, names[inst.id], frame, axis, lower, upper)
            )
            fronts.add(inst.id)
        elif c is not None and c.joints and c.parts:
            # Articulated: the body is the object's link; every moving part gets a link and its joint,
            # helper links without geometry included (a joint must not name a link the file lacks).
            parts = {p.name: p for p in c.parts}
            body = parts.get("body")
            # A body without geometry of its own (PartNet-Mobility's root link) stays a helper link:
            # the whole model there would double every part.
            links.append(
                Link(
                    names[inst.id],
                    None if body is None else body.mesh,
                    helper_inertial() if body is None else inertial_of(body.mesh, rho, fill),
                    inst.id,
                    inst.class_name,
                )
            )

            def part_link(part_name: str, base: str = names[inst.id]) -> str:
                return base if part_name == "body" else safe_name(f"{base}__{part_name}")

            for j in c.joints:
                part = parts.get(j.child)
                child = part_link(j.child)
                if part is not None:
                    links.append(Link(child, part.mesh, inertial_of(part.mesh, rho, fill), inst.id, inst.class_name))
                else:
                    links.append(Link(child, None, helper_inertial(), inst.id, inst.class_name))
                joints.append(
                    KinematicJoint(
                        safe_name(f"{child}_{j.name}"),
                        j.type,
                        part_link(j.parent),
                        child,
                        j.origin,
                        j.axis,
                        j.lower,
                        j.upper,
                    )
                )
        else:
            links.append(
                Link(
                    names[inst.id], mesh, inertial_of(mesh, rho, fill), inst.id, inst.class_name, collision.get(inst.id)
                )
            )
    for inst in instances:
        if inst.id in fronts:
            continue
        free = inst.id in floating_ids if floating_ids is not None else inst.class_name in floating_classes
        parent = graph.parent(inst.id) if graph is not None and inst.id in graph.support else None
        if not free and isinstance(parent, (int, np.integer)) and int(parent) in poses and int(parent) not in fronts:
            parent_name, parent_pose = names[int(parent)], poses[int(parent)]
        else:
            parent_name, parent_pose = ROOT_LINK, np.eye(4)
        jtype = "floating" if free else "fixed"
        joints.append(
            KinematicJoint(
                f"{names[inst.id]}_joint", jtype, parent_name, names[inst.id], invert(parent_pose) @ poses[inst.id]
            )
        )
    return KinematicTree(links, joints, list(statics or []))
