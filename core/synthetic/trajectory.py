"""Camera paths through a scene: a teleoperated-robot walk through free space, an orbit, a fixed view."""

from __future__ import annotations

import numpy as np

from stratamap.core.geometry.transforms import look_at
from stratamap.core.lazy import lazy_module
from stratamap.core.synthetic.scene import Scene
from stratamap.core.synthetic.spec import TrajectorySpec

ndimage = lazy_module("scipy.ndimage")

GRID = 0.05


def free_space(scene: Scene, clearance: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) from each cell to the nearest obstacle or wall, and the grid's origin."""
    lx, ly, _ = scene.room_size
    shape = (int(np.ceil(ly / GRID)), int(np.ceil(lx / GRID)))
    occupied = np.zeros(shape, bool)
    for obj in scene.objects:
        for _, mesh in obj.world_parts():
            lo, hi = mesh.bounds
            if lo[2] > 2.0:
                continue
            r0, c0 = int(np.floor(lo[1] / GRID)), int(np.floor(lo[0] / GRID))
            r1, c1 = int(np.ceil(hi[1] / GRID)), int(np.ceil(hi[0] / GRID))
            occupied[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = True
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    dist = ndimage.distance_transform_edt(~occupied) * GRID
    return dist, np.zeros(2)


def _resample_loop(points: np.ndarray, n: int) -> np.ndarray:
    closed = np.vstack([points, points[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    t = np.linspace(0, s[-1], n, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, k]) for k in range(2)], 1)


def walk(scene: Scene, spec: TrajectorySpec, rng: np.random.Generator) -> list[np.ndarray]:
    """A loop around the room, kept ``clearance`` from obstacles, looking toward the room's middle."""
    lx, ly, _ = scene.room_size
    dist, _ = free_space(scene, spec.clearance)
    ok = dist >= spec.clearance
    inset = np.array([min(1.0, lx / 2 - 0.05), min(1.0, ly / 2 - 0.05)])
    corners = np.array(
        [[inset[0], inset[1]], [lx - inset[0], inset[1]], [lx - inset[0], ly - inset[1]], [inset[0], ly - inset[1]]]
    )
    loop = _resample_loop(corners, 400)
    if ok.any():
        # Move every waypoint to the nearest cell with enough clearance.
        _, (ri, ci) = ndimage.distance_transform_edt(~ok, return_indices=True)
        rc = np.clip(np.floor(loop[:, ::-1] / GRID).astype(int), 0, np.array(ok.shape) - 1)
        loop = np.stack([ci[rc[:, 0], rc[:, 1]], ri[rc[:, 0], rc[:, 1]]], 1) * GRID + GRID / 2
    # Smooth the loop (circular moving average) and resample at even spacing.
    k = 15
    padded = np.vstack([loop[-k:], loop, loop[:k]])
    kernel = np.ones(2 * k + 1) / (2 * k + 1)
    loop = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(2)], 1)
    path = _resample_loop(loop, spec.frames)
    center = np.array([lx / 2, ly / 2])
    phase = rng.uniform(0, 2 * np.pi)
    poses = []
    for k, p in enumerate(path):
        # Look mostly toward the room's middle, with a slow sweep as a teleoperator would.
        to_center = center - p
        heading = np.arctan2(to_center[1], to_center[0]) + 0.35 * np.sin(
            2 * np.pi * 3 * k / max(spec.frames, 1) + phase
        )
        target = np.array([p[0] + 2.0 * np.cos(heading), p[1] + 2.0 * np.sin(heading), spec.look_height])
        eye = np.array([p[0], p[1], spec.height + 0.02 * np.sin(0.5 * k)])
        poses.append(look_at(eye, target))
    return poses


def orbit(scene: Scene, spec: TrajectorySpec) -> list[np.ndarray]:
    """An ellipse inside the room looking at its center."""
    lx, ly, _ = scene.room_size
    center = np.array([lx / 2, ly / 2])
    rx, ry = max(lx / 2 - 0.45, 0.5), max(ly / 2 - 0.45, 0.5)
    poses = []
    for k in range(spec.frames):
        a = 2 * np.pi * k / max(spec.frames, 1)
        eye = np.array([center[0] + rx * np.cos(a), center[1] + ry * np.sin(a), spec.height])
        poses.append(look_at(eye, [center[0], center[1], spec.look_height]))
    return poses


def fixed(scene: Scene, spec: TrajectorySpec) -> list[np.ndarray]:
    """One viewpoint from a corner, looking across the room (repeated ``frames`` times)."""
    lx, ly, _ = scene.room_size
    eye = np.array([0.4, 0.4, spec.height])
    pose = look_at(eye, [lx / 2, ly / 2, spec.look_height])
    return [pose.copy() for _ in range(spec.frames)]


def make_trajectory(scene: Scene, spec: TrajectorySpec, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng([seed, 104729])
    if spec.type == "walk":
        return walk(scene, spec, rng)
    if spec.type == "orbit":
        return orbit(scene, spec)
    return fixed(scene, spec)


def drift(poses: list[np.ndarray], std: float, seed: int) -> list[np.ndarray]:
    """Reported poses that drift from the true ones (a random walk in translation and yaw)."""
    if std <= 0:
        return [p.copy() for p in poses]
    rng = np.random.default_rng([seed, 15485863])
    offset = np.zeros(3)
    yaw = 0.0
    out = []
    for p in poses:
        offset += rng.normal(0, std, 3) * np.array([1.0, 1.0, 0.2])
        yaw += rng.normal(0, std / 10)
        c, s = np.cos(yaw), np.sin(yaw)
        d = np.eye(4)
        d[:2, :2] = [[c, -s], [s, c]]
        d[:3, 3] = offset
        out.append(d @ p)
    return out
