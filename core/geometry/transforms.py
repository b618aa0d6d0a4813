"""SE(3) helpers. Poses are 4x4 float64 matrices mapping a local frame into the world (z up, metres)."""

from __future__ import annotations

import numpy as np

from stratamap.core.lazy import lazy_module

rotations = lazy_module("scipy.spatial.transform")


def make_pose(translation=(0.0, 0.0, 0.0), yaw: float = 0.0, rotation: np.ndarray | None = None) -> np.ndarray:
    """Pose from a translation and either a yaw about +z or a 3x3 rotation."""
    pose = np.eye(4)
    if rotation is not None:
        pose[:3, :3] = rotation
    else:
        c, s = np.cos(yaw), np.sin(yaw)
        pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = translation
    return pose


def invert(pose: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    r = pose[:3, :3]
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ pose[:3, 3]
    return out


def apply(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Transform an (N, 3) array of points."""
    return points @ pose[:3, :3].T + pose[:3, 3]


def yaw_of(pose: np.ndarray) -> float:
    return float(np.arctan2(pose[1, 0], pose[0, 0]))


def rpy_of(pose: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (URDF convention: fixed-axis XYZ)."""
    r, p, y = rotations.Rotation.from_matrix(pose[:3, :3]).as_euler("xyz")
    return float(r), float(p), float(y)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world pose of an *optical* camera at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, float)
    forward = np.asarray(target, float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, float))
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, eye
    return pose


def matrix_to_quat_xyzw(r: np.ndarray) -> np.ndarray:
    return rotations.Rotation.from_matrix(r).as_quat()


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def upright_turns(pose: np.ndarray | None) -> int:
    """Quarter turns (anticlockwise, as ``np.rot90``) that bring the image of a camera at ``pose``
    (camera to z-up world; optical frame, x right, y down) upright: 0 for a camera held level, 1 when
    the world's up points to the image's right (a phone held upright, turned anticlockwise), 2 upside
    down, 3 up to the left. 0 without a pose, or looking straight up or down."""
    if pose is None:
        return 0
    up = np.asarray(pose)[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the world's up in the camera's frame
    if np.hypot(up[0], up[1]) < 0.3:
        return 0
    return int(np.round(np.degrees(np.arctan2(up[0], -up[1])) / 90.0)) % 4
