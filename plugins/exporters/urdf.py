"""Exporter ``urdf``: the scene as a URDF kinematic tree, meshes beside it.

One link per object (its completion, or the hull of its observed points), joined to its
supporter from the contact graph (or to ``world``), each with inertial, visual (the whole mesh)
and collision blocks (one per convex part). Objects of ``bodies.movable_classes`` hang from ``world`` by
floating joints, placed to rest on their support; articulated parts and segmented fronts keep
revolute and prismatic joints with limits; floor, walls and ceiling are static box links. Mesh
paths are relative to the URDF (or ``package://`` URIs when ``package_uri`` is set).

PyBullet turns floating joints into fixed ones; :func:`stratamap.core.simulation.bullet.load_scene`
loads each free body as its own multibody.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import ClassVar, Literal

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


def _fmt(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def _origin(parent: ET.Element, pose: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=_fmt(pose[:3, 3]), rpy=_fmt(rpy_of(pose)))


class URDFConfig(StageConfig):
    filename: str = Field(default="scene.urdf", description="Name of the URDF file in the export folder.")
    robot_name: str = Field(default="stratamap_scene", description="The <robot name> of the URDF.")
    mesh_dir: str = Field(default="meshes", description="Sub-folder (beside the URDF) for link meshes.")
    mesh_format: Literal["stl", "obj"] = Field(
        default="stl", description="Mesh file format for visual and collision geometry."
    )
    package_uri: str | None = Field(
        default=None,
        description="If set (e.g. 'package://my_scene'), mesh paths are written as '<package_uri>/<mesh_dir>/...'.",
    )
    bodies: Bodies = bodies_section()

    renamed: ClassVar[Mapping[str, str]] = renamed_bodies("movable_classes")


class URDFExporter(Exporter[URDFConfig]):
    """The scene as a URDF: one link per object, joints from the contact graph."""

    name = "urdf"
    Config = URDFConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph", "geometry", "semantics"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        warn_renamed(self)
        bodies = cfg.bodies
        tree, plan = scene_tree(
            data.map, bodies.movable_classes, bodies.density, structure=bodies.structure, rest=bodies.rest
        )
        self.note("rest", plan.to_dict())
        robot = ET.Element("robot", name=cfg.robot_name)
        ET.SubElement(robot, "link", name=ROOT_LINK)
        written: list[Path] = []

        def mesh_file(mesh, stem: str) -> str:
            rel = f"{cfg.mesh_dir}/{stem}.{cfg.mesh_format}"
            with atomic_path(out_dir / rel) as tmp:
                mesh.export(tmp, file_type=cfg.mesh_format)
            written.append(out_dir / rel)
            return f"{cfg.package_uri.rstrip('/')}/{rel}" if cfg.package_uri else rel

        for link in tree.links:
            el = ET.SubElement(robot, "link", name=link.name)
            inertial = ET.SubElement(el, "inertial")
            ET.SubElement(inertial, "origin", xyz=_fmt(link.inertial.center), rpy="0 0 0")
            ET.SubElement(inertial, "mass", value=f"{link.inertial.mass:.6g}")
            i = link.inertial.inertia
            ET.SubElement(
                inertial, "inertia",
                ixx=f"{i[0, 0]:.6g}", ixy=f"{i[0, 1]:.6g}", ixz=f"{i[0, 2]:.6g}",
                iyy=f"{i[1, 1]:.6g}", iyz=f"{i[1, 2]:.6g}", izz=f"{i[2, 2]:.6g}",
            )  # fmt: skip
            if link.mesh is None:  # a helper frame between two joints
                continue
            block = ET.SubElement(el, "visual")
            ET.SubElement(block, "origin", xyz="0 0 0", rpy="0 0 0")
            ET.SubElement(ET.SubElement(block, "geometry"), "mesh", filename=mesh_file(link.mesh, link.name))
            # Simulators collide convex hulls: one collision block per convex part.
            for k, part in enumerate(link_collision(link)):
                block = ET.SubElement(el, "collision", name=f"{link.name}_collision_{k}")
                ET.SubElement(block, "origin", xyz="0 0 0", rpy="0 0 0")
                ET.SubElement(ET.SubElement(block, "geometry"), "mesh", filename=mesh_file(part, f"{link.name}_c{k}"))
        for slab in tree.statics:
            el = ET.SubElement(robot, "link", name=slab.name)
            inertial = ET.SubElement(el, "inertial")  # fixed to the world; the values only keep loaders quiet
            ET.SubElement(inertial, "mass", value="1")
            ET.SubElement(inertial, "inertia", ixx="1", ixy="0", ixz="0", iyy="1", iyz="0", izz="1")
            for tag in ("visual", "collision"):
                block = ET.SubElement(el, tag)
                ET.SubElement(block, "origin", xyz="0 0 0", rpy="0 0 0")
                ET.SubElement(ET.SubElement(block, "geometry"), "box", size=_fmt(slab.size))
            joint = ET.SubElement(robot, "joint", name=f"{slab.name}_joint", type="fixed")
            _origin(joint, slab.pose)
            ET.SubElement(joint, "parent", link=ROOT_LINK)
            ET.SubElement(joint, "child", link=slab.name)
        for joint in tree.joints:
            el = ET.SubElement(robot, "joint", name=joint.name, type=joint.type)
            _origin(el, joint.origin)
            ET.SubElement(el, "parent", link=joint.parent)
            ET.SubElement(el, "child", link=joint.child)
            if joint.type in ("revolute", "prismatic", "continuous"):
                ET.SubElement(el, "axis", xyz=_fmt(joint.axis))
                ET.SubElement(
                    el, "limit", lower=f"{joint.lower:.6g}", upper=f"{joint.upper:.6g}", effort="100", velocity="1"
                )
        ET.indent(robot)
        path = out_dir / cfg.filename
        write_text(path, '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n")
        return [path, *written]


@hookimpl
def stratamap_register_exporters():
    return [URDFExporter]
