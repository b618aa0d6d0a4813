"""What the sensor saw through an object, for ``clusters``' recognition (``sightlines``).

A map of surfaces cannot tell a low shelf between a coffee table's legs from a cabinet's closed
front: both put points at the object's middle heights. The frames' depth rays can. A ray that
crosses the object's box at its middle heights, over its footprint, and ends beyond the box saw
through it (the open space under a table's top); a ray that ends on the way in was stopped by it (a
unit's front, a sofa's base). ``Sightlines`` holds a sample of an RGB-D stream's rays, and
``Sightlines.seen_through`` counts both kinds for an object's points.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from stratamap.core.map.sensors import evenly_spaced, posed_depth_frames

if TYPE_CHECKING:
    from stratamap.core.geometry.boxes import OrientedBox

#: At most this many frames, evenly spaced, give rays (a long sequence sees the same furniture many times).
MAX_FRAMES = 60
#: About this many rays per frame, on a regular pixel grid.
RAYS_PER_FRAME = 5000
#: The middle heights of an object, as shares of its height (the band ``Shape.solid`` reads).
BAND = (0.25, 0.75)
#: The box is shrunk by this much (m) on every side, so that rays grazing its edges do not count.
INSET = 0.03
#: A ray ends beyond the box when its depth runs this much (m) past where it leaves it: the depth noise.
BEYOND = 0.05
#: Footprint cells (m): a ray counts only where it passes over the object's own points, not over the
#: empty corners of a box that is larger than the object.
CELL = 0.05
#: Points sampled along each ray's way through the box to find whether it passes over the footprint.
SAMPLES = 24


def ray_frames(count: int) -> np.ndarray:
    """Which of a stream's ``count`` frames give rays: up to MAX_FRAMES, evenly spaced."""
    return evenly_spaced(count, MAX_FRAMES)


class Sight(NamedTuple):
    """Rays crossing an object's middle heights over its footprint: through it, or stopped on it."""

    through: int
    stopped: int

    @property
    def share(self) -> float:
        return self.through / max(1, self.through + self.stopped)


class Sightlines:
    """Camera centres and depth ray ends (world, z up) of a sample of a stream's frames."""

    def __init__(self, origins: np.ndarray, ends: np.ndarray) -> None:
        self.origins = np.asarray(origins, float).reshape(-1, 3)  # per ray
        self.ends = np.asarray(ends, float).reshape(-1, 3)
        self.directions = self.ends - self.origins  # unit length = the measured depth
        # BEYOND in each ray's own length (ray parameter 1 is its measured end).
        self.noise = BEYOND / np.maximum(np.linalg.norm(self.directions, axis=1), 1e-9)

    def __len__(self) -> int:
        return len(self.ends)

    @classmethod
    def from_stream(cls, stream: Any) -> Sightlines | None:
        """The rays of up to MAX_FRAMES posed frames with depth, or None for a stream without them
        (a point cloud, a scan)."""
        if stream is None or stream.intrinsics is None or not len(stream.frames):
            return None
        intr = stream.intrinsics
        stride = max(1, int(round(np.sqrt(intr.width * intr.height / RAYS_PER_FRAME))))
        origins, ends = [], []
        for depth, pose in posed_depth_frames(stream, MAX_FRAMES):
            pts, _ = intr.backproject(np.where(np.isfinite(depth), depth, 0.0), stride=stride)
            if not len(pts):
                continue
            ends.append(pts @ pose[:3, :3].T + pose[:3, 3])
            origins.append(np.broadcast_to(pose[:3, 3], (len(pts), 3)))
        if not ends:
            return None
        return cls(np.concatenate(origins), np.concatenate(ends))

    def seen_through(self, pts: np.ndarray, box: OrientedBox | None = None) -> Sight:
        """Of the rays that reached the object made of ``pts`` and crossed its middle heights (BAND)
        through its gravity-aligned box (``box``, found when not given) shrunk by INSET, over its
        footprint: how many ended beyond its box (by BEYOND) and how many ended on it."""
        from stratamap.core.geometry.boxes import gravity_aligned_box

        box = gravity_aligned_box(pts) if box is None else box
        half = np.asarray(box.size[:2], float) / 2.0 - INSET
        if (half <= 0.0).any() or not len(self):
            return Sight(0, 0)
        z = pts[:, 2]
        low, high = float(z.min()), float(z.max())
        band = (low + BAND[0] * (high - low), low + BAND[1] * (high - low))
        turn = box.pose[:2, :2]
        start = (self.origins[:, :2] - box.center[:2]) @ turn  # in the box's frame
        step = self.directions[:, :2] @ turn

        def slabs(half: np.ndarray, rays: Any = slice(None)) -> tuple[np.ndarray, np.ndarray]:
            with np.errstate(divide="ignore", invalid="ignore"):
                a, b = (-half - start[rays]) / step[rays], (half - start[rays]) / step[rays]
            return np.nanmax(np.minimum(a, b), axis=1), np.nanmin(np.maximum(a, b), axis=1)

        enter, leave = slabs(half)  # the shrunk box: which rays cross the object's middle
        z_in = self.origins[:, 2] + enter * self.directions[:, 2]
        z_out = self.origins[:, 2] + leave * self.directions[:, 2]
        rays = np.flatnonzero(
            (enter < leave)
            & (enter > 0.0)
            & (np.minimum(z_in, z_out) >= band[0])
            & (np.maximum(z_in, z_out) <= band[1])
        )
        # The whole box: where the object begins and ends on each of those rays. A ray ending nearer
        # than its box, less the noise, did not reach it (something in front hid it).
        reach, beyond = slabs(half + INSET, rays)
        reached = reach - self.noise[rays] < 1.0
        rays, beyond = rays[reached], beyond[reached]
        if not len(rays):
            return Sight(0, 0)
        # Over the footprint: some point of the way through the box lies in a cell the object occupies.
        corner = pts[:, :2].min(axis=0)
        cells = np.floor((pts[:, :2] - corner) / CELL).astype(np.int64)
        footprint = np.zeros(cells.max(axis=0) + 1, bool)
        footprint[cells[:, 0], cells[:, 1]] = True
        t = enter[rays, None] + (leave - enter)[rays, None] * ((np.arange(SAMPLES) + 0.5) / SAMPLES)
        way = self.origins[rays, None, :2] + t[..., None] * self.directions[rays, None, :2]
        at = np.floor((way - corner) / CELL).astype(np.int64)
        inside = (at >= 0).all(axis=-1) & (at[..., 0] < footprint.shape[0]) & (at[..., 1] < footprint.shape[1])
        over = np.zeros(inside.shape, bool)
        over[inside] = footprint[at[inside][:, 0], at[inside][:, 1]]
        kept = over.any(axis=1)
        through = beyond[kept] + self.noise[rays[kept]] < 1.0
        return Sight(int(through.sum()), int((~through).sum()))

    def across_level(self, height: float) -> tuple[np.ndarray, np.ndarray]:
        """Where the rays cross the level ``z = height`` (xy) and whether each went on past it (True) or
        ended on it, within the depth noise (False); rays ending before the level are left out."""
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (height - self.origins[:, 2]) / self.directions[:, 2]
        crossing = np.flatnonzero(np.isfinite(t) & (t > 0.0) & (t < 1.0 + self.noise))
        xy = self.origins[crossing, :2] + t[crossing, None] * self.directions[crossing, :2]
        return xy, t[crossing] < 1.0 - self.noise[crossing]
