"""Ground-truth occupancy of a scene: 3D voxels in a height band, and its 2D projections.

A voxel is occupied when any part of any object, or a wall, intersects it: voxel centers inside a
part count (exact inside test per closed part), and so do voxels that dense surface samples of the
part fall into (so thin parts such as chair legs are never missed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import OccupancyGrid
from stratamap.core.synthetic.scene import Scene

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")
trimesh = lazy_module("trimesh")


@dataclass
class VoxelOccupancy:
    occupied: np.ndarray  # (nz, ny, nx) bool
    origin: np.ndarray  # world coordinates of the corner of voxel (0, 0, 0)
    resolution: float

    def project(self) -> OccupancyGrid:
        """Occupied where any voxel of the column is; free elsewhere (a fully known grid)."""
        cells = np.where(self.occupied.any(axis=0), 100, 0).astype(np.int8)
        return OccupancyGrid(cells, self.resolution, (float(self.origin[0]), float(self.origin[1]), 0.0))


def _occupancy(meshes: list[trimesh.Trimesh], lo: np.ndarray, shape: tuple[int, int, int], res: float) -> np.ndarray:
    nz, ny, nx = shape
    occ = np.zeros(shape, bool)
    hi = lo + np.array([nx, ny, nz]) * res
    for k, mesh in enumerate(meshes):
        mlo, mhi = mesh.bounds
        if np.any(mhi < lo) or np.any(mlo > hi):
            continue
        # Voxel centers inside this closed part.
        i0 = np.clip(np.floor((mlo - lo) / res).astype(int), 0, [nx, ny, nz])
        i1 = np.clip(np.ceil((mhi - lo) / res).astype(int), 0, [nx, ny, nz])
        if np.all(i1 > i0):
            xs, ys, zs = (lo[d] + (np.arange(i0[d], i1[d]) + 0.5) * res for d in range(3))
            grid = np.stack(np.meshgrid(zs, ys, xs, indexing="ij"), -1).reshape(-1, 3)[:, ::-1]
            if mesh.is_watertight and len(grid):
                scene = o3d.t.geometry.RaycastingScene()
                scene.add_triangles(
                    o3c.Tensor(mesh.vertices.astype(np.float32)), o3c.Tensor(mesh.faces.astype(np.uint32))
                )
                inside = scene.compute_occupancy(o3c.Tensor(grid.astype(np.float32))).numpy() > 0.5
                sub = occ[i0[2] : i1[2], i0[1] : i1[1], i0[0] : i1[0]]
                sub |= inside.reshape(sub.shape)
        # Surface samples catch parts thinner than a voxel.
        count = int(np.clip(mesh.area / (res / 3) ** 2, 64, 50000))
        pts, _ = trimesh.sample.sample_surface(mesh, count, seed=k)
        idx = np.floor((pts - lo) / res).astype(int)
        keep = np.all((idx >= 0) & (idx < [nx, ny, nz]), axis=1)
        occ[idx[keep, 2], idx[keep, 1], idx[keep, 0]] = True
    return occ


def scene_occupancy(scene: Scene, z_min: float, z_max: float, resolution: float, margin: float = 0.2) -> VoxelOccupancy:
    """Voxels between ``z_min`` and ``z_max`` over the room (plus ``margin``, so walls show)."""
    lx, ly, _ = scene.room_size
    lo = np.array([-margin, -margin, z_min])
    shape = (
        max(1, int(np.ceil((z_max - z_min) / resolution))),
        int(np.ceil((ly + 2 * margin) / resolution)),
        int(np.ceil((lx + 2 * margin) / resolution)),
    )
    meshes = [mesh for class_name, _, mesh, _ in scene.all_meshes() if class_name not in ("floor", "ceiling")]
    return VoxelOccupancy(_occupancy(meshes, lo, shape, resolution), lo, resolution)
