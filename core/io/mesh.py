"""Mesh files (OBJ, PLY, STL, OFF, GLB, DAE, ...), read with trimesh and checked: a mesh that cannot be
parsed, has no triangles, non-finite vertices or faces that index missing vertices is a :class:`DataError`
naming the file and what was expected (a PLY is first verified against its header, as point clouds are);
writing goes through an atomic temporary file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.atomic import atomic_path
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.io.pointcloud import read_ply
from stratamap.core.lazy import lazy_module

trimesh = lazy_module("trimesh")


def check_mesh(vertices: Any, faces: Any, where: str) -> None:
    """Raise a DataError (``where: ...``) unless ``faces`` are (F, 3) indices into the finite (V, 3) ``vertices``."""
    v, f = np.asarray(vertices), np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise DataError(f"{where}: vertices have shape {v.shape}, expected (V, 3)")
    if f.ndim != 2 or f.shape[1] != 3:
        raise DataError(f"{where}: faces have shape {f.shape}, expected (F, 3) triangles")
    if len(f) == 0:
        raise DataError(f"{where}: no triangles")
    if not np.all(np.isfinite(v)):
        raise DataError(f"{where}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices are NaN or infinite")
    if f.min() < 0 or f.max() >= len(v):
        bad = f[(f < 0) | (f >= len(v))][0]
        raise DataError(f"{where}: a face uses vertex index {bad}, but there are {len(v)} vertices (0..{len(v) - 1})")


def read_mesh(path: str | Path, what: str = "mesh") -> Any:
    """A ``trimesh.Trimesh`` (scenes are concatenated; nothing is merged or reordered), checked with
    :func:`check_mesh`; ``what`` says in errors what the mesh is for."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: {what} file missing")
    if path.suffix.lower() == ".ply":  # trimesh reads a cut or malformed PLY silently: check it against its header
        read_ply(path.read_bytes(), path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh's loaders raise many types (IndexError, ValueError, KeyError, ...)
        raise DataError(f"{path}: cannot be read as a {what} ({brief(exc, True)})") from exc
    if not isinstance(loaded, trimesh.Trimesh):
        raise DataError(f"{path}: holds no triangle mesh (got {type(loaded).__name__}); expected a {what}")
    check_mesh(loaded.vertices, loaded.faces, str(path))
    return loaded


def _vertex_colors(mesh: Any) -> np.ndarray | None:
    colors = getattr(mesh.visual, "vertex_colors", None) if getattr(mesh.visual, "kind", None) == "vertex" else None
    return None if colors is None or len(colors) != len(mesh.vertices) else np.asarray(colors)


def read_vertices_only(path: str | Path) -> tuple[np.ndarray, np.ndarray | None] | None:
    """The vertices (and their colours in [0, 1]) of a mesh file that holds points and no faces (an OBJ
    of ``v`` lines only, as some scanners and photogrammetry tools export clouds; a glTF of POINTS);
    None when the file holds faces, or nothing trimesh reads as points."""
    path = Path(path)
    try:
        loaded = trimesh.load(path, process=False)
    except Exception:  # read_mesh reports what is wrong with the file
        return None
    parts = [loaded]
    if isinstance(loaded, trimesh.Scene):  # each part where the scene puts it
        parts = [loaded.geometry[n].copy().apply_transform(loaded.graph[n][0]) for n in loaded.graph.nodes_geometry]
    # A faceless Trimesh is the same (trimesh reads an OFF of vertices only so).
    parts = [
        trimesh.points.PointCloud(g.vertices, colors=_vertex_colors(g))
        if isinstance(g, trimesh.Trimesh) and len(g.vertices) and not len(g.faces)
        else g
        for g in parts
    ]
    if not parts or not all(isinstance(g, trimesh.points.PointCloud) for g in parts):
        return None
    points = np.concatenate([np.asarray(g.vertices, np.float64) for g in parts])
    colors = None
    if all(len(getattr(g, "colors", [])) == len(g.vertices) for g in parts):
        colors = np.concatenate([np.asarray(g.colors, np.float64)[:, :3] / 255.0 for g in parts])
    return (points, colors) if len(points) else None


def write_mesh(mesh: Any, path: str | Path, file_type: str | None = None) -> Path:
    """Export ``mesh`` atomically; the type follows the suffix unless ``file_type`` is given."""
    path = Path(path)
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type=file_type or path.suffix.lstrip(".").lower())
    return path


#: Files read as meshes by point-cloud readers (a PLY is one when it declares faces).
MESH_SUFFIXES = (".obj", ".stl", ".off", ".glb", ".gltf")


def is_mesh_file(path: str | Path) -> bool:
    """Whether ``path`` holds a surface mesh rather than points: a mesh format, or a PLY declaring faces."""
    from stratamap.core.io.pointcloud import parse_ply_header

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in MESH_SUFFIXES:
        return True
    if suffix != ".ply" or not path.is_file():
        return False
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    try:
        face = parse_ply_header(head, path).element("face")
    except DataError:
        return False  # the point-cloud reader reports what is wrong with it
    return face is not None and face.count > 0


def sample_surface(
    mesh: Any, spacing: float, max_points: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """Points on ``mesh``'s surface, one per ``spacing``² of area on average (area-weighted, seeded: the
    same points every run), with the mesh's colours where it has them (vertex or face colours, or its
    texture); at most ``max_points``. Returns (points, colours in [0, 1] or None, the spacing used)."""
    area = float(mesh.area)
    if not np.isfinite(area) or area <= 0:
        raise DataError("the mesh has no surface area (all its triangles are degenerate)")
    count = int(np.ceil(area / spacing**2))
    used = spacing
    if count > max_points:
        count = max_points
        used = float(np.sqrt(area / count))
    kind = getattr(mesh.visual, "kind", None)
    if kind in ("vertex", "face", "texture"):
        points, faces, colors = trimesh.sample.sample_surface(mesh, count, sample_color=True, seed=seed)
        if colors is not None and len(colors) == len(points):
            return np.asarray(points, np.float64), np.asarray(colors, np.float64)[:, :3] / 255.0, used
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points, np.float64), None, used
