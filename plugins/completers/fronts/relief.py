"""A face's height map: the heights out of the face (and the luminance) of what the sensors saw
on it, per cell, as the evidence of handles, knobs and the gaps between fronts.

From the depth frames that saw the face most squarely and closest, each cell's median over every
frame's measurements (a far sensor's centimetres of noise fall to millimetres over dozens), or
from a static cloud's points at its own spacing. The *relief* is the height above the face's local
level where a cell has a like neighbour along a row or a column; the *contrast* is the luminance
less its surroundings', where colour images are registered with the depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.plugins.completers.fronts.face import Face

spatial = lazy_module("scipy.spatial")

#: The face's height map cell (m) from depth frames: finer than a fused map's voxels, so that
#: handles and the gaps between fronts show; from a map's points, its voxel spacing.
FACE_CELL = 0.01
#: Fewest measurements a cell of the height map needs.
CELL_MIN = 3
#: The local level of the face: the median height over this many cells around each cell (wider
#: than a handle is tall, narrower than a front), so that a sensor's banding and a slightly bent
#: face are not taken for fixtures or gaps.
LEVEL_WINDOW = 9


#: The slab of space a face's height map looks at: this far (m) behind the face and in front of it.
SLAB = (0.08, 0.1)


@dataclass
class HeightMap:
    """Heights out of a face (m, NaN: unseen) on a grid of the face: ``heights[i, j]`` is the cell
    at ``u = u0 + (j + 0.5) * cell``, ``z = z0 + (i + 0.5) * cell``; ``relief`` is the height above
    the face's local level."""

    u0: float
    z0: float
    cell: float
    heights: np.ndarray
    relief: np.ndarray
    #: Luminance less the cell's surroundings' (NaN: no colour), from registered colour images.
    contrast: np.ndarray | None = None
    #: Share of the cell's measurements that each frame's colour image marked as part of a thin
    #: light or dark line (:func:`thin_lines`; NaN: no colour): a steel bar on a red door, the shadow
    #: in a gap. Seen per frame before any averaging, so colour off the depth by a centimetre or two
    #: from frame to frame (unregistered RGB-D) does not blur it away.
    light_lines: np.ndarray | None = None
    dark_lines: np.ndarray | None = None

    @property
    def noise(self) -> float:
        """The relief's spread on the face (m): 1.4826 median absolute deviations."""
        r = self.relief[np.isfinite(self.relief)]
        return float(1.4826 * np.median(np.abs(r - np.median(r)))) if len(r) else 0.0

    def centres(self, mask: np.ndarray) -> np.ndarray:
        """(N, 2) face coordinates (u, z) of the cells in ``mask``."""
        i, j = np.nonzero(mask)
        return np.stack([self.u0 + (j + 0.5) * self.cell, self.z0 + (i + 0.5) * self.cell], axis=1)


