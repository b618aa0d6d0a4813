"""From the contact graph and completed instances to a kinematic tree of links and joints.

Every object becomes a link (in its object frame: origin at the bottom center, +z up) attached to
its supporter by a joint; the root link is ``world``. A completion from an articulated model adds
a link per moving part (door, drawer, lid, swivel seat) with the model's revolute, prismatic or
continuous joint and limits. Shared by the URDF, MJCF and SDF exporters.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.geometry.transforms import invert
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstance, ObjectInstances

trimesh = lazy_module("trimesh")

ROOT_LINK = "world"

#: Solid density per class, kg/m^3 of the mesh volume (furniture is partly hollow, hence low).
DEFAULT_DENSITY = {
    "chair": 250.0,
    "table": 300.0,
    "desk": 300.0,
    "cabinet": 200.0,
    "shelf": 200.0,
    "sofa": 150.0,
    "box": 150.0,
    "book": 600.0,
    "cup": 400.0,
    "laptop": 700.0,
    "monitor": 400.0,
}
FALLBACK_DENSITY = 300.0


@dataclass
class Inertial:
    mass: float
    center: np.ndarray  # in the link frame
    inertia: np.ndarray  # (3, 3) about the center, link axes


@dataclass
class Link:
    name: str
    mesh: trimesh.Trimesh  # link frame
    inertial: Inertial
    instance_id: int | None = None
    class_name: str = ""


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

    def link_names(self) -> list[str]:
        return [ROOT_LINK] + [link.name for link in self.links]


def safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", text)


def link_name(inst: ObjectInstance) -> str:
    return safe_name(f"{inst.class_name}_{inst.id}")


def inertial_of(mesh: trimesh.Trimesh, density: float) -> Inertial:
    """Mass from volume x density and the inertia tensor of the solid (convex hull if not watertight)."""
    solid = mesh if mesh.is_volume else mesh.convex_hull
    volume = max(float(solid.volume), 1e-9)
    mass = max(volume * density, 1e-3)
    inertia = np.asarray(solid.moment_inertia, dtype=float) / max(float(solid.volume), 1e-12) * volume * density
    # Guard against degenerate hulls: keep the tensor positive definite and physically valid.
    evals = np.linalg.eigvalsh(inertia)
    if not np.all(np.isfinite(inertia)) or evals.min() <= 1e-9:
        ext = np.maximum(solid.extents, 1e-3)
        inertia = np.diag(mass / 12.0 * (ext[[1, 0, 0]] ** 2 + ext[[2, 2, 1]] ** 2))
    return Inertial(mass, np.asarray(solid.center_mass, dtype=float), inertia)


def object_mesh(inst: ObjectInstance) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh of an object in its object frame and the object-to-world pose.

    A completed object uses its completion; an uncompleted one the convex hull of its observed
    points (or its box when the points are degenerate), framed at its box's bottom center.
    """
    if inst.completion is not None:
        return inst.completion.mesh, inst.completion.pose
    pose = inst.box.pose
    pose[2, 3] = inst.box.bottom_z
    local = (inst.points - pose[:3, 3]) @ pose[:3, :3]
    try:
        mesh = trimesh.convex.convex_hull(local)
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
) -> KinematicTree:
    """Links for every object; joints to the supporting object (or the world) from the contact graph."""
    density = {**DEFAULT_DENSITY, **(density or {})}
    poses: dict[int, np.ndarray] = {}
    links: list[Link] = []
    names: dict[int, str] = {}
    joints: list[KinematicJoint] = []
    for inst in instances:
        mesh, pose = object_mesh(inst)
        poses[inst.id] = pose
        names[inst.id] = link_name(inst)
        rho = density.get(inst.class_name, FALLBACK_DENSITY)
        c = inst.completion
        if c is not None and c.joints and c.parts:
            # Articulated: the body is the object's link; every moving part gets a link and its joint.
            parts = {p.name: p for p in c.parts}
            body = parts.get("body")
            links.append(
                Link(
                    names[inst.id],
                    body.mesh if body is not None else mesh,
                    inertial_of(body.mesh if body is not None else mesh, rho),
                    inst.id,
                    inst.class_name,
                )
            )
            for j in c.joints:
                part = parts.get(j.child)
                if part is None:
                    continue
                child = safe_name(f"{names[inst.id]}__{j.child}")
                parent = names[inst.id] if j.parent == "body" else safe_name(f"{names[inst.id]}__{j.parent}")
                links.append(Link(child, part.mesh, inertial_of(part.mesh, rho), inst.id, inst.class_name))
                joints.append(
                    KinematicJoint(
                        safe_name(f"{child}_{j.name}"), j.type, parent, child, j.origin, j.axis, j.lower, j.upper
                    )
                )
        else:
            links.append(Link(names[inst.id], mesh, inertial_of(mesh, rho), inst.id, inst.class_name))
    for inst in instances:
        parent = graph.parent(inst.id) if graph is not None and inst.id in graph.support else None
        if isinstance(parent, (int, np.integer)) and int(parent) in poses:
            parent_name, parent_pose = names[int(parent)], poses[int(parent)]
        else:
            parent_name, parent_pose = ROOT_LINK, np.eye(4)
        jtype = "floating" if inst.class_name in floating_classes else "fixed"
        joints.append(
            KinematicJoint(
                f"{names[inst.id]}_joint", jtype, parent_name, names[inst.id], invert(parent_pose) @ poses[inst.id]
            )
        )
    return KinematicTree(links, joints)
