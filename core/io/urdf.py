"""A URDF reader for articulated models (PartNet-Mobility objects, kitchens, exported scenes).

It resolves ``package://NAME/...`` URIs against given package roots (or by walking up from the
URDF to a folder called NAME), reports missing meshes and falls back to the link's collision
geometry (or primitive shapes) so a model with a few absent visual files still loads.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from stratamap.core.errors import DataError


@dataclass
class UrdfVisual:
    mesh: trimesh.Trimesh  # in the link frame (visual origin and scale applied)
    source: str  # file or primitive name
    name: str = ""


@dataclass
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # child link frame in the parent link frame at q = 0
    axis: np.ndarray
    lower: float = 0.0
    upper: float = 0.0


@dataclass
class UrdfModel:
    name: str
    path: Path
    links: dict[str, list[UrdfVisual]] = field(default_factory=dict)
    joints: list[UrdfJoint] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints}
        roots = [name for name in self.links if name not in children]
        if len(roots) != 1:
            raise DataError(f"{self.path}: expected one root link, found {roots}")
        return roots[0]

    def link_poses(self, q: dict[str, float] | None = None) -> dict[str, np.ndarray]:
        """Link frames in the root frame at joint positions ``q`` (default all 0)."""
        q = q or {}
        poses = {self.root: np.eye(4)}
        by_parent: dict[str, list[UrdfJoint]] = {}
        for j in self.joints:
            by_parent.setdefault(j.parent, []).append(j)
        stack = [self.root]
        while stack:
            parent = stack.pop()
            for j in by_parent.get(parent, []):
                motion = np.eye(4)
                value = q.get(j.name, 0.0)
                if j.type in ("revolute", "continuous") and value:
                    motion[:3, :3] = Rotation.from_rotvec(j.axis / np.linalg.norm(j.axis) * value).as_matrix()
                elif j.type == "prismatic" and value:
                    motion[:3, 3] = j.axis / np.linalg.norm(j.axis) * value
                poses[j.child] = poses[parent] @ j.origin @ motion
                stack.append(j.child)
        return poses


def _origin(el: ET.Element | None) -> np.ndarray:
    pose = np.eye(4)
    if el is None:
        return pose
    xyz = [float(v) for v in el.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in el.get("rpy", "0 0 0").split()]
    pose[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    pose[:3, 3] = xyz
    return pose


def resolve_uri(uri: str, urdf_path: Path, package_roots: dict[str, Path] | None = None) -> Path:
    """A mesh path from a URDF: relative to the URDF, ``file://``, or ``package://NAME/...``."""
    if uri.startswith("file://"):
        return Path(uri[len("file://") :])
    if uri.startswith("package://"):
        rest = uri[len("package://") :]
        package, _, rel = rest.partition("/")
        if package_roots and package in package_roots:
            return Path(package_roots[package]) / rel
        for parent in urdf_path.resolve().parents:
            if parent.name == package or (parent / "package.xml").is_file() and _package_name(parent) == package:
                return parent / rel
        return urdf_path.parent / rel
    path = Path(uri)
    return path if path.is_absolute() else urdf_path.parent / path


def _package_name(folder: Path) -> str | None:
    try:
        root = ET.parse(folder / "package.xml").getroot()
        name = root.find("name")
        return name.text.strip() if name is not None and name.text else None
    except (ET.ParseError, OSError):
        return None


def _load_mesh(path: Path) -> trimesh.Trimesh:
    loaded = trimesh.load(path, force="mesh", process=False)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError("no triangles")
    return loaded


def _geometry(geom: ET.Element, urdf_path: Path, roots: dict[str, Path] | None) -> tuple[trimesh.Trimesh, str]:
    mesh_el = geom.find("mesh")
    if mesh_el is not None:
        uri = mesh_el.get("filename", "")
        path = resolve_uri(uri, urdf_path, roots)
        if not path.is_file():
            raise FileNotFoundError(f"mesh {uri} (looked at {path})")
        mesh = _load_mesh(path)
        scale = mesh_el.get("scale")
        if scale:
            mesh.apply_scale([float(v) for v in scale.split()])
        return mesh, str(path)
    box = geom.find("box")
    if box is not None:
        return trimesh.creation.box([float(v) for v in box.get("size", "0 0 0").split()]), "box"
    cyl = geom.find("cylinder")
    if cyl is not None:
        return trimesh.creation.cylinder(float(cyl.get("radius", 0)), float(cyl.get("length", 0))), "cylinder"
    sph = geom.find("sphere")
    if sph is not None:
        return trimesh.creation.icosphere(radius=float(sph.get("radius", 0))), "sphere"
    raise ValueError("geometry without mesh, box, cylinder or sphere")


def read_urdf(path: str | Path, package_roots: dict[str, Path] | None = None, load_meshes: bool = True) -> UrdfModel:
    """Parse a URDF; missing or unreadable visual meshes fall back to collision geometry (with a warning)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: URDF not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DataError(f"{path}: not valid XML ({exc})") from exc
    if root.tag != "robot":
        raise DataError(f"{path}: root element is <{root.tag}>, expected <robot>")
    model = UrdfModel(root.get("name", path.stem), path)
    for link in root.findall("link"):
        name = link.get("name", "")
        visuals: list[UrdfVisual] = []
        if load_meshes:
            vis_els = link.findall("visual")
            col_els = link.findall("collision")
            for k, vis in enumerate(vis_els):
                geom = vis.find("geometry")
                if geom is None:
                    continue
                try:
                    mesh, source = _geometry(geom, path, package_roots)
                    mesh.apply_transform(_origin(vis.find("origin")))
                    visuals.append(UrdfVisual(mesh, source, vis.get("name", "")))
                    continue
                except (FileNotFoundError, ValueError, OSError) as exc:
                    problem = f"link {name!r}: visual {k} unusable ({exc})"
                fallback = col_els[k] if k < len(col_els) else (col_els[0] if col_els else None)
                try:
                    if fallback is None or fallback.find("geometry") is None:
                        raise ValueError("no collision geometry")
                    mesh, source = _geometry(fallback.find("geometry"), path, package_roots)  # type: ignore[arg-type]
                    mesh.apply_transform(_origin(fallback.find("origin")))
                    visuals.append(UrdfVisual(mesh, source, vis.get("name", "")))
                    model.warnings.append(f"{problem}; using its collision geometry {source}")
                except (FileNotFoundError, ValueError, OSError) as exc:
                    model.warnings.append(
                        f"{problem}; no usable collision geometry either ({exc}); link left without a mesh"
                    )
        model.links[name] = visuals
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise DataError(f"{path}: joint {joint.get('name')!r} lacks <parent> or <child>")
        axis_el = joint.find("axis")
        axis = np.array([float(v) for v in (axis_el.get("xyz", "1 0 0") if axis_el is not None else "1 0 0").split()])
        limit = joint.find("limit")
        lower = float(limit.get("lower", 0)) if limit is not None else 0.0
        upper = float(limit.get("upper", 0)) if limit is not None else 0.0
        model.joints.append(
            UrdfJoint(
                joint.get("name", ""),
                joint.get("type", "fixed"),
                parent.get("link", ""),
                child.get("link", ""),
                _origin(joint.find("origin")),
                axis,
                lower,
                upper,
            )
        )
    for j in model.joints:
        for end in (j.parent, j.child):
            if end not in model.links:
                raise DataError(f"{path}: joint {j.name!r} names link {end!r}, which is not defined")
    return model
