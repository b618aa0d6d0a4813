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

from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.mesh import read_mesh
from stratamap.core.lazy import lazy_module

rotations = lazy_module("scipy.spatial.transform")

trimesh = lazy_module("trimesh")


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
                    motion[:3, :3] = rotations.Rotation.from_rotvec(j.axis / np.linalg.norm(j.axis) * value).as_matrix()
                elif j.type == "prismatic" and value:
                    motion[:3, 3] = j.axis / np.linalg.norm(j.axis) * value
                poses[j.child] = poses[parent] @ j.origin @ motion
                stack.append(j.child)
        return poses


def _floats(text: str | None, count: int | tuple[int, ...], where: str, default: str | None = None) -> list[float]:
    """``count`` finite numbers from an attribute value, or a DataError naming the file and element."""
    text = default if text is None else text
    counts = (count,) if isinstance(count, int) else count
    try:
        values = [float(v) for v in (text or "").split()]
    except ValueError:
        values = []
    if len(values) not in counts or not all(np.isfinite(values)):
        want = " or ".join(str(c) for c in counts)
        raise DataError(f"{where}: expected {want} finite numbers, got {text!r}"[:300])
    return values


def _origin(el: ET.Element | None, where: str = "origin") -> np.ndarray:
    pose = np.eye(4)
    if el is None:
        return pose
    xyz = _floats(el.get("xyz"), 3, f"{where} xyz", "0 0 0")
    rpy = _floats(el.get("rpy"), 3, f"{where} rpy", "0 0 0")
    pose[:3, :3] = rotations.Rotation.from_euler("xyz", rpy).as_matrix()
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
    try:
        return read_mesh(path, "visual mesh")
    except DataError as exc:  # unreadable or empty meshes fall back to the collision geometry, with a warning
        raise ValueError(str(exc)) from exc


def _geometry(
    geom: ET.Element, urdf_path: Path, roots: dict[str, Path] | None, where: str
) -> tuple[trimesh.Trimesh, str]:
    mesh_el = geom.find("mesh")
    if mesh_el is not None:
        uri = mesh_el.get("filename", "")
        scale = _floats(mesh_el.get("scale"), (1, 3), f"{where} <mesh> scale", "1 1 1")
        path = resolve_uri(uri, urdf_path, roots)
        if not path.is_file():
            raise FileNotFoundError(f"mesh {uri} (looked at {path})")
        mesh = _load_mesh(path)
        mesh.apply_scale(scale if len(scale) == 3 else scale[0])
        return mesh, str(path)
    box = geom.find("box")
    if box is not None:
        size = _floats(box.get("size"), 3, f"{where} <box> size")
        if min(size) < 0:
            raise DataError(f"{where} <box> size must not be negative, got {box.get('size')!r}")
        return trimesh.creation.box(size), "box"
    cyl = geom.find("cylinder")
    if cyl is not None:
        radius = _floats(cyl.get("radius"), 1, f"{where} <cylinder> radius")[0]
        length = _floats(cyl.get("length"), 1, f"{where} <cylinder> length")[0]
        if radius <= 0 or length < 0:
            raise DataError(f"{where} <cylinder>: radius must be positive and length not negative")
        return trimesh.creation.cylinder(radius, length), "cylinder"
    sph = geom.find("sphere")
    if sph is not None:
        radius = _floats(sph.get("radius"), 1, f"{where} <sphere> radius")[0]
        if radius <= 0:
            raise DataError(f"{where} <sphere>: radius must be positive, got {radius}")
        return trimesh.creation.icosphere(radius=radius), "sphere"
    raise ValueError("geometry without mesh, box, cylinder or sphere")


JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


