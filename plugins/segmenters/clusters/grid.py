"""The working grid and the small geometric helpers every pass of ``clusters`` shares: the grid's
size, cell normals facing the sensor, neighbour pairs, connected components, footprints and 2D
convex hulls."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from stratamap.core import PipelineData
    from stratamap.plugins.segmenters.clusters.config import ClustersConfig


def working_voxel(points: np.ndarray, map_voxel: float | None, cfg: ClustersConfig) -> float:
    """The grid everything scales with: the configured one, the map's, or a raw cloud's spacing
    (median nearest-neighbour distance over an evenly strided sample) times ``spacing_factor``."""
    from scipy.spatial import cKDTree

    from stratamap.core.geometry.points import first_of_each_row

    if cfg.voxel_size is not None:
        return cfg.voxel_size
    if map_voxel:
        return float(map_voxel)
    # Spacing between distinct points: a cloud may hold every point twice (a scan saved with its
    # copy), and a repeated point's nearest neighbour is itself.
    points = points[first_of_each_row(points)]
    if len(points) < 2:
        return 0.01
    sample = points[:: max(1, len(points) // 20000)]
    spacing = cKDTree(points).query(sample, k=2)[0][:, 1]
    spacing = spacing[spacing > 0]
    return float(cfg.spacing_factor * np.median(spacing)) if len(spacing) else 0.01


def source_floor(data: PipelineData) -> float | None:
    """The floor's height where an RGB-D source's gravity alignment found it (z = 0), else None."""
    stream = data.stream
    alignment = stream.metadata.get("gravity_alignment") if stream is not None else None
    return 0.0 if alignment and alignment.get("floor_inliers", 0) > 0 else None


def estimate_normals(points: np.ndarray, radius: float, views: np.ndarray) -> np.ndarray:
    """PCA normals within ``radius`` (Open3D), each turned to face the nearest of ``views``."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    normals = np.asarray(cloud.normals).copy()
    nearest = views[cKDTree(views).query(points)[1]]
    flip = np.einsum("ij,ij->i", normals, nearest - points) < 0
    normals[flip] *= -1
    return normals


def linked(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component id per node of the graph of ``pairs`` (float-weighted, any number of pairs)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = (
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else coo_matrix((n, n))
    )
    # int64: patch-pair keys are products of patch ids, which overflow int32 past 46,341 patches
    return connected_components(graph, directed=False)[1].astype(np.int64)


def cell_normals(cells: np.ndarray, radius: float) -> np.ndarray:
    """Unoriented PCA normals of cell centres within ``radius`` (Open3D; each point's own
    neighbourhood, so the result does not depend on threads)."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cells))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    return np.asarray(cloud.normals).copy()


def neighbour_pairs(cells: np.ndarray, radius: float) -> np.ndarray:
    """Pairs (i < j) of cells closer than ``radius`` (a k-d tree; linear in the cells for a surface)."""
    from scipy.spatial import cKDTree

    if len(cells) < 2:
        return np.zeros((0, 2), np.int64)
    return cKDTree(cells).query_pairs(radius, output_type="ndarray").astype(np.int64)


def components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component id (int64) per node of an undirected graph given by its edge pairs."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


#: Smallest grid cell (m) on which a floor's size is measured.
AREA_CELL = 0.05


def footprint_area(xy: np.ndarray, cell: float) -> float:
    """Area (m^2) of the grid squares of side ``cell`` that points ``xy`` occupy."""
    if len(xy) == 0:
        return 0.0
    ij = np.floor(xy / cell).astype(np.int64)
    ij -= ij.min(axis=0)
    keys = np.unique(ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1])  # one integer per square: a 1-D unique
    return float(len(keys) * cell * cell)


def hull_equations(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-planes ``a @ p + b <= 0`` of the 2D convex hull of ``xy`` (a point's box if degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        eq = ConvexHull(xy).equations
        return eq[:, :2], eq[:, 2]
    except (QhullError, ValueError):
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        return np.array([[1.0, 0], [-1, 0], [0, 1], [0, -1]]), np.array([-hi[0], lo[0], -hi[1], lo[1]])


def share_within(xy: np.ndarray, around: np.ndarray, margin: float = 0.05) -> float:
    """The share of points ``xy`` within ``margin`` (m) of the convex hull of ``around`` (top view)."""
    a, b = hull_equations(around)
    return float(((xy @ a.T + b) <= margin).all(axis=1).mean())
