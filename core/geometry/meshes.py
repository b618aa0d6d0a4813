"""Points against triangle meshes, with Open3D's ray-casting scene."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")


def raycasting_scene(mesh: Any) -> Any:
    """An Open3D ray-casting scene of ``mesh`` (a trimesh; distances to it, rays against it)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3c.Tensor(np.asarray(mesh.vertices, dtype=np.float32)), o3c.Tensor(np.asarray(mesh.faces, dtype=np.uint32))
    )
    return scene


def surface_distances(points: np.ndarray, mesh: Any) -> np.ndarray:
    """Distance (m) of each of ``points`` from the surface of ``mesh`` (same frame); infinite when the
    mesh has no faces."""
    if len(points) == 0 or len(mesh.faces) == 0:
        return np.full(len(points), np.inf)
    return raycasting_scene(mesh).compute_distance(o3c.Tensor(np.asarray(points, dtype=np.float32))).numpy()
