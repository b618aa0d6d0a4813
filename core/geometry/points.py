"""Point-set helpers: RANSAC planes, voxel downsampling, voxel cell keys and neighbourhoods."""

from __future__ import annotations

import numpy as np

# A voxel itself, then its 26 neighbours by distance (faces, edges, corners).
VOXEL_NEIGHBOURS = np.array(
    sorted(([x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)), key=lambda v: (sum(map(abs, v)), v))
)


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


def first_of_each_row(points: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each distinct row, ascending: ``np.unique(axis=0)``'s
    ``return_index`` sorted, from a 1-D unique of each row's bytes (three times faster on a room's
    300,000 points). Adding 0.0 makes -0.0 and 0.0 one value, as they compare."""
    rows = np.ascontiguousarray(np.asarray(points, dtype=np.float64) + 0.0)
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).reshape(-1)
    return np.sort(np.unique(keys, return_index=True)[1])


#: The bulk of a cloud: per axis, its points between these percentiles (the lower one rounded up,
#: the upper one down, so one stray point of a hundred never becomes a bound).
BULK_PERCENTILES = (1.0, 99.0)
#: A point farther outside the bulk's box than this many times its largest side is a stray (a
#: sensor's glitch at 1e9 m, a float read as garbage): a 30 m room keeps whatever lies within 600 m
#: of it, a window's view of trees 100 m away included.
FAR_FROM_BULK = 20.0
#: Percentiles of more points than this are taken on an even subsample (the same on every run).
BULK_SAMPLE = 1_000_000


def bulk_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) corners of the box that holds the bulk of ``points`` (finite values only;
    ``BULK_PERCENTILES``): bounds that a few stray points cannot stretch."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) > BULK_SAMPLE:
        points = points[:: int(np.ceil(len(points) / BULK_SAMPLE))]
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) == 0:
        return np.zeros(3), np.zeros(3)
    low = np.percentile(points, BULK_PERCENTILES[0], axis=0, method="higher")
    high = np.percentile(points, BULK_PERCENTILES[1], axis=0, method="lower")
    return low, np.maximum(high, low)


def far_from_bulk(points: np.ndarray, factor: float = FAR_FROM_BULK) -> np.ndarray:
    """Per point, whether it lies farther than ``factor`` times the bulk's largest side outside the
    bulk's box (:func:`bulk_box`), or has a NaN or infinite coordinate. A cloud whose bulk is one
    point has no scale to judge by: only its non-finite points are far."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    low, high = bulk_box(points)
    size = float(np.max(high - low))
    far = np.zeros(len(points), bool)
    for k in range(3):  # a column at a time: a 10-million-point cloud needs no (N, 3) temporaries
        column = points[:, k]
        far |= ~np.isfinite(column)
        if size > 0:
            far |= (column < low[k] - factor * size) | (column > high[k] + factor * size)
    return far


#: A cloud whose bulk spans at least this much along every axis, and ``UNIT_HINT_LARGEST`` along one,
#: is no scene in metres a robot maps (200 m tall): it was written in smaller units (a room 2.5 m tall
#: is 250 cm or 2,500 mm; a site a kilometre long but 10 m tall is no hint).
UNIT_HINT_SMALLEST, UNIT_HINT_LARGEST = 200.0, 300.0


def unit_hint(points: np.ndarray) -> str | None:
    """Why ``points`` look written in millimetres or centimetres, with the scale to set, when the
    bulk's extent says so (:data:`UNIT_HINT_SMALLEST`); else None. One stray far point does not
    count: the bulk's box leaves it out."""
    low, high = bulk_box(points)
    spans = high - low
    if spans.min() < UNIT_HINT_SMALLEST or spans.max() < UNIT_HINT_LARGEST:
        return None

    def metres(scale: float) -> str:
        return " x ".join(f"{v * scale:.3g}" for v in spans)

    return (
        f"its bulk spans {' x '.join(f'{v:,.0f}' for v in spans)} units, no scene in metres: millimetres "
        f"(source.params.scale=0.001: {metres(0.001)} m) or centimetres (0.01: {metres(0.01)} m)?"
    )