def read_urdf(path: str | Path, package_roots: dict[str, Path] | None = None, load_meshes: bool = True) -> UrdfModel:
    """Parse a URDF; missing or unreadable visual meshes fall back to collision geometry (with a warning).
    Malformed numbers, unknown joint types, repeated names and joints that do not form one tree of links
    are DataErrors naming the file and the element."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: URDF not found")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise DataError(f"{path}: not valid XML ({brief(exc)})") from exc
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot be read as XML ({brief(exc)})") from exc
    if root.tag != "robot":
        raise DataError(f"{path}: root element is <{root.tag}>, expected <robot>")
    model = UrdfModel(root.get("name", path.stem), path)
    for link in root.findall("link"):
        name = link.get("name", "")
        if not name:
            raise DataError(f"{path}: a <link> without a name")
        if name in model.links:
            raise DataError(f"{path}: link {name!r} is defined twice")
        visuals: list[UrdfVisual] = []
        if load_meshes:
            vis_els = link.findall("visual")
            col_els = link.findall("collision")
            for k, vis in enumerate(vis_els):
                geom = vis.find("geometry")
                if geom is None:
                    continue
                where = f"{path}: link {name!r} visual {k}"
                try:
                    mesh, source = _geometry(geom, path, package_roots, where)
                    mesh.apply_transform(_origin(vis.find("origin"), f"{where} <origin>"))
                    visuals.append(UrdfVisual(mesh, source, vis.get("name", "")))
                    continue
                except (FileNotFoundError, ValueError, OSError) as exc:
                    problem = f"link {name!r}: visual {k} unusable ({brief(exc)})"
                fallback = col_els[k] if k < len(col_els) else (col_els[0] if col_els else None)
                try:
                    if fallback is None or fallback.find("geometry") is None:
                        raise ValueError("no collision geometry")
                    where = f"{path}: link {name!r} collision {col_els.index(fallback)}"
                    mesh, source = _geometry(fallback.find("geometry"), path, package_roots, where)  # type: ignore[arg-type]
                    mesh.apply_transform(_origin(fallback.find("origin"), f"{where} <origin>"))
                    visuals.append(UrdfVisual(mesh, source, vis.get("name", "")))
                    model.warnings.append(f"{problem}; using its collision geometry {source}")
                except (FileNotFoundError, ValueError, OSError) as exc:
                    model.warnings.append(
                        f"{problem}; no usable collision geometry either ({brief(exc)}); link left without a mesh"
                    )
        model.links[name] = visuals
    names: set[str] = set()
    for joint in root.findall("joint"):
        jname = joint.get("name", "")
        where = f"{path}: joint {jname!r}"
        if not jname or jname in names:
            raise DataError(f"{where}: every joint needs a name of its own" if jname else f"{path}: a nameless <joint>")
        names.add(jname)
        jtype = joint.get("type", "fixed")
        if jtype not in JOINT_TYPES:
            raise DataError(f"{where}: type {jtype!r} is not one of {', '.join(JOINT_TYPES)}")
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None:
            raise DataError(f"{where}: lacks <parent> or <child>")
        axis_el = joint.find("axis")
        axis = np.array(_floats(axis_el.get("xyz") if axis_el is not None else None, 3, f"{where} <axis>", "1 0 0"))
        if jtype in ("revolute", "continuous", "prismatic") and np.linalg.norm(axis) < 1e-9:
            raise DataError(f"{where}: a {jtype} joint needs a non-zero <axis>")
        limit = joint.find("limit")
        lower = _floats(limit.get("lower"), 1, f"{where} <limit> lower", "0")[0] if limit is not None else 0.0
        upper = _floats(limit.get("upper"), 1, f"{where} <limit> upper", "0")[0] if limit is not None else 0.0
        model.joints.append(
            UrdfJoint(
                jname,
                jtype,
                parent.get("link", ""),
                child.get("link", ""),
                _origin(joint.find("origin"), f"{where} <origin>"),
                axis,
                lower,
                upper,
            )
        )
    _check_tree(model)
    return model


def _check_tree(model: UrdfModel) -> None:
    """Every joint links two defined links, no link has two parents, and all links hang from one root."""
    path = model.path
    parent_of: dict[str, str] = {}
    for j in model.joints:
        for end in (j.parent, j.child):
            if end not in model.links:
                raise DataError(f"{path}: joint {j.name!r} names link {end!r}, which is not defined")
        if j.child in parent_of:
            raise DataError(f"{path}: link {j.child!r} is the child of two joints; a URDF is a tree")
        parent_of[j.child] = j.name
    roots = [name for name in model.links if name not in parent_of]
    if len(roots) != 1:
        raise DataError(f"{path}: expected one root link (a link no joint has as child), found {roots[:10]}")
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    seen, stack = {roots[0]}, [roots[0]]
    while stack:
        for c in children.get(stack.pop(), []):
            if c not in seen:
                seen.add(c)
                stack.append(c)
    unreachable = [name for name in model.links if name not in seen]
    if unreachable:
        raise DataError(f"{path}: links {unreachable[:10]} are not connected to the root {roots[0]!r} (a joint cycle?)")
