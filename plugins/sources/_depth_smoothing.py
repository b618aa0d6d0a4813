"""Smoothing of one depth camera's cloud before mapping, as KinectFusion smooths its raw
depth maps (Newcombe et al. 2011, section 3.2: a bilateral filter keeps edges and removes noise).

Structured-light and stereo cameras measure disparity in steps, so depth comes in steps that grow
with the square of range: a Kinect's are 2 mm at 0.8 m and 3.6 cm at 3.5 m. A far surface is then a
staircase of bands a few centimetres apart that no fixed neighbour radius joins, and a room seen by
one frame falls into dozens of slivers where its far wall is. In inverse depth the steps are even,
so the filter works there with one range sigma, taken from the cloud's own step: the median gap
between the distinct inverse depths the camera reported. A cloud whose depths do not come in steps
(a time-of-flight camera, a rendered frame) is left as it is. Points move only along their pixel's
ray, so colours and labels stay with them. An organized cloud is filtered on its image grid; one
stored without it finds each point's pixel from its ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A camera quantizes when its frame holds fewer distinct depths than this share of its valid pixels.
QUANTIZED_SHARE = 0.05
#: Disparity steps are even in inverse depth: the gaps between distinct inverse depths vary by at
#: most this factor (10th to 90th percentile; mOSD's Kinect scans: 1.8), and by less than the gaps
#: between distinct depths do. Depths stored in whole millimetres (a time-of-flight camera's) come
#: in steps even in depth, not in inverse depth.
EVEN_STEPS = 3.0
#: Range sigma in inverse-depth steps: neighbours one or two steps apart are the same surface
#: (weights 0.95 and 0.8), six steps apart an edge (0.13).
RANGE_SIGMA_STEPS = 3.0
#: Pixels within this radius are averaged, with a spatial sigma of half of it.
RADIUS_PX = 4


@dataclass(frozen=True)
class Smoothing:
    """What was done: the inverse-depth step (1/m) found, or why the cloud was left as it is."""

    step: float | None
    skipped: str | None = None

    def report(self) -> dict[str, object]:
        if self.skipped:
            return {"applied": False, "reason": self.skipped}
        return {"applied": True, "inverse_depth_step": round(float(self.step), 6), "radius_px": RADIUS_PX}


def _spread(values: np.ndarray) -> tuple[float, np.ndarray]:
    """How unevenly the distinct ``values`` are spaced (90th over 10th percentile gap), and the gaps."""
    gaps = np.diff(np.unique(values))
    low, high = np.percentile(gaps, [10, 90])
    return float(high / low), gaps


def inverse_depth_step(depth: np.ndarray) -> float | None:
    """The camera's inverse-depth step (1/m) from its valid pixels' depths (m), or None when they do
    not come in even steps of inverse depth."""
    distinct = np.unique(np.round(depth, 6))
    if len(distinct) < 3 or len(distinct) > QUANTIZED_SHARE * len(depth):
        return None
    spread, gaps = _spread(np.round(1.0 / distinct, 7))
    if spread > EVEN_STEPS or spread >= _spread(distinct)[0]:
        return None
    return float(np.median(gaps))


def _camera_step(depth: np.ndarray) -> tuple[float | None, str | None]:
    """The inverse-depth step of a camera's valid depths (m), or why they are no disparity camera's."""
    if len(depth) < 3:
        return None, "fewer than 3 valid points"
    if np.any(depth <= 0):
        # A lidar sweep or a scan from inside a room has points all around its sensor.
        return None, "points behind the sensor: not a camera's frame"
    step = inverse_depth_step(depth)
    if step is None:
        return None, "depths do not come in even steps of inverse depth (no disparity camera's)"
    return step, None


def _weight(distance_px: np.ndarray | float, near: np.ndarray, centre: np.ndarray, step: float) -> np.ndarray:
    """The bilateral filter's weight of a neighbour ``distance_px`` pixels away whose inverse depth is
    ``near``, for a point whose inverse depth is ``centre``."""
    spatial_sigma = RADIUS_PX / 2.0
    range_sigma = RANGE_SIGMA_STEPS * step
    return np.exp(-np.square(distance_px) / (2 * spatial_sigma**2)) * np.exp(
        -np.square(near - centre) / (2 * range_sigma**2)
    )


def smooth_depth(points: np.ndarray, image_size: tuple[int, int]) -> tuple[np.ndarray, Smoothing]:
    """The points of an organized cloud in its camera's optical frame (z forward, one row of points
    per image row, NaN where the camera saw nothing) with their depth bilaterally filtered in
    inverse depth; the input is not changed."""
    width, height = image_size
    depth = points[:, 2].reshape(height, width)
    valid = np.isfinite(points).all(axis=1).reshape(height, width)
    step, skipped = _camera_step(depth[valid])
    if step is None:
        return points, Smoothing(None, skipped)
    inverse = np.zeros((height, width))
    inverse[valid] = 1.0 / depth[valid]
    padded = np.pad(inverse, RADIUS_PX)
    padded_valid = np.pad(valid, RADIUS_PX)
    total = np.zeros((height, width))
    weight = np.zeros((height, width))
    for dy in range(-RADIUS_PX, RADIUS_PX + 1):
        for dx in range(-RADIUS_PX, RADIUS_PX + 1):
            if dx * dx + dy * dy > RADIUS_PX * RADIUS_PX:
                continue
            window = (slice(RADIUS_PX + dy, RADIUS_PX + dy + height), slice(RADIUS_PX + dx, RADIUS_PX + dx + width))
            near = padded[window]
            w = _weight(np.hypot(dx, dy), near, inverse, step) * padded_valid[window]
            total += w * near
            weight += w
    # A valid pixel weighs itself by 1, so weight > 0 wherever the depth is valid.
    ratio = np.ones((height, width))
    ratio[valid] = (1.0 / (total[valid] / weight[valid])) / depth[valid]
    smoothed = points.copy()
    smoothed[valid.reshape(-1)] *= ratio[valid][:, None]
    return smoothed, Smoothing(step)


#: Points filtered at once in an unorganized cloud (each with up to NEIGHBOURS neighbours).
CHUNK = 20_000
#: Neighbours looked up per point: the pixels of a disc of RADIUS_PX (49) and some slack.
NEIGHBOURS = 64


def smooth_unorganized_depth(points: np.ndarray) -> tuple[np.ndarray, Smoothing]:
    """The same filter for a camera's cloud stored without its image grid (its invalid pixels dropped,
    as mOSD's test43.pcd): each point's pixel is its ray ``(x / z, y / z)``, one pixel is the median
    distance between neighbouring rays, and its neighbours are the points within RADIUS_PX pixels."""
    from scipy.spatial import cKDTree

    valid = np.flatnonzero(np.isfinite(points).all(axis=1))
    depth = points[valid, 2].astype(np.float64)
    step, skipped = _camera_step(depth)
    if step is None:
        return points, Smoothing(None, skipped)
    rays = points[valid, :2] / depth[:, None]
    tree = cKDTree(rays)
    gaps = tree.query(rays[:: max(1, len(rays) // 20_000)], k=2)[0][:, 1]
    gaps = gaps[gaps > 0]
    if len(gaps) == 0:
        return points, Smoothing(None, "all points on one ray")
    pixel = float(np.median(gaps))
    inverse = 1.0 / depth
    smoothed_inverse = np.empty_like(inverse)
    for start in range(0, len(rays), CHUNK):
        part = slice(start, start + CHUNK)
        distance, index = tree.query(
            rays[part], k=min(NEIGHBOURS, len(rays)), distance_upper_bound=RADIUS_PX * pixel * 1.001
        )
        found = index < len(rays)
        near = inverse[np.where(found, index, 0)]
        w = _weight(np.where(found, distance, 0.0) / pixel, near, inverse[part, None], step) * found
        smoothed_inverse[part] = (w * near).sum(axis=1) / w.sum(axis=1)
    smoothed = points.copy()
    smoothed[valid] *= ((1.0 / smoothed_inverse) / depth)[:, None]
    return smoothed, Smoothing(step)
