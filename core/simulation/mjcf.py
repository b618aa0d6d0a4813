"""MuJoCo scenes (MJCF): the completed objects as bodies, meshes beside the model file.

Furniture is static (bodies without joints, welded to the world); objects of ``free_classes``
get a free joint, placed by the rest plan (:mod:`stratamap.core.simulation.rest`) just above their
support, or stay static where they cannot rest; articulated parts and segmented fronts keep hinge
and slide joints with their ranges. Floor (a plane at the floor height), walls and ceiling (boxes)
are world geoms. MuJoCo collides convex hulls, so every link mesh is split into its closed shells
(a chair's legs, seat and back) and each shell's convex hull is its own geom (a flat shell, whose
hull MuJoCo refuses, becomes a thin box): one hull per chair would fill the space under a table
and push the chair out.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, ObjectInstances
from stratamap.core.simulation.kinematics import ROOT_LINK, build_tree, link_collision
from stratamap.core.simulation.rest import RestPlan, rest_offsets

rotations = lazy_module("scipy.spatial.transform")

#: Classes :func:`write_mjcf` frees by default (the completion benchmark's physics check); the
#: ``mjcf`` exporter frees :data:`~stratamap.core.simulation.kinematics.DEFAULT_MOVABLE_CLASSES`.
DEFAULT_FREE_CLASSES = ("chair", "box", "book", "cup", "bottle", "laptop", "monitor", "plant")


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _quat_wxyz(pose: np.ndarray) -> str:
    x, y, z, w = rotations.Rotation.from_matrix(pose[:3, :3]).as_quat()
    return _fmt([w, x, y, z])


def write_mjcf(
    instances: ObjectInstances,
    out_dir: Path,
    filename: str = "scene.xml",
    mesh_dir: str = "mjcf_meshes",
    free_classes: Iterable[str] = DEFAULT_FREE_CLASSES,
    density: Mapping[str, float] | None = None,
    hinge_holding: float = 2.0,
    timestep: float = 0.002,
    graph: ContactGraph | None = None,
    statics: list | None = None,
    rest: bool = False,
    plan: RestPlan | None = None,
) -> list[Path]:
    """Write ``out_dir/filename`` and its meshes atomically; return the model file first, then the meshes.

    ``statics`` are the room's slabs (:func:`~stratamap.core.simulation.structure.room_structure`);
    ``rest`` places free bodies by the rest plan (``graph`` orders it parents first), or by ``plan``
    when the caller made one; without either, objects start where the map has them (what the
    completion benchmark's physics check measures)."""
    density = density or {}
    free_classes = tuple(free_classes)
    statics = list(statics or [])
    if plan is None:
        plan = rest_offsets(instances, graph, free_classes, statics) if rest else RestPlan()
    free_ids = plan.free_ids(instances, free_classes)
    # Free objects are children of the world in MuJoCo (a free joint must sit on a top-level body).
    tree = build_tree(
        instances,
        None,
        dict(density),
        offsets=plan.offsets,
        statics=statics,
        floating_ids=free_ids,
        rotations=plan.rotations,
        collision=plan.collision,
    )
    root = ET.Element("mujoco", model="stratamap_scene")
    ET.SubElement(root, "compiler", angle="radian", meshdir=mesh_dir, autolimits="true")
    ET.SubElement(root, "option", timestep=f"{timestep:g}", gravity="0 0 -9.81")
    default = ET.SubElement(root, "default")
    ET.SubElement(default, "geom", friction="0.8 0.01 0.001", solref="0.005 1", condim="3")
    asset = ET.SubElement(root, "asset")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos="0 0 3", dir="0 0 -1", directional="true")
    floor_z = 0.0
    for slab in tree.statics:
        if slab.name == "floor":  # the floor is a plane at its top, the walls and ceiling boxes
            floor_z = float(slab.pose[2, 3] + slab.size[2] / 2)
            continue
        ET.SubElement(
            world,
            "geom",
            name=slab.name,
            type="box",
            size=_fmt(np.asarray(slab.size) / 2),
            pos=_fmt(slab.pose[:3, 3]),
            quat=_quat_wxyz(slab.pose),
            rgba="0.85 0.85 0.82 1",
        )
    ET.SubElement(
        world, "geom", name="floor", type="plane", size="50 50 0.1", pos=_fmt([0, 0, floor_z]), rgba="0.6 0.6 0.6 1"
    )
    written: list[Path] = []
    by_parent: dict[str, list] = {}
    for j in tree.joints:
        by_parent.setdefault(j.parent, []).append(j)
    links = {link.name: link for link in tree.links}

    def add_body(parent_el: ET.Element, joint) -> None:
        link = links[joint.child]
        body = ET.SubElement(
            parent_el, "body", name=link.name, pos=_fmt(joint.origin[:3, 3]), quat=_quat_wxyz(joint.origin)
        )
        if joint.parent == ROOT_LINK and joint.type == "floating":
            ET.SubElement(body, "freejoint", name=f"{link.name}_free")
        elif joint.type in ("revolute", "continuous"):
            # Real hinges hold a lid or door where it was left: dry friction above gravity's torque.
            arm = np.linalg.norm(np.cross(link.inertial.center, joint.axis / max(np.linalg.norm(joint.axis), 1e-9)))
            hold = hinge_holding * link.inertial.mass * 9.81 * arm
            attrs = {
                "name": joint.name,
                "type": "hinge",
                "axis": _fmt(joint.axis),
                "damping": "1",
                "frictionloss": f"{hold:.6g}",
            }
            if joint.type == "revolute":
                attrs["range"] = _fmt([joint.lower, joint.upper])
            ET.SubElement(body, "joint", **attrs)
        elif joint.type == "prismatic":
            # A drawer or a chair's gas lift stays where it was left: dry friction above gravity's pull.
            unit = joint.axis / max(np.linalg.norm(joint.axis), 1e-9)
            hold = hinge_holding * link.inertial.mass * 9.81 * max(abs(float((joint.origin[:3, :3] @ unit)[2])), 0.05)
            ET.SubElement(
                body,
                "joint",
                name=joint.name,
                type="slide",
                axis=_fmt(joint.axis),
                range=_fmt([joint.lower, joint.upper]),
                damping="5",
                frictionloss=f"{hold:.6g}",
            )
        i = link.inertial
        evals, evecs = np.linalg.eigh(i.inertia)
        if np.linalg.det(evecs) < 0:
            evecs[:, 0] = -evecs[:, 0]
        frame = np.eye(4)
        frame[:3, :3] = evecs
        ET.SubElement(
            body,
            "inertial",
            pos=_fmt(i.center),
            quat=_quat_wxyz(frame),
            mass=f"{i.mass:.6g}",
            diaginertia=_fmt(np.maximum(evals, 1e-8)),
        )
        for k, shell in enumerate(link_collision(link)):
            mesh_name = f"{link.name}_{k}"
            rel = f"{mesh_name}.stl"
            path = out_dir / mesh_dir / rel
            with atomic_path(path) as tmp:
                shell.export(tmp, file_type="stl")
            written.append(path)
            ET.SubElement(asset, "mesh", name=mesh_name, file=rel)
            ET.SubElement(body, "geom", name=f"{mesh_name}_geom", type="mesh", mesh=mesh_name, density="0")
        for child in by_parent.get(link.name, []):
            add_body(body, child)

    for joint in by_parent.get(ROOT_LINK, []):
        add_body(world, joint)
    ET.indent(root)
    path = out_dir / filename
    write_text(path, ET.tostring(root, encoding="unicode") + "\n")
    return [path, *written]
