"""Exporter ``sdf``: the scene as a Gazebo world (SDFormat 1.9), meshes beside it.

Every object is a model posed in the world; furniture on the floor is ``static``, objects of
``dynamic_classes`` are not; articulated models keep revolute and prismatic joints with limits.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from pydantic import Field

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.geometry.transforms import rpy_of
from stratamap.core.simulation.kinematics import ROOT_LINK, build_tree


def _pose(pose: np.ndarray) -> str:
    return " ".join(f"{float(v):.9g}" for v in (*pose[:3, 3], *rpy_of(pose)))


class SDFConfig(StageConfig):
    filename: str = Field(default="scene.sdf", description="Name of the world file in the export folder.")
    mesh_dir: str = Field(default="sdf_meshes", description="Sub-folder (beside the world) for meshes.")
    world_name: str = Field(default="stratamap_scene", description="The <world name>.")
    dynamic_classes: list[str] = Field(
        default_factory=lambda: ["chair", "box", "book", "cup", "bottle", "laptop", "monitor", "plant"],
        description="Classes simulated as dynamic (not static) models.",
    )
    density: dict[str, float] = Field(default_factory=dict, description="Per-class density overrides, kg/m^3.")


class SDFExporter(Exporter[SDFConfig]):
    """A Gazebo world (SDFormat): one model per object, static furniture, articulated joints."""

    name = "sdf"
    Config = SDFConfig
    requires = frozenset({"instances"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        tree = build_tree(data.map.instances, None, cfg.density)  # type: ignore[arg-type]
        sdf = ET.Element("sdf", version="1.9")
        world = ET.SubElement(sdf, "world", name=cfg.world_name)
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
            ET.SubElement(model, "static").text = "false" if link.class_name in cfg.dynamic_classes else "true"
            ET.SubElement(model, "pose").text = _pose(top.origin)
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
                rel = f"{cfg.mesh_dir}/{name}.stl"
                with atomic_path(out_dir / rel) as tmp:
                    lk.mesh.export(tmp, file_type="stl")
                written.append(out_dir / rel)
                for tag in ("collision", "visual"):
                    g = ET.SubElement(ET.SubElement(ET.SubElement(el, tag, name=tag), "geometry"), "mesh")
                    ET.SubElement(g, "uri").text = rel
                for j in children.get(name, []):
                    joint = ET.SubElement(
                        model, "joint", name=j.name, type={"continuous": "revolute"}.get(j.type, j.type)
                    )
                    ET.SubElement(joint, "parent").text = j.parent
                    ET.SubElement(joint, "child").text = j.child
                    axis = ET.SubElement(joint, "axis")
                    ET.SubElement(axis, "xyz").text = " ".join(f"{v:.9g}" for v in j.axis)
                    if j.type in ("revolute", "prismatic"):
                        limit = ET.SubElement(axis, "limit")
                        ET.SubElement(limit, "lower").text = f"{j.lower:.9g}"
                        ET.SubElement(limit, "upper").text = f"{j.upper:.9g}"
                    stack.append((j.child, pose_in_model @ j.origin))
        ET.indent(sdf)
        path = out_dir / cfg.filename
        write_text(path, '<?xml version="1.0"?>\n' + ET.tostring(sdf, encoding="unicode") + "\n")
        return [path, *written]


@hookimpl
def stratamap_register_exporters():
    return [SDFExporter]
