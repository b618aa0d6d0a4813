"""Gravity-aligned oriented boxes: fitting, footprints, overlaps and 3D IoU."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module

spatial = lazy_module("scipy.spatial")

trimesh = lazy_module("trimesh")


@dataclass
class OrientedBox:
    """A gravity-aligned box: center, yaw about +z, and size (extent along the box's x, y, z)."""

    center: np.ndarray
    yaw: float
    size: np.ndarray

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.size = np.asarray(self.size, dtype=np.float64).reshape(3)
        self.yaw = float(self.yaw)

    @property
    def pose(self) -> np.ndarray:
        """Box frame to world, at the box center."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        pose = np.eye(4)
        pose[:2, :2] = [[c, -s], [s, c]]
        pose[:3, 3] = self.center
        return pose

    @property
    def bottom_z(self) -> float:
        return float(self.center[2] - self.size[2] / 2)

    @property
    def top_z(self) -> float:
        return float(self.center[2] + self.size[2] / 2)

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Per point (N, 3), whether it lies inside the box grown by ``margin`` (m) on every side."""
        local = (np.asarray(points, dtype=np.float64) - self.center) @ self.pose[:3, :3]
        return np.all(np.abs(local) <= self.size / 2 + margin, axis=1)

    def corners_2d(self) -> np.ndarray:
        """(4, 2) footprint corners in world x, y, counter-clockwise."""
        hx, hy = self.size[0] / 2, self.size[1] / 2
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return local @ np.array([[c, s], [-s, c]]) + self.center[:2]

    def to_mesh(self) -> trimesh.Trimesh:
        return trimesh.creation.box(extents=self.size, transform=self.pose)

    def to_dict(self) -> dict[str, Any]:
        return {"center": self.center.tolist(), "yaw": self.yaw, "size": self.size.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> OrientedBox:
        return cls(d["center"], d["yaw"], d["size"])


def min_area_rectangle(
    xy: np.ndarray, area_slack: float = 0.0, axes: Sequence[float] = (), axes_slack: float = 0.0
) -> tuple[np.ndarray, float, np.ndarray]:
    """Minimum-area enclosing rectangle of 2D points (rotating calipers over the convex hull).

    With ``area_slack`` > 0, among the rectangles at most that fraction larger than the minimum the
    one whose axes the hull's edges follow best (by length) wins: a partly seen counter whose back
    corners are hidden has a slightly smaller tilted rectangle, yet its long front edge gives the
    orientation away. ``axes`` (yaws, radians, modulo 90 degrees: a room's walls) are tried too: the
    smallest rectangle along one of them wins when it is at most ``axes_slack`` larger than the
    minimum (furniture stands square to the walls; a fridge seen from the front and one side, or
    with a strip of the wall beside it, has a tilted rectangle a few per cent smaller). Returns
    ``(center_xy, yaw, size_xy)`` with ``size_xy[0] >= size_xy[1]`` and yaw in [-pi/2, pi/2).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        raise ValueError("min_area_rectangle needs at least one point")
    try:
        hull = xy[spatial.ConvexHull(xy).vertices]
    except (spatial.QhullError, ValueError):
        hull = xy  # collinear or too few points: the edges of the raw set still work
    if len(hull) == 1:
        return hull[0].copy(), 0.0, np.zeros(2)
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    preferred = np.unique(np.mod(np.asarray(axes, dtype=np.float64), np.pi / 2)) if axes_slack > 0 else np.zeros(0)
    n_edges = len(angles)
    angles = np.concatenate([angles, preferred])
    c, s = np.cos(angles), np.sin(angles)
    # Rotate the hull by -angle for every candidate at once: (A, H)
    rx = hull[None, :, 0] * c[:, None] + hull[None, :, 1] * s[:, None]
    ry = -hull[None, :, 0] * s[:, None] + hull[None, :, 1] * c[:, None]
    w = rx.max(1) - rx.min(1)
    h = ry.max(1) - ry.min(1)
    area = w * h
    best = int(np.argmin(area[:n_edges]))
    smallest = area[best]
    if area_slack > 0 and n_edges > 1:
        lengths = np.linalg.norm(edges, axis=1)
        edge_angles = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)
        diff = np.abs(edge_angles[None, :] - angles[:n_edges, None])
        diff = np.minimum(diff, np.pi / 2 - diff)
        support = (lengths[None, :] * (diff < np.radians(2.0))).sum(axis=1)
        near = area[:n_edges] <= smallest * (1 + area_slack)
        best = int(np.flatnonzero(near)[np.argmax(support[near])])
    if len(preferred):
        square = n_edges + int(np.argmin(area[n_edges:]))
        if area[square] <= smallest * (1 + axes_slack):
            best = square
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


def gravity_aligned_box(
    points: np.ndarray,
    z_range: tuple[float, float] | None = None,
    area_slack: float = 0.03,
    axes: Sequence[float] = (),
    axes_slack: float = 0.0,
) -> OrientedBox:
    """The gravity-aligned minimal box of points: footprint by min-area rectangle (see
    :func:`min_area_rectangle` for ``area_slack``, ``axes`` and ``axes_slack``), z from min to max."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    center_xy, yaw, size_xy = min_area_rectangle(points[:, :2], area_slack, axes, axes_slack)
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

        def inside(p: tuple[float, float], a: np.ndarray = a, b: np.ndarray = b) -> bool:
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= -1e-12

        def intersect(
            p: tuple[float, float], q: tuple[float, float], a: np.ndarray = a, b: np.ndarray = b
        ) -> tuple[float, float]:
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
