"""Exporter ``sdf``: the scene as a Gazebo world (SDFormat 1.9), meshes beside it.

Every object is a model posed in the world; furniture is ``static``, objects of
``bodies.movable_classes`` are not (placed to rest on their support by the rest plan, or static where
they cannot rest); articulated models keep revolute and prismatic joints with limits, and fronts
found by a segmenter hang from the world by their hinge or drawer joint. Floor, walls and ceiling
are the static model ``room``; collision geometry is the meshes' convex parts.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.geometry.transforms import rpy_of
from stratamap.core.simulation.kinematics import ROOT_LINK, link_collision
from stratamap.core.simulation.scene import scene_tree
from stratamap.core.stages import warn_renamed
from stratamap.plugins.exporters._sections import (
    Bodies,
    bodies_section,
    renamed_bodies,
)


def _pose(pose: np.ndarray) -> str:
    return " ".join(f"{float(v):.9g}" for v in (*pose[:3, 3], *rpy_of(pose)))


class SDFConfig(StageConfig):
    filename: str = Field(default="scene.sdf", description="Name of the world file in the export folder.")
    mesh_dir: str = Field(default="sdf_meshes", description="Sub-folder (beside the world) for meshes.")
    world_name: str = Field(default="stratamap_scene", description="The <world name>.")
    bodies: Bodies = bodies_section()

    renamed: ClassVar[Mapping[str, str]] = renamed_bodies("dynamic_classes")


def _joint(model: ET.Element, j, parent: str) -> None:
    joint = ET.SubElement(model, "joint", name=j.name, type={"continuous": "revolute"}.get(j.type, j.type))
    ET.SubElement(joint, "parent").text = parent
    ET.SubElement(joint, "child").text = j.child
    axis = ET.SubElement(joint, "axis")
    ET.SubElement(axis, "xyz").text = " ".join(f"{v:.9g}" for v in j.axis)
    if j.type in ("revolute", "prismatic"):
        limit = ET.SubElement(axis, "limit")
        ET.SubElement(limit, "lower").text = f"{j.lower:.9g}"
        ET.SubElement(limit, "upper").text = f"{j.upper:.9g}"


class SDFExporter(Exporter[SDFConfig]):
    """A Gazebo world (SDFormat): one model per object, static furniture, articulated joints."""

    name = "sdf"
    Config = SDFConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph", "geometry", "semantics"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        warn_renamed(self)
        bodies = cfg.bodies
        tree, plan = scene_tree(
            data.map,
            bodies.movable_classes,
            bodies.density,
            use_graph=False,
            structure=bodies.structure,
            rest=bodies.rest,
        )
        self.note("rest", plan.to_dict())
        sdf = ET.Element("sdf", version="1.9")
        world = ET.SubElement(sdf, "world", name=cfg.world_name)
        if tree.statics:
            room = ET.SubElement(world, "model", name="room")
            ET.SubElement(room, "static").text = "true"
            for slab in tree.statics:
                link = ET.SubElement(room, "link", name=slab.name)
                ET.SubElement(link, "pose").text = _pose(slab.pose)
                for tag in ("collision", "visual"):
                    box = ET.SubElement(ET.SubElement(ET.SubElement(link, tag, name=tag), "geometry"), "box")
                    ET.SubElement(box, "size").text = " ".join(f"{v:.9g}" for v in slab.size)
        else:
            ground = ET.SubElement(world, "model", name="ground_plane")
            ET.SubElement(ground, "static").text = "true"
            gl = ET.SubElement(ground, "link", name="link")
            for tag in ("collision", "visual"):
                el = ET.SubElement(gl, tag, name=tag)
                plane = ET.SubElement(ET.SubElement(el, "geometry"), "plane")
                ET.SubElement(plane, "normal").text = "0 0 1"
                ET.SubElement(plane, "size").text = "100 100"
        links = {link.name: link for link in tree.links}
        children: dict[str, list] = {}
        for j in tree.joints:
            children.setdefault(j.parent, []).append(j)
        written: list[Path] = []
        for top in children.get(ROOT_LINK, []):
            link = links[top.child]
            model = ET.SubElement(world, "model", name=link.name)
            moving = top.type in ("floating", "revolute", "prismatic", "continuous")
            ET.SubElement(model, "static").text = "false" if moving else "true"
            ET.SubElement(model, "pose").text = _pose(top.origin)
            if top.type in ("revolute", "prismatic", "continuous"):  # a front on its hinge or drawer runner
                _joint(model, top, "world")
            stack = [(link.name, np.eye(4))]
            while stack:
                name, pose_in_model = stack.pop()
                lk = links[name]
                el = ET.SubElement(model, "link", name=name)
                ET.SubElement(el, "pose").text = _pose(pose_in_model)
                inertial = ET.SubElement(el, "inertial")
                ET.SubElement(inertial, "pose").text = " ".join(f"{v:.9g}" for v in (*lk.inertial.center, 0, 0, 0))
                ET.SubElement(inertial, "mass").text = f"{lk.inertial.mass:.6g}"
                inertia = ET.SubElement(inertial, "inertia")
                for tag, (r, c) in {
                    "ixx": (0, 0),
                    "ixy": (0, 1),
                    "ixz": (0, 2),
                    "iyy": (1, 1),
                    "iyz": (1, 2),
                    "izz": (2, 2),
                }.items():
                    ET.SubElement(inertia, tag).text = f"{lk.inertial.inertia[r, c]:.6g}"
                if lk.mesh is not None:
                    rel = f"{cfg.mesh_dir}/{name}.stl"
                    with atomic_path(out_dir / rel) as tmp:
                        lk.mesh.export(tmp, file_type="stl")
                    written.append(out_dir / rel)
                    g = ET.SubElement(ET.SubElement(ET.SubElement(el, "visual", name="visual"), "geometry"), "mesh")
                    ET.SubElement(g, "uri").text = rel
                    for k, part in enumerate(link_collision(lk)):
                        rel = f"{cfg.mesh_dir}/{name}_c{k}.stl"
                        with atomic_path(out_dir / rel) as tmp:
                            part.export(tmp, file_type="stl")
                        written.append(out_dir / rel)
                        collision = ET.SubElement(el, "collision", name=f"collision_{k}")
                        g = ET.SubElement(ET.SubElement(collision, "geometry"), "mesh")
                        ET.SubElement(g, "uri").text = rel
                for j in children.get(name, []):
                    _joint(model, j, j.parent)
                    stack.append((j.child, pose_in_model @ j.origin))
        ET.indent(sdf)
        path = out_dir / cfg.filename
        write_text(path, '<?xml version="1.0"?>\n' + ET.tostring(sdf, encoding="unicode") + "\n")
        return [path, *written]


@hookimpl
def stratamap_register_exporters():
    return [SDFExporter]
