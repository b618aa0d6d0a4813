"""Small geometric helpers shared by stages: boxes, footprints, overlaps."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from stratamap.core.layers import OrientedBox

# A voxel itself, then its 26 neighbours by distance (faces, edges, corners).
VOXEL_NEIGHBOURS = np.array(sorted(([x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)), key=lambda v: (sum(map(abs, v)), v)))


def min_area_rectangle(xy: np.ndarray, area_slack: float = 0.0) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimum-area enclosing rectangle of 2D points (rotating calipers over the convex hull).

    With ``area_slack`` > 0, among the rectangles at most that fraction larger than the minimum the
    one whose axes the hull's edges follow best (by length) wins: a partly seen counter whose back
    corners are hidden has a slightly smaller tilted rectangle, yet its long front edge gives the
    orientation away. Returns ``(center_xy, yaw, size_xy)`` with ``size_xy[0] >= size_xy[1]`` and
    yaw in [-pi/2, pi/2).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        raise ValueError("min_area_rectangle needs at least one point")
    try:
        hull = xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):
        hull = xy  # collinear or too few points: the edges of the raw set still work
    if len(hull) == 1:
        return hull[0].copy(), 0.0, np.zeros(2)
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    c, s = np.cos(angles), np.sin(angles)
    # Rotate the hull by -angle for every candidate at once: (A, H)
    rx = hull[None, :, 0] * c[:, None] + hull[None, :, 1] * s[:, None]
    ry = -hull[None, :, 0] * s[:, None] + hull[None, :, 1] * c[:, None]
    w = rx.max(1) - rx.min(1)
    h = ry.max(1) - ry.min(1)
    area = w * h
    best = int(np.argmin(area))
    if area_slack > 0 and len(angles) > 1:
        lengths = np.linalg.norm(edges, axis=1)
        edge_angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)
        diff = np.abs(edge_angles[None, :] - angles[:, None])
        diff = np.minimum(diff, np.pi / 2 - diff)
        support = (lengths[None, :] * (diff < np.radians(2.0))).sum(axis=1)
        near = area <= area[best] * (1 + area_slack)
        best = int(np.flatnonzero(near)[np.argmax(support[near])])
    a = angles[best]
    cx_r = (rx[best].max() + rx[best].min()) / 2
    cy_r = (ry[best].max() + ry[best].min()) / 2
    center = np.array([cx_r * np.cos(a) - cy_r * np.sin(a), cx_r * np.sin(a) + cy_r * np.cos(a)])
    size = np.array([w[best], h[best]])
    if size[1] > size[0]:
        size = size[::-1].copy()
        a += np.pi / 2
    yaw = (a + np.pi / 2) % np.pi - np.pi / 2
    return center, float(yaw), size


def gravity_aligned_box(points: np.ndarray, z_range: tuple[float, float] | None = None, area_slack: float = 0.03) -> OrientedBox:
    """The gravity-aligned minimal box of points: footprint by min-area rectangle (see
    :func:`min_area_rectangle` for ``area_slack``), z from min to max."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    center_xy, yaw, size_xy = min_area_rectangle(points[:, :2], area_slack)
    z0, z1 = z_range if z_range is not None else (points[:, 2].min(), points[:, 2].max())
    return OrientedBox(np.array([center_xy[0], center_xy[1], (z0 + z1) / 2]), yaw, np.array([*size_xy, z1 - z0]))


def footprint_overlap(a: OrientedBox, b: OrientedBox) -> float:
    """Area of the intersection of two box footprints (m^2), by polygon clipping."""
    return polygon_area(clip_polygon(a.corners_2d(), b.corners_2d()))


def polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def clip_polygon(subject: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman clipping of a polygon by a convex counter-clockwise polygon."""
    output = [tuple(p) for p in subject]
    n = len(clip)
    for i in range(n):
        a, b = clip[i], clip[(i + 1) % n]
        inputs, output = output, []
        if not inputs:
            break

        def inside(p: tuple[float, float]) -> bool:
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= -1e-12

        def intersect(p: tuple[float, float], q: tuple[float, float]) -> tuple[float, float]:
            d1 = np.subtract(q, p)
            d2 = b - a
            denom = d1[0] * d2[1] - d1[1] * d2[0]
            if abs(denom) < 1e-15:
                return q
            t = ((a[0] - p[0]) * d2[1] - (a[1] - p[1]) * d2[0]) / denom
            return (p[0] + t * d1[0], p[1] + t * d1[1])

        prev = inputs[-1]
        for cur in inputs:
            if inside(cur):
                if not inside(prev):
                    output.append(intersect(prev, cur))
                output.append(cur)
            elif inside(prev):
                output.append(intersect(prev, cur))
            prev = cur
    return np.array(output, dtype=np.float64).reshape(-1, 2)


def box_iou_3d(a: OrientedBox, b: OrientedBox) -> float:
    """IoU of two gravity-aligned boxes (exact: footprint polygon intersection times z overlap)."""
    inter_xy = footprint_overlap(a, b)
    inter_z = max(0.0, min(a.top_z, b.top_z) - max(a.bottom_z, b.bottom_z))
    inter = inter_xy * inter_z
    union = float(np.prod(a.size) + np.prod(b.size)) - inter
    return inter / union if union > 0 else 0.0


def ransac_plane(
    points: np.ndarray, distance: float, iterations: int = 500, seed: int = 0, chunk: int = 64
) -> tuple[np.ndarray, float, np.ndarray]:
    """Deterministic RANSAC plane fit: (unit normal, d with n.x + d = 0, inlier indices).

    Seeded numpy sampling and a least-squares refit on the best inlier set; unlike Open3D's
    parallel ``segment_plane`` the result is the same on every run.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n < 3:
        raise ValueError("ransac_plane needs at least 3 points")
    rng = np.random.default_rng(seed)
    best_count, best = -1, (np.array([0.0, 0.0, 1.0]), 0.0)
    for start in range(0, iterations, chunk):
        k = min(chunk, iterations - start)
        idx = rng.integers(0, n, size=(k, 3))
        a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
        normals = np.cross(b - a, c - a)
        norm = np.linalg.norm(normals, axis=1)
        ok = norm > 1e-12
        if not ok.any():
            continue
        normals = normals[ok] / norm[ok, None]
        d = -np.einsum("ij,ij->i", normals, a[ok])
        counts = (np.abs(points @ normals.T + d) < distance).sum(0)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best_count, best = int(counts[j]), (normals[j], float(d[j]))
    normal, d = best
    for _ in range(2):  # refit on the inliers, then re-select them
        inliers = np.flatnonzero(np.abs(points @ normal + d) < distance)
        if len(inliers) < 3:
            break
        centroid = points[inliers].mean(0)
        _, _, vt = np.linalg.svd(points[inliers] - centroid, full_matrices=False)
        normal = vt[2] if np.dot(vt[2], normal) >= 0 else -vt[2]
        d = -float(np.dot(normal, centroid))
    inliers = np.flatnonzero(np.abs(points @ normal + d) < distance)
    return normal, d, inliers


def voxel_downsample(points: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell means of a cubic grid of side ``size``, and for every input point the index of its
    cell (deterministic, numpy only; cells in lexicographic order of their grid coordinates)."""
    _, inverse = np.unique(cell_keys(points, size), return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse)
    means = np.stack([np.bincount(inverse, weights=points[:, k]) / counts for k in range(3)], axis=1)
    return means, inverse


def cell_keys(points: np.ndarray, size: float) -> np.ndarray:
    """One int64 per point naming its cubic cell of side ``size``."""
    k = np.floor(points / size).astype(np.int64)
    k -= k.min(axis=0)
    span = k.max(axis=0) + 1
    return (k[:, 0] * span[1] + k[:, 1]) * span[2] + k[:, 2]
