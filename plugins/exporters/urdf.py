"""Exporter ``urdf``: the scene as a URDF kinematic tree, meshes beside it.

One link per object (its completion, or the hull of its observed points), joined to its
supporter from the contact graph (or to ``world``), each with visual, collision and inertial
blocks. Mesh paths are relative to the URDF (or ``package://`` URIs when ``package_uri`` is set).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.geometry.transforms import rpy_of
from stratamap.core.simulation.kinematics import ROOT_LINK, build_tree


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
    floating_classes: list[str] = Field(
        default_factory=list,
        description="Classes joined by floating joints (movable objects); others get fixed joints.",
    )
    density: dict[str, float] = Field(default_factory=dict, description="Per-class density overrides, kg/m^3.")


class URDFExporter(Exporter[URDFConfig]):
    """The scene as a URDF: one link per object, joints from the contact graph."""

    name = "urdf"
    Config = URDFConfig
    requires = frozenset({"instances"})
    optional = frozenset({"contact_graph"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        instances, graph = data.map.instances, data.map.contact_graph
        tree = build_tree(instances, graph, cfg.density, set(cfg.floating_classes))  # type: ignore[arg-type]
        robot = ET.Element("robot", name=cfg.robot_name)
        ET.SubElement(robot, "link", name=ROOT_LINK)
        written: list[Path] = []
        for link in tree.links:
            rel = f"{cfg.mesh_dir}/{link.name}.{cfg.mesh_format}"
            with atomic_path(out_dir / rel) as tmp:
                link.mesh.export(tmp, file_type=cfg.mesh_format)
            written.append(out_dir / rel)
            uri = f"{cfg.package_uri.rstrip('/')}/{rel}" if cfg.package_uri else rel
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
            for tag in ("visual", "collision"):
                block = ET.SubElement(el, tag)
                ET.SubElement(block, "origin", xyz="0 0 0", rpy="0 0 0")
                geom = ET.SubElement(block, "geometry")
                ET.SubElement(geom, "mesh", filename=uri)
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