def _runs(ordered: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The values of a sorted array, where each one's run starts and how long it is (as
    ``np.unique(..., return_index=True, return_counts=True)`` gives them, without sorting again)."""
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    return ordered[starts], starts, np.diff(np.r_[starts, len(ordered)])


def _by_cell_then_value(cells: np.ndarray, values: np.ndarray, n_cells: int) -> np.ndarray:
    """The order that sorts by cell, then by value within a cell (``np.lexsort((values, cells))``'s
    values in each cell, in half its time: a sort of the values, then a stable radix sort of the
    cells as 16-bit integers where they fit)."""
    by_value = np.argsort(values)
    small = np.uint16 if n_cells <= np.iinfo(np.uint16).max + 1 else np.int64
    return by_value[np.argsort(cells[by_value].astype(small), kind="stable")]


def height_map(points: np.ndarray, face: Face, cell: float, min_count: int = 1) -> HeightMap:
    """The median height out of ``face`` of ``points`` per cell of its rectangle (and, when the
    points carry a fourth column, their median luminance as ``contrast`` to the cell's
    surroundings; with a fifth and sixth, their thin-line marks' shares as ``light_lines`` and
    ``dark_lines``)."""
    from scipy import ndimage

    shade_values = points[:, 3] if points.shape[1] > 3 else None
    marks = points[:, 4:6] if points.shape[1] > 5 else None
    points = points[:, :3]

    u0, u1, z0, z1 = face.rect
    shape = (max(1, int(np.ceil((z1 - z0) / cell))), max(1, int(np.ceil((u1 - u0) / cell))))
    fu, fz, h = points @ face.u_axis, points[:, 2], points @ face.normal + face.d
    j, i = np.floor((fu - u0) / cell).astype(np.int64), np.floor((fz - z0) / cell).astype(np.int64)
    ok = (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1]) & (h > -SLAB[0]) & (h < SLAB[1])
    flat, h = i[ok] * shape[1] + j[ok], h[ok]
    heights = np.full(shape[0] * shape[1], np.nan)
    shades = np.full(shape[0] * shape[1], np.nan)
    if len(flat):
        order = _by_cell_then_value(flat, h, heights.size)
        cells, starts, counts = _runs(flat[order])
        keep = counts >= min_count
        heights[cells[keep]] = h[order][starts[keep] + counts[keep] // 2]
        if shade_values is not None:
            lum = shade_values[ok]
            has = np.isfinite(lum)
            if has.sum():
                order = _by_cell_then_value(flat[has], lum[has], heights.size)
                cells, starts, counts = _runs(flat[has][order])
                keep = counts >= min_count
                shades[cells[keep]] = lum[has][order][starts[keep] + counts[keep] // 2]
    heights = heights.reshape(shape)
    shades = shades.reshape(shape)
    shares = [None, None]
    if marks is not None:
        has = np.isfinite(marks[ok, 0])
        n = np.bincount(flat[has], minlength=heights.size)
        for k in range(2):
            total = np.bincount(flat[has], weights=marks[ok, k][has], minlength=heights.size)
            shares[k] = np.where(n >= min_count, total / np.maximum(n, 1), np.nan).reshape(shape)
    seen = np.isfinite(heights)
    fill = float(np.median(heights[seen])) if seen.any() else 0.0
    level = ndimage.median_filter(np.where(seen, heights, fill), size=LEVEL_WINDOW, mode="nearest")
    relief = np.where(seen, heights - level, 0.0)
    # A cell stands out only with a neighbour along a row or a column: a handle or a gap is a
    # line; the sensor's noise is single cells.
    lines = np.stack([ndimage.median_filter(relief, size=size, mode="nearest") for size in ((1, 3), (3, 1))], axis=0)
    relief = np.where(np.abs(lines[0]) > np.abs(lines[1]), lines[0], lines[1])
    contrast = np.full(shape, np.nan)
    lit = np.isfinite(shades)
    if lit.sum() > 50:
        fill = float(np.median(shades[lit]))
        base = ndimage.median_filter(np.where(lit, shades, fill), size=LEVEL_WINDOW, mode="nearest")
        contrast = np.where(lit, shades - base, np.nan)
    return HeightMap(u0, z0, cell, heights, np.where(seen, relief, np.nan), contrast, *shares)


#: Thin lines in a frame's colour image: narrower than this many pixels (a grey top-hat's width).
LINE_PIXELS = 9
#: ... and standing out of their surroundings by this much luminance (0-1) at least, and by this many
#: spreads of the top-hat over the image window.
LINE_CONTRAST = 0.06
LINE_SPREADS = 3.0


def thin_lines(shade: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where a luminance image (0-1) shows thin light and thin dark lines and specks: each pixel's
    grey top-hat (white and black, LINE_PIXELS across) above LINE_CONTRAST and LINE_SPREADS spreads
    over the image's median top-hat."""
    from scipy import ndimage

    out = []
    for hat in (ndimage.white_tophat(shade, size=LINE_PIXELS), ndimage.black_tophat(shade, size=LINE_PIXELS)):
        mid = float(np.median(hat))
        spread = float(1.4826 * np.median(np.abs(hat - mid)))
        out.append(hat > max(LINE_CONTRAST, mid + LINE_SPREADS * spread))
    return out[0], out[1]


