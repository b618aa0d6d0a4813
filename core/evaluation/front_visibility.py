"""Which true doors and drawers a walk saw from the front, for the ``articulation`` family's
``recall_large_seen``: issue 66 asks that every large front the walk sees from the front be found,
and a walk that never faced a unit cannot be blamed for its drawers.

A true joint's front is the face of its moving part (at joint position 0) across a drawer's slide or
a door's thinnest side, on the side it opens towards (``articulation.opening_motion``). GRID x GRID
points spread over it (inset by INSET of its size, set OFFSET_M out from it) are seen by a frame
where they fall in its image, its measured depth there is not nearer than the point by more than
OCCLUSION_M (nothing stands in between; the front itself lies just behind the point) and the frame
looks at the face within FRONT_ANGLE_DEG of its normal. The front is seen from the front when at
least SEEN_SHARE of its points were, over up to MAX_FRAMES frames spread evenly over the walk.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Sample points along each side of a front.
GRID = 6
#: Share of the front's size left out at each edge (a handle, a neighbour's gap).
INSET = 0.1
#: How far (m) the points stand out from the face: the front itself is measured just behind them.
OFFSET_M = 0.01
#: A depth this much (m) nearer than the point is something in between.
OCCLUSION_M = 0.05
#: The farthest angle (degrees) between the face's normal and the direction to the camera.
FRONT_ANGLE_DEG = 60.0
#: The share of a front's points seen for the front to count as seen.
SEEN_SHARE = 0.5
#: Frames looked at, evenly spread over the walk.
MAX_FRAMES = 120


def front_face(joint: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """A true joint's front as sample points (GRID², world) and its outward normal; None where the
    moving part's box or the way it opens is unknown."""
    from stratamap.core.evaluation.articulation import opening_motion

    if joint.part_size is None or joint.part_axes is None or joint.part_center is None:
        return None
    axes = np.asarray(joint.part_axes, float)
    size = np.asarray(joint.part_size, float)
    motion = opening_motion(joint)
    if motion is None:
        return None
    across = int(np.argmax(np.abs(axes.T @ joint.axis))) if joint.type == "prismatic" else int(np.argmin(size))
    normal = axes[:, across] if float(axes[:, across] @ motion) >= 0.0 else -axes[:, across]
    side = [k for k in range(3) if k != across]
    steps = np.linspace(-0.5 + INSET, 0.5 - INSET, GRID)
    a, b = np.meshgrid(steps, steps, indexing="ij")
    centre = np.asarray(joint.part_center, float) + normal * (size[across] / 2.0 + OFFSET_M)
    points = (
        centre
        + a.reshape(-1, 1) * size[side[0]] * axes[:, side[0]]
        + b.reshape(-1, 1) * size[side[1]] * axes[:, side[1]]
    )
    return points, normal


def seen_from_front(joints: list[Any], stream: Any) -> list[bool | None] | None:
    """For each true joint, whether the stream's posed depth frames saw its front from the front
    (None where its front is unknown); None for a stream without posed depth frames."""
    from stratamap.core.map.sensors import posed_depth_frames

    faces = [front_face(j) for j in joints]
    seen = [np.zeros(GRID * GRID, bool) if face is not None else None for face in faces]
    cos_front = np.cos(np.radians(FRONT_ANGLE_DEG))
    intr = getattr(stream, "intrinsics", None)
    used = 0
    for depth, pose in posed_depth_frames(stream, MAX_FRAMES):
        used += 1
        eye = pose[:3, 3]
        for face, hits in zip(faces, seen, strict=True):
            if face is None:
                continue
            points, normal = face
            cam = (points - eye) @ pose[:3, :3]  # world -> camera (z forward)
            z = cam[:, 2]
            ahead = z > 0.05
            u = np.full(len(z), -1, np.int64)
            v = np.full(len(z), -1, np.int64)
            u[ahead] = np.round(intr.fx * cam[ahead, 0] / z[ahead] + intr.cx).astype(np.int64)
            v[ahead] = np.round(intr.fy * cam[ahead, 1] / z[ahead] + intr.cy).astype(np.int64)
            inside = ahead & (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
            measured = np.full(len(z), np.nan, np.float32)
            measured[inside] = depth[v[inside], u[inside]]
            clear = np.isfinite(measured) & (measured > 0) & (measured >= z - OCCLUSION_M)
            towards = eye - points
            towards /= np.linalg.norm(towards, axis=1, keepdims=True)
            hits |= inside & clear & (towards @ normal >= cos_front)
    if not used:
        return None
    return [None if hits is None else bool(hits.mean() >= SEEN_SHARE) for hits in seen]
