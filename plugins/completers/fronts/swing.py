"""Room to open: a side-hinged door hinges where it can swing open.

The kitchen paper hinges a door opposite its handle, and a door without a telling handle on the side
where its face ends (``core/furniture/faces.hinge_side``). Both are guesses a scan can get wrong: a
handle seen near the middle of a narrow door, or a door in the corner of an L of units, whose face
ends against the other run. A door hinged there swings into that run, in a simulator as in the room.
So each side-hinged door's swing is sampled, in the top view, on both hinge sides: the panel at
opening angles up to :data:`SWING_SHARE` of its range. When the side chosen swings into the box of a
fixed neighbour (an object of no movable class, or a wall) and the other side swings into less than
half as much, the door hinges on the other side.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: The share of a door's range its swing is sampled to: the opening a simulator check asks for.
SWING_SHARE = 0.9
#: How far (m) a swing may reach into a neighbour's box before it counts: fitted boxes are loose.
TOLERANCE = 0.01
#: Opening angles and points along the panel sampled per swing.
ANGLES, RADII = 9, 8
OTHER_SIDE = {"left": "right", "right": "left"}


def swing_blocked(
    rect: tuple[float, float, float, float],
    hinge: str,
    y_face: float,
    opening: float,
    pose: np.ndarray,
    obstacles: Sequence[tuple[np.ndarray, np.ndarray]],
) -> float:
    """The share of the sampled positions of a door's panel that lie in an obstacle's box.

    ``rect`` is the door's ``(x0, x1, z0, z1)`` in the object frame (``pose``: object-to-world; the
    face at ``y = y_face``, the room at lower y), ``hinge`` ``"left"`` (at x0) or ``"right"`` (at x1);
    ``obstacles`` are ``(pose, size)`` boxes in the world, their z axis up."""
    x0, x1, z0, z1 = rect
    width = x1 - x0
    if width <= 0 or not len(obstacles):
        return 0.0
    angles = np.linspace(0.0, SWING_SHARE * opening, ANGLES + 1)[1:]
    radii = np.linspace(0.0, width, RADII + 1)[1:]
    a, r = np.meshgrid(angles, radii, indexing="ij")
    hinge_x, along = (x0, 1.0) if hinge == "left" else (x1, -1.0)
    local = np.stack([hinge_x + along * r.ravel() * np.cos(a.ravel()), y_face - r.ravel() * np.sin(a.ravel())], 1)
    world = local @ pose[:2, :2].T + pose[:2, 3]
    door_z = pose[2, 3] + np.array([z0, z1])
    inside = np.zeros(len(world), bool)
    for o_pose, o_size in obstacles:
        half = np.asarray(o_size, float) / 2
        o_z = o_pose[2, 3] + np.array([-half[2], half[2]])
        if min(door_z[1], o_z[1]) - max(door_z[0], o_z[0]) <= TOLERANCE:
            continue
        q = (world - o_pose[:2, 3]) @ o_pose[:2, :2]
        inside |= (np.abs(q) < half[:2] - TOLERANCE).all(axis=1)
    return float(inside.mean())


def room_to_open(
    rects: list[tuple[tuple[float, float, float, float], str, str | None, Any]],
    y_face: float,
    opening: float,
    pose: np.ndarray,
    obstacles: Sequence[tuple[np.ndarray, np.ndarray]],
) -> tuple[list[tuple[tuple[float, float, float, float], str, str | None, Any]], list[dict[str, Any]]]:
    """``rects`` (as :func:`articulated_body` takes them) with each side-hinged door that swings into
    a neighbour on the side chosen, and into less than half as much on the other, hinged on the
    other; and a note per door turned (its index, the sides, the shares of its swing blocked)."""
    out, turned = [], []
    for k, (rect, label, hinge, fixtures) in enumerate(rects):
        if hinge in OTHER_SIDE:
            mine = swing_blocked(rect, hinge, y_face, opening, pose, obstacles)
            if mine > 0:
                other = swing_blocked(rect, OTHER_SIDE[hinge], y_face, opening, pose, obstacles)
                if other < mine / 2:
                    blocked = [round(mine, 3), round(other, 3)]
                    turned.append({"front": k, "from": hinge, "to": OTHER_SIDE[hinge], "blocked": blocked})
                    hinge = OTHER_SIDE[hinge]
        out.append((rect, label, hinge, fixtures))
    return out, turned
