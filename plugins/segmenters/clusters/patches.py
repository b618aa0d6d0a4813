"""Smooth patches (supervoxels) of the free cells and which adjacent ones meet convexly: the graph
the ``segment`` pass merges (LCCP) and cuts (CPC) on."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from stratamap.plugins.segmenters.clusters.config import ClustersConfig
from stratamap.plugins.segmenters.clusters.grid import linked


def convex_links(
    points: np.ndarray, normals: np.ndarray, pairs: np.ndarray, smooth_deg: float, tolerance: float
) -> np.ndarray:
    """Which neighbour pairs are locally convex or smooth (kept)."""
    i, j = pairs[:, 0], pairs[:, 1]
    diff = points[i] - points[j]
    dist = np.linalg.norm(diff, axis=1)
    convexity = np.einsum("ij,ij->i", normals[i] - normals[j], diff)
    smooth = np.einsum("ij,ij->i", normals[i], normals[j]) >= np.cos(np.radians(smooth_deg))
    return smooth | (convexity >= -tolerance * dist)


class PatchGraph(NamedTuple):
    """Smooth patches (supervoxels) and their adjacency, each edge convex (kept) or concave."""

    patch: np.ndarray  # patch id per point
    centroid: np.ndarray  # (patches, 3)
    normal: np.ndarray  # (patches, 3), unit, facing the sensor
    size: np.ndarray  # points per patch
    edges: np.ndarray  # (edges, 2) adjacent patch pairs
    convex: np.ndarray  # per edge: convex or flat, and most point links across it agree
    crease: np.ndarray  # per edge: concave at the cuts' stricter tolerance (planar cuts follow these)


def patch_graph(
    points: np.ndarray,
    normals: np.ndarray,
    pairs: np.ndarray,
    cfg: ClustersConfig,
    patch_size: float,
    tolerance: float,
    cut_tolerance: float,
) -> PatchGraph:
    """Smooth patches inside coarse cells of side ``patch_size`` (metres), and which adjacent
    patches meet convexly at concavity ``tolerance`` (and at ``cut_tolerance``, for the cuts). A
    patch pair's boundary is convex when the patches' mean normals and centroids say so and most
    point links across it agree; one noisy link cannot join two objects."""
    cell = np.floor(points / patch_size).astype(np.int64)
    same_cell = np.all(cell[pairs[:, 0]] == cell[pairs[:, 1]], axis=1)
    smooth = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) >= np.cos(
        np.radians(cfg.patch_normal_deg)
    )
    patch = linked(len(points), pairs[same_cell & smooth])
    n_patch = int(patch.max()) + 1
    count = np.bincount(patch, minlength=n_patch).astype(float)
    centroid = (
        np.stack([np.bincount(patch, weights=points[:, k], minlength=n_patch) for k in range(3)], 1) / count[:, None]
    )
    normal = np.stack([np.bincount(patch, weights=normals[:, k], minlength=n_patch) for k in range(3)], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    a, b = patch[pairs[:, 0]], patch[pairs[:, 1]]
    between = a != b
    lo, hi = np.minimum(a[between], b[between]), np.maximum(a[between], b[between])
    key = lo * n_patch + hi
    keys, inverse = np.unique(key, return_inverse=True)
    pa, pb = keys // n_patch, keys % n_patch
    diff = centroid[pa] - centroid[pb]
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
    convexity = np.einsum("ij,ij->i", normal[pa] - normal[pb], diff)
    flat = np.einsum("ij,ij->i", normal[pa], normal[pb]) >= np.cos(np.radians(cfg.smooth_deg))

    def kept(tolerance: float) -> np.ndarray:
        link_ok = convex_links(points, normals, pairs[between], cfg.smooth_deg, tolerance)
        votes = np.bincount(inverse, weights=link_ok.astype(float)) / np.bincount(inverse)
        return ((convexity >= -tolerance * dist) | flat) & (votes >= cfg.convex_votes)

    return PatchGraph(
        patch,
        centroid,
        normal,
        count,
        np.stack([pa, pb], 1),
        kept(tolerance),
        ~kept(cut_tolerance),
    )


def convex_segments(graph: PatchGraph) -> np.ndarray:
    """LCCP: patches merged across convex boundaries; a segment id per patch."""
    return linked(len(graph.centroid), graph.edges[graph.convex])
