"""The augmented scene (augmented-representations paper, section IV-B3): A = (G \\ S) U O, where S
are the points of the geometry G within ``epsilon`` of a completed model and O the completed models
sampled on their surfaces. The completers build it; the physical check rebuilds it after it moves
or swaps models, so both give the same scene for the same placements.
"""

from __future__ import annotations

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Geometry, ObjectInstances

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")
trimesh = lazy_module("trimesh")


def augmented_scene(
    geometry: Geometry | None, instances: ObjectInstances, epsilon: float, spacing: float
) -> Geometry | None:
    """A = (G \\ S) U O: observed points near completed models are replaced by the models."""
    completed = instances.completed()
    if geometry is None:
        return None
    if not completed:
        return Geometry(
            points=geometry.points.copy(),
            colors=None if geometry.colors is None else geometry.colors.copy(),
            mesh=geometry.mesh,
        )
    scene = o3d.t.geometry.RaycastingScene()
    model_pts, model_cols = [], []
    meshes = []
    for inst in completed:
        world = inst.completion.world_mesh()  # type: ignore[union-attr]
        meshes.append(world)
        scene.add_triangles(o3c.Tensor(world.vertices.astype(np.float32)), o3c.Tensor(world.faces.astype(np.uint32)))
        count = int(np.clip(world.area / spacing**2, 64, 20000))
        pts, _ = trimesh.sample.sample_surface(world, count, seed=inst.id)
        model_pts.append(pts)
        color = (
            np.mean(inst.colors, axis=0) if inst.colors is not None and len(inst.colors) else np.array([0.6, 0.6, 0.6])
        )
        model_cols.append(np.tile(color, (len(pts), 1)))
    dist = scene.compute_distance(o3c.Tensor(geometry.points.astype(np.float32))).numpy()
    keep = dist > epsilon
    points = np.vstack([geometry.points[keep], *model_pts])
    colors = None
    if geometry.colors is not None:
        colors = np.vstack([geometry.colors[keep], *model_cols])
    mesh = None
    if geometry.mesh is not None:
        g = geometry.mesh
        vd = scene.compute_distance(o3c.Tensor(np.asarray(g.vertices, dtype=np.float32))).numpy()
        face_keep = (vd[g.faces] > epsilon).all(axis=1)
        kept = g.copy()
        kept.update_faces(face_keep)
        kept.remove_unreferenced_vertices()
        mesh = trimesh.util.concatenate([kept, *meshes])
    return Geometry(points=points, colors=colors, mesh=mesh, voxel_size=geometry.voxel_size)
