"""Where the sensor saw empty space: free-space evidence from posed depth frames.

A fused map holds surfaces; it does not say whether the space beside an object was seen empty or
never seen at all. The frames do: a point in space was *seen free* by a frame when the frame's depth
ray through it ends beyond it (the ray passed the point on its way to a farther surface). A chair
pushed in under a table shows only its backrest; the space where its seat is was never seen free
(the table top and the backrest hid it), while the space behind the backrest was. ``FreeSpace``
answers that question for any points, from a sample of a stream's frames.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.map.sensors import posed_depth_frames

#: At most this many frames, evenly spaced, are kept (a long recording sees the same space many times).
MAX_FRAMES = 60
#: Depth images are kept at one pixel in STRIDE along each axis (a 640 x 480 frame: 160 x 120).
STRIDE = 4
#: A ray ends beyond a point when its depth runs this much (m) past the point's: the depth noise.
BEYOND = 0.05
#: Points nearer to a camera than this (m) are not judged from it (the sensor's blind range).
NEAREST = 0.3


class FreeSpace:
    """Depth images (downsampled) and camera poses of a sample of a stream's posed frames."""

    def __init__(self, intrinsics: Any, frames: list[tuple[np.ndarray, np.ndarray]], stride: int = STRIDE) -> None:
        self.intrinsics = intrinsics
        self.stride = int(stride)
        self.depths = [np.asarray(depth, np.float32)[:: self.stride, :: self.stride] for depth, _ in frames]
        self.world_to_camera = [np.linalg.inv(np.asarray(pose, float)) for _, pose in frames]

    @classmethod
    def from_stream(cls, stream: Any, most: int = MAX_FRAMES, stride: int = STRIDE) -> FreeSpace | None:
        """The free space up to ``most`` posed depth frames saw, or None for a stream without them
        (a point cloud, a laser scan)."""
        frames = list(posed_depth_frames(stream, most))
        if not frames:
            return None
        return cls(stream.intrinsics, frames, stride)

    def __len__(self) -> int:
        return len(self.depths)

    def seen_free(self, points: np.ndarray, beyond: float = BEYOND) -> np.ndarray:
        """For each of ``points`` (N, 3, world), how many frames saw it free: it lies in the frame's
        view, at least NEAREST in front of the camera, and the depth at its pixel runs ``beyond`` past it."""
        pts = np.asarray(points, float).reshape(-1, 3)
        counts = np.zeros(len(pts), np.int32)
        intr, s = self.intrinsics, self.stride
        for depth, to_camera in zip(self.depths, self.world_to_camera, strict=True):
            cam = pts @ to_camera[:3, :3].T + to_camera[:3, 3]
            z = cam[:, 2]
            ahead = z > NEAREST
            safe = np.where(ahead, z, 1.0)
            u = np.round((intr.fx * cam[:, 0] / safe + intr.cx) / s).astype(np.int64)
            v = np.round((intr.fy * cam[:, 1] / safe + intr.cy) / s).astype(np.int64)
            inside = ahead & (u >= 0) & (v >= 0) & (u < depth.shape[1]) & (v < depth.shape[0])
            measured = np.zeros(len(pts), np.float32)
            measured[inside] = depth[v[inside], u[inside]]
            counts += (inside & np.isfinite(measured) & (measured > z + beyond)).astype(np.int32)
        return counts