def frame_points(stream, face: Face, max_frames: int, max_range: float, reach: float = 0.1) -> np.ndarray | None:
    """The depth frames' points on ``face``'s rectangle (``reach`` m around it, within SLAB of it),
    (N, 6): x, y, z, the colour image's luminance there and whether :func:`thin_lines` marked it
    light or dark (NaN without a colour image of the depth's size);
    from the frames that saw it most squarely and closest (at most ``max_frames``, within ``max_range`` m):
    over many frames a cell's median falls from a far sensor's centimetres of noise to millimetres.
    None without posed depth frames that saw it."""
    intr = getattr(stream, "intrinsics", None)
    frames = getattr(stream, "frames", None)
    if intr is None or not frames:
        return None
    poses = getattr(frames, "poses", None)
    if poses is None:
        poses = [f.pose for f in frames]
    u_axis = face.u_axis
    u0, u1, z0, z1 = face.rect
    center = ((u0 + u1) / 2) * u_axis - face.d * face.normal
    center[2] = (z0 + z1) / 2
    corners = np.array(
        [
            u * u_axis - face.d * face.normal + [0.0, 0.0, z]
            for u in (u0 - reach, u1 + reach)
            for z in (z0 - reach, z1 + reach)
        ]
    )
    scored = []
    for k, pose in enumerate(poses):
        if pose is None:
            continue
        pose = np.asarray(pose, float)
        eye = pose[:3, 3]
        to_face = center - eye
        dist = float(np.linalg.norm(to_face))
        facing = float(-(to_face / max(dist, 1e-6)) @ face.normal)
        if dist > max_range or facing < 0.3:
            continue
        c = (center - eye) @ pose[:3, :3]
        if c[2] <= 0.1 or np.any(((corners - eye) @ pose[:3, :3])[:, 2] <= 0.05):
            continue
        px, py = intr.fx * c[0] / c[2] + intr.cx, intr.fy * c[1] / c[2] + intr.cy
        if 0 <= px < intr.width and 0 <= py < intr.height:
            scored.append((facing / dist, k))
    if not scored:
        return None
    scored.sort(reverse=True)
    clouds = []
    for k in sorted(k for _, k in scored[:max_frames]):
        pose = np.asarray(poses[k], float)
        eye = pose[:3, 3]
        cam = (corners - eye) @ pose[:3, :3]
        us = intr.fx * cam[:, 0] / cam[:, 2] + intr.cx
        vs = intr.fy * cam[:, 1] / cam[:, 2] + intr.cy
        ua, ub = int(max(0, np.floor(us.min()))), int(min(intr.width, np.ceil(us.max()) + 1))
        va, vb = int(max(0, np.floor(vs.min()))), int(min(intr.height, np.ceil(vs.max()) + 1))
        if ub - ua < 2 or vb - va < 2:
            continue
        frame = frames[k]
        depth = np.asarray(frame.depth, np.float32)[va:vb, ua:ub]
        rgb = np.asarray(frame.rgb)
        # Luminance where the colour image matches the depth image's size (registered RGB-D).
        if rgb.ndim == 3 and rgb.shape[:2] == np.asarray(frame.depth).shape:
            shade = rgb[va:vb, ua:ub, :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32) / 255.0
            light, dark = (m.astype(np.float32) for m in thin_lines(shade))
        else:
            shade = np.full(depth.shape, np.nan, np.float32)
            light = dark = shade
        vv, uu = np.mgrid[va:vb, ua:ub]
        ok = np.isfinite(depth) & (depth > 0) & (depth < max_range)
        zc = depth[ok].astype(float)
        pts = np.stack([(uu[ok] - intr.cx) * zc / intr.fx, (vv[ok] - intr.cy) * zc / intr.fy, zc], axis=1)
        world = pts @ pose[:3, :3].T + eye
        h = world @ face.normal + face.d
        fu, fz = world @ u_axis, world[:, 2]
        keep = (
            (h > -SLAB[0])
            & (h < SLAB[1])
            & (fu > u0 - reach)
            & (fu < u1 + reach)
            & (fz > z0 - reach)
            & (fz < z1 + reach)
        )
        clouds.append(np.column_stack([world[keep], shade[ok][keep], light[ok][keep], dark[ok][keep]]))
    cloud = np.concatenate(clouds) if clouds else np.zeros((0, 6))
    return cloud if len(cloud) else None


def lines_only(mask: np.ndarray, length: int) -> np.ndarray:
    """The cells of ``mask`` on a row or a column run at least ``length`` cells long: handles, knobs
    and gaps between fronts run along the face's axes; a sensor's banding runs across them."""
    from scipy import ndimage

    runs = [ndimage.binary_opening(mask, structure=np.ones(shape, bool)) for shape in ((1, length), (length, 1))]
    return runs[0] | runs[1]


def point_spacing(points: np.ndarray) -> float:
    """How far apart a map's points lie (the median distance to the nearest one; a fused map's voxel)."""
    sample = points[:: max(1, len(points) // 2000)]
    if len(sample) < 2:
        return 0.02
    dist, _ = spatial.cKDTree(points).query(sample, k=2)
    return float(np.clip(np.median(dist[:, 1]), 0.005, 0.05))
