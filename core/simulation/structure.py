"""The room itself for simulators: floor, walls and ceiling as static boxes.

A map knows its layout as labelled points (the stuff classes ``floor``, ``wall``, ``ceiling`` of
its semantics) in a gravity-aligned frame. The floor is a slab whose top is the floor height (the
median height of floor points, else z = 0) under the whole mapped extent; every wall is a slab
behind a vertical plane found by RANSAC among the wall points, spanning the points it holds
(along the wall) and from the floor to its highest point; the ceiling is a slab above the median
height of ceiling points. Slabs lie outside the room (behind the observed surface), so an object
touching a wall or standing on the floor starts in contact, not inside.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from stratamap.core.geometry.points import ransac_plane, voxel_downsample
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.layers import LayeredMap

#: Thickness of the floor, wall and ceiling slabs (metres).
SLAB_THICKNESS = 0.1
#: Margin of the floor (and ceiling) slab around the mapped extent (metres).
FLOOR_MARGIN = 0.5
#: RANSAC inlier distance for wall planes, and the fewest points (and share of wall points) a wall holds.
WALL_DISTANCE = 0.04
MIN_WALL_POINTS = 100
MIN_WALL_SHARE = 0.03
MAX_WALLS = 12


@dataclass
class StaticBox:
    """A static slab: ``pose`` is its centre's pose in the world, ``size`` its full extents."""

    name: str
    class_name: str
    pose: np.ndarray
    size: np.ndarray


def _class_points(layered: LayeredMap, class_name: str) -> np.ndarray:
    geometry, semantics = layered.geometry, layered.semantics
    if geometry is None or semantics is None or class_name not in semantics.vocabulary:
        return np.zeros((0, 3))
    if len(semantics) != len(geometry.points):
        return np.zeros((0, 3))
    return geometry.points[semantics.class_ids == semantics.vocabulary.id(class_name)]


def _extent(layered: LayeredMap) -> tuple[np.ndarray, np.ndarray]:
    """xy bounds of everything mapped (geometry and objects)."""
    chunks = []
    if layered.geometry is not None and len(layered.geometry.points):
        chunks.append(layered.geometry.points[:, :2])
    for inst in layered.instances or []:
        chunks.append(inst.box.corners_2d())
    if not chunks:
        return np.array([-5.0, -5.0]), np.array([5.0, 5.0])
    xy = np.concatenate(chunks)
    return xy.min(0), xy.max(0)


def floor_height(layered: LayeredMap) -> float:
    """Median height of the floor points, else 0 (gravity-aligned maps put the floor at z = 0)."""
    floor = _class_points(layered, "floor")
    return float(np.median(floor[:, 2])) if len(floor) >= 20 else 0.0


_STRUCTURE_CACHE: dict[str, list[StaticBox]] = {}


def room_structure(layered: LayeredMap, seed: int = 0) -> list[StaticBox]:
    """Floor (always), walls and ceiling (when the map has their points) as static slabs."""
    digest = hashlib.sha1(str(seed).encode())
    if layered.geometry is not None:
        digest.update(np.ascontiguousarray(layered.geometry.points).tobytes())
    if layered.semantics is not None:
        digest.update(np.ascontiguousarray(layered.semantics.class_ids).tobytes())
        digest.update(" ".join(layered.semantics.vocabulary.names).encode())
    for inst in layered.instances or []:
        digest.update(np.ascontiguousarray(inst.box.corners_2d()).tobytes())
    key = digest.hexdigest()
    if key not in _STRUCTURE_CACHE:
        if len(_STRUCTURE_CACHE) >= 16:
            _STRUCTURE_CACHE.pop(next(iter(_STRUCTURE_CACHE)))
        _STRUCTURE_CACHE[key] = _room_structure(layered, seed)
    return [StaticBox(b.name, b.class_name, b.pose.copy(), b.size.copy()) for b in _STRUCTURE_CACHE[key]]


def _room_structure(layered: LayeredMap, seed: int) -> list[StaticBox]:
    lo, hi = _extent(layered)
    lo, hi = lo - FLOOR_MARGIN, hi + FLOOR_MARGIN
    center_xy = (lo + hi) / 2
    floor_z = floor_height(layered)
    boxes = [
        StaticBox(
            "floor",
            "floor",
            make_pose((*center_xy, floor_z - SLAB_THICKNESS / 2)),
            np.array([*(hi - lo), SLAB_THICKNESS]),
        )
    ]
    ceiling = _class_points(layered, "ceiling")
    ceiling_z = float(np.median(ceiling[:, 2])) if len(ceiling) >= 20 else None
    if ceiling_z is not None and ceiling_z > floor_z + 1.0:
        boxes.append(
            StaticBox(
                "ceiling",
                "ceiling",
                make_pose((*center_xy, ceiling_z + SLAB_THICKNESS / 2)),
                np.array([*(hi - lo), SLAB_THICKNESS]),
            )
        )
    walls = _class_points(layered, "wall")
    if len(walls) >= MIN_WALL_POINTS:
        walls, _ = voxel_downsample(walls, 0.05)
        room_center = np.append(center_xy, 0.0)
        remaining = walls
        min_points = max(MIN_WALL_POINTS // 4, int(MIN_WALL_SHARE * len(walls)))
        for k in range(MAX_WALLS * 2):
            if len(remaining) < min_points or sum(b.class_name == "wall" for b in boxes) >= MAX_WALLS:
                break
            normal, d, inliers = ransac_plane(remaining, WALL_DISTANCE, seed=seed + k)
            if len(inliers) < min_points:
                break
            on_plane, remaining = remaining[inliers], np.delete(remaining, inliers, axis=0)
            if abs(normal[2]) > 0.15:  # not a wall plane (a sill, a slanted patch): drop its points
                continue
            normal = np.array([normal[0], normal[1], 0.0]) / np.linalg.norm(normal[:2])
            d = -float(np.median(on_plane @ normal))
            if room_center @ normal + d > 0:  # the normal points into the room
                outward = -normal
            else:
                outward = normal
            along = np.cross([0.0, 0.0, 1.0], outward)
            u = on_plane @ along
            u0, u1 = np.percentile(u, [1, 99])
            top = float(on_plane[:, 2].max()) if ceiling_z is None else ceiling_z
            if u1 - u0 < 0.3 or top - floor_z < 0.5:
                continue
            surface = float(np.median(on_plane @ outward))
            center = along * (u0 + u1) / 2 + outward * (surface + SLAB_THICKNESS / 2)
            center[2] = (floor_z + top) / 2
            yaw = float(np.arctan2(along[1], along[0]))
            name = f"wall_{sum(b.class_name == 'wall' for b in boxes)}"
            boxes.append(
                StaticBox(name, "wall", make_pose(center, yaw), np.array([u1 - u0, SLAB_THICKNESS, top - floor_z]))
            )
    return boxes
