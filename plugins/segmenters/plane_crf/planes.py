"""Planar decomposition of indoor scans (the kitchen paper, section III).

* :func:`multilod_planes` -- planes found by MSAC with sampling localized in octree cells, from
  the coarsest level to the finest (big planes first, then what is left in smaller cells); each
  plane found in a cell is refined by growing its support over the neighbouring cells and
  refitting (least squares), and coplanar neighbours are merged at the end.
* :func:`boundary_points` and :func:`region_grow` -- each plane's inliers split into connected
  regions; boundary points (an angular gap in their in-plane neighbourhood) stop the growth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.furniture.faces import plane_axes, radius_components
from stratamap.core.geometry.points import cell_keys
from stratamap.core.lazy import lazy_module

spatial = lazy_module("scipy.spatial")

# --------------------------------------------------------------------------------------------
# Planes


@dataclass
class Plane:
    normal: np.ndarray  # unit, oriented to +z for horizontal planes
    d: float  # n . x + d = 0
    indices: np.ndarray  # point indices


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[2]
    if n[2] < 0 or (abs(n[2]) < 1e-9 and n[0] < 0):
        n = -n
    return n, float(-n @ c)


def _msac(
    points: np.ndarray,
    normals: np.ndarray,
    threshold: float,
    normal_cos: float,
    iterations: int,
    rng: np.random.Generator,
    chunk: int = 32,
) -> tuple[np.ndarray, float, np.ndarray] | None:
    """MSAC: the plane minimizing the truncated quadratic loss; inliers also agree in normal."""
    n_pts = len(points)
    if n_pts < 3:
        return None
    s = rng.integers(0, n_pts, size=(iterations, 3))
    nrm = np.cross(points[s[:, 1]] - points[s[:, 0]], points[s[:, 2]] - points[s[:, 0]])
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-9
    nrm = nrm[ok] / length[ok, None]
    anchor = points[s[ok, 0]]
    agree = np.abs(np.einsum("ij,ij->i", nrm, normals[s[ok, 0]])) >= normal_cos  # the sample's own normal must agree
    nrm, anchor = nrm[agree], anchor[agree]
    if len(nrm) == 0:
        return None
    offs = -np.einsum("ij,ij->i", nrm, anchor)
    t2 = threshold * threshold
    costs = np.empty(len(nrm))
    for a in range(0, len(nrm), chunk):
        r = points @ nrm[a : a + chunk].T + offs[a : a + chunk]  # (N, c)
        c = np.minimum(r * r, t2)
        c[np.abs(normals @ nrm[a : a + chunk].T) < normal_cos] = t2
        costs[a : a + chunk] = c.sum(0)
    k = int(np.argmin(costs))
    n, d = nrm[k], float(offs[k])
    inl = np.flatnonzero((np.abs(points @ n + d) < threshold) & (np.abs(normals @ n) >= normal_cos))
    if len(inl) < 3:
        return None
    n, d = _fit_plane(points[inl])
    inl = np.flatnonzero((np.abs(points @ n + d) < threshold) & (np.abs(normals @ n) >= normal_cos))
    return n, d, inl


def multilod_planes(
    points: np.ndarray,
    normals: np.ndarray,
    cell_sizes: tuple[float, ...] = (2.0, 1.0, 0.5),
    threshold: float = 0.02,
    normal_deg: float = 25.0,
    min_points: int = 60,
    iterations: int = 150,
    merge_deg: float = 5.0,
    merge_offset: float = 0.02,
    adjacency: float = 0.05,
    seed: int = 0,
) -> list[Plane]:
    """Planes by octree-localized MSAC, coarse to fine; see the module doc."""
    rng = np.random.default_rng(seed)
    normal_cos = float(np.cos(np.radians(normal_deg)))
    free = np.ones(len(points), bool)
    planes: list[Plane] = []
    for size in cell_sizes:
        keys = np.floor(points / size).astype(np.int64)
        flat = cell_keys(points, size)
        changed = True
        while changed:
            changed = False
            idx_free = np.flatnonzero(free)
            if len(idx_free) < min_points:
                break
            _, first, inverse, counts = np.unique(
                flat[idx_free], return_index=True, return_inverse=True, return_counts=True
            )
            cells = keys[idx_free[first]]
            inverse = inverse.reshape(-1)
            order = np.lexsort((np.arange(len(cells)), -counts))  # fullest cells first (deterministic)
            for ci in order:
                if counts[ci] < min_points:
                    break
                members = idx_free[inverse == ci]
                members = members[free[members]]
                if len(members) < min_points:
                    continue
                found = _msac(points[members], normals[members], threshold, normal_cos, iterations, rng)
                if found is None or len(found[2]) < min_points:
                    continue
                nrm, d, _ = found
                # refine: grow the plane over the 3x3x3 neighbouring cells and refit, twice
                near = np.flatnonzero(free & np.all(np.abs(keys - cells[ci]) <= 1, axis=1))
                for _ in range(2):
                    ok = (np.abs(points[near] @ nrm + d) < threshold) & (np.abs(normals[near] @ nrm) >= normal_cos)
                    if ok.sum() < 3:
                        break
                    nrm, d = _fit_plane(points[near[ok]])
                inl = near[(np.abs(points[near] @ nrm + d) < threshold) & (np.abs(normals[near] @ nrm) >= normal_cos)]
                inl = _largest_components(points, inl, adjacency, min_points)
                if len(inl) < min_points:
                    continue
                planes.append(Plane(nrm, d, inl))
                free[inl] = False
                changed = True
    return merge_planes(points, planes, merge_deg, merge_offset, adjacency)


def _largest_components(points: np.ndarray, idx: np.ndarray, radius: float, min_points: int) -> np.ndarray:
    """The connected pieces (within ``radius``) of ``idx`` that have at least ``min_points``."""
    if len(idx) == 0:
        return idx
    comp = radius_components(points[idx], radius)
    sizes = np.bincount(comp)
    return idx[sizes[comp] >= min_points]


def merge_planes(
    points: np.ndarray, planes: list[Plane], merge_deg: float, merge_offset: float, adjacency: float
) -> list[Plane]:
    """Union of planes that are parallel (``merge_deg``), at the same offset and touching."""
    if len(planes) < 2:
        return planes
    parent = list(range(len(planes)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    trees = [spatial.cKDTree(points[p.indices]) for p in planes]
    cos = np.cos(np.radians(merge_deg))
    for i in range(len(planes)):
        for j in range(i + 1, len(planes)):
            a, b = planes[i], planes[j]
            if abs(a.normal @ b.normal) < cos:
                continue
            ci, cj = points[a.indices].mean(0), points[b.indices].mean(0)
            if abs(a.normal @ cj + a.d) > merge_offset or abs(b.normal @ ci + b.d) > merge_offset:
                continue
            if trees[i].count_neighbors(trees[j], adjacency) == 0:
                continue
            parent[find(j)] = find(i)
    groups: dict[int, list[int]] = {}
    for i in range(len(planes)):
        groups.setdefault(find(i), []).append(i)
    out = []
    for members in groups.values():
        idx = np.sort(np.concatenate([planes[m].indices for m in members]))
        n, d = _fit_plane(points[idx]) if len(members) > 1 else (planes[members[0]].normal, planes[members[0]].d)
        out.append(Plane(n, d, idx))
    return out


def boundary_points(
    points: np.ndarray, normal: np.ndarray, radius: float, k: int = 12, gap_deg: float = 90.0
) -> np.ndarray:
    """Points whose in-plane neighbours leave an angular gap wider than ``gap_deg`` (PCL's
    boundary estimation): the rim of a surface, where region growing must stop."""
    n = len(points)
    if n < 4:
        return np.ones(n, bool)
    u, v = plane_axes(normal)
    uv = np.stack([points @ u, points @ v], 1)
    dist, nb = spatial.cKDTree(uv).query(uv, k=min(k + 1, n), distance_upper_bound=radius)
    nb = nb[:, 1:]
    valid = np.isfinite(dist[:, 1:])
    safe = np.where(valid, nb, 0)
    delta = uv[safe] - uv[:, None, :]
    ang = np.sort(np.where(valid, np.arctan2(delta[..., 1], delta[..., 0]), 100.0), axis=1)  # invalid last
    count = valid.sum(1)
    gaps = np.diff(ang, axis=1)
    gaps = np.where(np.arange(gaps.shape[1])[None, :] + 1 < count[:, None], gaps, 0.0)
    first = ang[:, 0]
    last = np.take_along_axis(ang, np.maximum(count - 1, 0)[:, None], 1)[:, 0]
    wrap = np.where(count > 0, 2 * np.pi - (last - first), 2 * np.pi)
    widest = np.maximum(gaps.max(axis=1) if gaps.shape[1] else 0.0, wrap)
    return (count < 3) | (widest > np.radians(gap_deg))


def region_grow(points: np.ndarray, boundary: np.ndarray, radius: float) -> np.ndarray:
    """Regions of one plane's inliers: interior points connect within ``radius``; boundary
    points stop the growth and join their nearest interior region. Labels 0..R-1."""
    inner = np.flatnonzero(~boundary)
    labels = np.zeros(len(points), np.int64)
    if len(inner) == 0:
        return labels
    labels[inner] = radius_components(points[inner], radius)
    if boundary.any():
        _, nearest = spatial.cKDTree(points[inner]).query(points[boundary])
        labels[boundary] = labels[inner][nearest]
    return labels
