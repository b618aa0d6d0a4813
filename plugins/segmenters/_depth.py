"""Per-frame geometric segmentation of depth images, and panoptic labels from it and 2D detections.

The functional-scenes paper (section 3.1) segments every depth frame geometrically before any
label is attached: surfaces are cut where the depth jumps and where two surfaces meet in a concave
crease (a chair leg on the floor, a cup on a table, the floor against a wall), never along convex
edges (a table top's rim). Each segment is then one piece of one object or of the room, so a 2D
detection only has to say *which* segments are its object: the segments lying mostly inside its
box or mask, near its main segment in 3D. What a box or a mask spills onto (the wall and the floor
behind a chair) is a segment of its own and goes to the background. Layout (floor, wall, ceiling)
comes from the segments' gravity-aligned planes, so segmenters that do not know it still give it.

Everything works on an image grid ``stride`` times coarser than the frame (a 640 x 480 frame at
stride 2: 320 x 240 cells), then labels are taken back to the frame's resolution.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.lazy import lazy_module
from stratamap.core.map.priors import CLASS_SIZES
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.map.vocabulary import LAYOUT_CLASSES

ndimage = lazy_module("scipy.ndimage")
spatial = lazy_module("scipy.spatial")


class DepthSegmentsConfig(BaseModel):
    """How each depth frame is cut into geometric segments."""

    model_config = ConfigDict(extra="forbid")

    stride: int = Field(
        default=2, ge=1, le=8, description="Segment on a grid this many times coarser than the frame (speed)."
    )
    smoothing: int = Field(
        default=2, ge=1, le=8, description="Half-width in grid cells of the point smoothing before normals."
    )
    jump_ratio: float = Field(
        default=0.03, gt=0, le=0.5, description="A depth step above this share of the depth separates surfaces."
    )
    jump_floor: float = Field(
        default=0.01, ge=0, description="Metres added to the jump threshold (sensor quantization at short range)."
    )
    concave_deg: float = Field(
        default=25.0,
        gt=0,
        lt=90,
        description="Concave creases sharper than this separate surfaces (a leg on the floor, a cup on a table).",
    )
    min_cells: int = Field(default=20, ge=1, description="Segments of fewer grid cells are dropped as noise.")


class LayoutConfig(BaseModel):
    """What makes a segment floor, wall or ceiling (in the gravity-aligned world, z up)."""

    model_config = ConfigDict(extra="forbid")

    floor_height: float | None = Field(
        default=None,
        description="Height of the floor (m); default: the lowest large upward-facing surface of the frames.",
    )
    tilt_deg: float = Field(
        default=20.0, gt=0, lt=45, description="Surfaces within this of horizontal or vertical count as such."
    )
    floor_band: float = Field(default=0.12, ge=0, description="Upward surfaces at most this high above it are floor.")
    ceiling_min: float = Field(
        default=1.9, gt=0, description="Downward surfaces higher than this above the floor are ceiling."
    )
    wall_min_height: float = Field(
        default=1.0, gt=0, description="Vertical planar surfaces spanning this much height are wall."
    )
    wall_min_width: float = Field(
        default=2.0,
        gt=0,
        description="...or this much width while reaching above wall_wide_top (a counter's front is wide but low).",
    )
    wall_wide_top: float = Field(default=1.3, gt=0, description="See wall_min_width (m above the floor).")
    planar_rms: float = Field(
        default=0.03, gt=0, description="RMS distance (m) to its plane a wall segment stays under."
    )


@dataclass
class FrameGeometry:
    """A depth frame on the coarse grid: camera-frame points and normals, and their segments."""

    points: np.ndarray  # (h, w, 3) camera frame, smoothed; 0 where invalid
    normals: np.ndarray  # (h, w, 3) unit, towards the camera; 0 where invalid
    valid: np.ndarray  # (h, w) bool
    segments: np.ndarray  # (h, w) int32, 0 = none
    stride: int


def _box_mean(values: np.ndarray, weights: np.ndarray, radius: int) -> np.ndarray:
    size = 2 * radius + 1
    w = ndimage.uniform_filter(weights.astype(np.float64), size=size, mode="constant")
    if values.ndim == 3:
        num = np.stack(
            [ndimage.uniform_filter(values[..., k] * weights, size=size, mode="constant") for k in range(3)], -1
        )
        return num / np.maximum(w, 1e-12)[..., None]
    return ndimage.uniform_filter(values * weights, size=size, mode="constant") / np.maximum(w, 1e-12)


def frame_geometry(depth: np.ndarray, intrinsics: CameraIntrinsics, params: DepthSegmentsConfig) -> FrameGeometry:
    """Points, normals and geometric segments of one depth image (metres, 0 or NaN = no return)."""
    s = max(1, int(params.stride))
    z = np.nan_to_num(np.asarray(depth, np.float64)[::s, ::s], nan=0.0, posinf=0.0, neginf=0.0)
    h, w = z.shape
    valid = z > 0
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = xs * s, ys * s
    raw = np.stack([(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z], -1)

    # Depth jumps on the raw points (smoothing would blur them into slopes).
    thresh = params.jump_ratio * z + params.jump_floor
    cut = ~valid.copy()
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        step = np.abs(z[tuple(a)] - z[tuple(b)]) > np.minimum(thresh[tuple(a)], thresh[tuple(b)])
        both = valid[tuple(a)] & valid[tuple(b)]
        jump = step & both
        cut[tuple(a)] |= jump
        cut[tuple(b)] |= jump

    # Normals from points smoothed within one surface: a box filter over cells that are not cut
    # keeps a chair's edge from averaging with the wall behind it.
    inside = valid & ~cut
    pts = _box_mean(raw, inside.astype(np.float64), params.smoothing)
    pts[~valid] = 0.0
    r = max(1, params.smoothing)
    dx = np.zeros_like(pts)
    dy = np.zeros_like(pts)
    dx[:, r:-r] = pts[:, 2 * r :] - pts[:, : -2 * r]
    dy[r:-r, :] = pts[2 * r :, :] - pts[: -2 * r, :]
    n = np.cross(dx, dy)
    norm = np.linalg.norm(n, axis=-1)
    ok = valid & (norm > 1e-12)
    n = np.where(ok[..., None], n / np.maximum(norm, 1e-12)[..., None], 0.0)
    n *= np.where(np.einsum("hwc,hwc->hw", n, pts) > 0, -1.0, 1.0)[..., None]  # face the camera

    # Concave creases: (n_b - n_a) . (p_b - p_a) < 0 with a sharp enough angle, for cells a and b
    # 2r either side of a cell: far enough that neither normal's support crosses the crease.
    cos_min = np.cos(np.radians(params.concave_deg))
    span = 2 * r
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(0, -2 * span), slice(2 * span, None)
        na, nb, pa, pb = n[tuple(a)], n[tuple(b)], pts[tuple(a)], pts[tuple(b)]
        both = ok[tuple(a)] & ok[tuple(b)]
        concave = np.einsum("hwc,hwc->hw", nb - na, pb - pa) < 0
        sharp = np.einsum("hwc,hwc->hw", na, nb) < cos_min
        crease = both & concave & sharp
        mid = [slice(None), slice(None)]
        mid[axis] = slice(span, -span)
        cut[tuple(mid)] |= crease

    # Cells with no normal (the frame's rim) cannot be judged: they are cut too, and regrown below.
    cut |= ~ok
    segments, _ = ndimage.label(~cut)
    segments = segments.astype(np.int32)
    # Small pieces (noise at edges) are dropped; cut cells then join the segment they are nearest
    # to when their depth continues it, so creases do not leave unlabelled bands.
    counts = np.bincount(segments.ravel())
    small = counts < params.min_cells
    small[0] = True
    segments[small[segments]] = 0
    holes = valid & (segments == 0)
    if holes.any() and (segments > 0).any():
        _, (iy, ix) = ndimage.distance_transform_edt(segments == 0, return_indices=True)
        near = segments[iy, ix]
        continuous = np.abs(z[iy, ix] - z) <= thresh * 2
        grow = holes & continuous & (np.hypot(iy - ys, ix - xs) <= 2 * span + 1)
        segments[grow] = near[grow]
    pts = np.where(valid[..., None], np.where(ok[..., None], pts, raw), 0.0)
    return FrameGeometry(pts, n, valid, segments, s)


@dataclass
class SegmentStats:
    """Per segment (index = segment id): size, world centroid, mean world normal and extents."""

    cells: np.ndarray
    centroid: np.ndarray  # (n, 3)
    normal: np.ndarray  # (n, 3) mean unit normal (not renormalised: its length says how planar)
    z_low: np.ndarray
    z_high: np.ndarray
    width: np.ndarray  # horizontal extent along the segment's main horizontal direction
    rms: np.ndarray  # RMS distance to the segment's least-squares plane
    z_std: np.ndarray  # standard deviation of the heights
    world_points: np.ndarray  # (h * w, 3) the grid's points in the world frame (0-cells included)


def segment_stats(geometry: FrameGeometry, camera_to_world: np.ndarray) -> SegmentStats:
    labels = geometry.segments.ravel()
    n_seg = int(labels.max()) + 1 if labels.size else 1
    rot, t = camera_to_world[:3, :3], camera_to_world[:3, 3]
    world_points = geometry.points.reshape(-1, 3) @ rot.T + t
    p = world_points
    nw = geometry.normals.reshape(-1, 3) @ rot.T
    keep = labels > 0
    lab, p, nw = labels[keep], p[keep], nw[keep]
    cells = np.bincount(lab, minlength=n_seg).astype(np.float64)
    den = np.maximum(cells, 1)[:, None]
    centroid = np.stack([np.bincount(lab, p[:, k], n_seg) for k in range(3)], -1) / den
    normal = np.stack([np.bincount(lab, nw[:, k], n_seg) for k in range(3)], -1) / den
    z_low = np.full(n_seg, np.inf)
    z_high = np.full(n_seg, -np.inf)
    np.minimum.at(z_low, lab, p[:, 2])
    np.maximum.at(z_high, lab, p[:, 2])
    # Covariance per segment, for the plane fit and the horizontal extent.
    d = p - centroid[lab]
    cov = np.zeros((n_seg, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(lab, d[:, i] * d[:, j], n_seg) / den[:, 0]
    evals = np.linalg.eigvalsh(cov)  # ascending
    rms = np.sqrt(np.maximum(evals[:, 0], 0))
    horiz = cov[:, :2, :2]
    hev = np.linalg.eigvalsh(horiz)
    width = 4.0 * np.sqrt(np.maximum(hev[:, -1], 0))  # +-2 sigma of a uniform spread ~ its length
    z_std = np.sqrt(np.maximum(cov[:, 2, 2], 0))
    return SegmentStats(cells, centroid, normal, z_low, z_high, width, rms, z_std, world_points)


def layout_segments(stats: SegmentStats, floor_height: float, params: LayoutConfig) -> dict[str, np.ndarray]:
    """Boolean masks over segment ids: which segments are floor, wall and ceiling."""
    length = np.linalg.norm(stats.normal, axis=1)
    unit = stats.normal / np.maximum(length, 1e-12)[:, None]
    flat = length > 0.8  # a planar segment's normals agree
    cos_t = np.cos(np.radians(params.tilt_deg))
    sin_t = np.sin(np.radians(params.tilt_deg))
    rel_high = stats.z_high - floor_height
    rel_low = stats.z_low - floor_height
    planar = stats.rms <= params.planar_rms
    # Pieces lying wholly within a few centimetres of the floor are floor whatever their normals (the
    # floor's fragments between chair legs are small and noisy; no object is that flat on the floor).
    lying = (np.abs(stats.centroid[:, 2] - floor_height) < params.floor_band / 3) & (
        stats.z_std < params.floor_band / 6
    )
    floor = (flat & (unit[:, 2] > cos_t) & (rel_high < params.floor_band)) | lying
    ceiling = flat & (unit[:, 2] < -cos_t) & (rel_low > params.ceiling_min)
    tall = (rel_high - np.maximum(rel_low, 0)) >= params.wall_min_height
    wide = (stats.width >= params.wall_min_width) & (rel_high >= params.wall_wide_top)
    wall = flat & planar & (np.abs(unit[:, 2]) < sin_t) & (tall | wide)
    wall &= ~floor & ~ceiling
    for mask in (floor, wall, ceiling):
        mask[0] = False
    return {"floor": floor, "wall": wall, "ceiling": ceiling}


def class_reach(class_name: str, scale: float = 1.2) -> float:
    """How far (m) an object of this class reaches from its main segment: ``scale`` times the class's
    largest extent in the size priors, 1 m times ``scale`` for a class without one."""
    size = CLASS_SIZES.get(class_name)
    return (size.extent[1] if size else 1.0) * scale


def stuff_class_ids(vocabulary) -> dict[str, int]:
    """Vocabulary ids of the layout classes the planes name (floor, wall, ceiling)."""
    return {name: vocabulary.id(name) for name in LAYOUT_CLASSES if name in vocabulary}


@dataclass
class Region:
    """One 2D detection: a class id, a score and where it is (a box in frame pixels or a mask)."""

    class_id: int
    score: float
    box: tuple[float, float, float, float] | None = None  # x1, y1, x2, y2 in frame pixels
    mask: np.ndarray | None = None  # (H, W) bool at the frame's resolution
    extent: float = 1.0  # metres: the farthest an object of this class reaches from its main segment


def suppress_duplicates(
    regions: list[Region], iou: float = 0.75, contained: float = 0.8, grouped: float = 0.5
) -> list[Region]:
    """Drop boxes that describe an object a more confident box already describes: any class with a
    box overlap of ``iou`` or more (a table also called a desk), or the same class lying ``contained``
    inside it (a second chair box around the chair's back). Drop as well a box around a group: one
    holding more than ``grouped`` of each of two or more more confident boxes of its class (a weak
    "chair" spanning two chairs, which would take what lies between them: their bases, the floor's
    clutter). Masks are kept as they are."""
    kept: list[Region] = []
    for region in sorted(regions, key=lambda r: -r.score):
        if region.box is not None:
            x1, y1, x2, y2 = region.box
            area = max(x2 - x1, 0) * max(y2 - y1, 0)
            duplicate = False
            members = 0
            for other in kept:
                if other.box is None:
                    continue
                ox1, oy1, ox2, oy2 = other.box
                other_area = max(ox2 - ox1, 0) * max(oy2 - oy1, 0)
                inter = max(min(x2, ox2) - max(x1, ox1), 0) * max(min(y2, oy2) - max(y1, oy1), 0)
                union = area + other_area - inter
                same = other.class_id == region.class_id
                if inter >= iou * max(union, 1e-9) or (same and inter >= contained * max(area, 1e-9)):
                    duplicate = True
                    break
                members += int(same and inter > grouped * max(other_area, 1e-9))
            if duplicate or members >= 2:
                continue
        kept.append(region)
    return kept


def _region_masks(regions: list[Region], shape: tuple[int, int], stride: int) -> list[np.ndarray | None]:
    h, w = shape
    out: list[np.ndarray | None] = []
    for region in regions:
        if region.mask is not None:
            out.append(np.asarray(region.mask, bool)[::stride, ::stride][:h, :w])
        elif region.box is not None:
            x1, y1, x2, y2 = region.box
            inside = np.zeros((h, w), bool)
            r0, r1 = int(np.floor(max(y1, 0) / stride)), int(np.ceil(min(y2, h * stride) / stride))
            c0, c1 = int(np.floor(max(x1, 0) / stride)), int(np.ceil(min(x2, w * stride) / stride))
            inside[r0:r1, c0:c1] = True
            out.append(inside)
        else:
            out.append(None)
    return out


def _segment_boxes(labels: np.ndarray, n_seg: int) -> np.ndarray:
    """(n, 4) row0, col0, row1, col1 (exclusive) of each segment on the grid."""
    rows, cols = np.nonzero(labels)
    lab = labels[rows, cols]
    # Each bound in its own contiguous float array: ufunc.at takes its fast path only when the
    # values' dtype is the target's (integer rows into a float column run ten times slower).
    rows, cols = rows.astype(np.float64), cols.astype(np.float64)
    low = [np.full(n_seg, np.inf), np.full(n_seg, np.inf)]
    high = [np.zeros(n_seg), np.zeros(n_seg)]
    np.minimum.at(low[0], lab, rows)
    np.minimum.at(low[1], lab, cols)
    np.maximum.at(high[0], lab, rows + 1)
    np.maximum.at(high[1], lab, cols + 1)
    return np.stack([low[0], low[1], high[0], high[1]], axis=1)


def assign_regions(
    geometry: FrameGeometry,
    stats: SegmentStats,
    layout: dict[str, np.ndarray],
    regions: list[Region],
    inside_ratio: float = 0.5,
    gap: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """Segment -> (class id, instance id) arrays (instance ids are region indices + 1).

    A segment is a candidate of a region when at least ``inside_ratio`` of it lies inside the
    region. Each region first gets one core segment: pairs are taken best first by how well the
    segment fits the region (IoU of the segment's image box with a box, or of its pixels with a
    mask), so that where boxes overlap (a chair before a table) each one's core is the segment it
    frames best, not the largest one it happens to contain. Regions then grow through their other
    free candidates that come within ``gap`` (metres) of a segment they hold, nearest first, up to
    their class's ``extent`` from the core. Layout segments (floor, wall, ceiling) are never taken."""
    n_seg = len(stats.cells)
    seg_class = np.zeros(n_seg, np.int64)
    seg_instance = np.zeros(n_seg, np.int64)
    labels = geometry.segments
    free = np.ones(n_seg, bool)
    for name in ("floor", "wall", "ceiling"):
        free &= ~layout[name]
    free[0] = False
    if not regions or not free.any():
        return seg_class, seg_instance
    masks = _region_masks(regions, labels.shape, geometry.stride)
    seg_box = _segment_boxes(labels, n_seg)
    seg_area = (seg_box[:, 2] - seg_box[:, 0]).clip(0) * (seg_box[:, 3] - seg_box[:, 1]).clip(0)
    candidates: list[np.ndarray] = []
    pairs: list[tuple[float, float, int, int]] = []
    for k, (region, inside) in enumerate(zip(regions, masks, strict=True)):
        if inside is None:
            candidates.append(np.zeros(0, np.int64))
            continue
        in_count = np.bincount(labels[inside], minlength=n_seg)[:n_seg]
        cand = np.flatnonzero((in_count >= inside_ratio * np.maximum(stats.cells, 1)) & free)
        candidates.append(cand)
        if region.mask is not None:
            area = float(inside.sum())
            fit = in_count[cand] / np.maximum(stats.cells[cand] + area - in_count[cand], 1)
        else:
            rows, cols = np.nonzero(inside)
            r0, c0, r1, c1 = rows.min(), cols.min(), rows.max() + 1, cols.max() + 1
            b = seg_box[cand]
            ih = (np.minimum(b[:, 2], r1) - np.maximum(b[:, 0], r0)).clip(0)
            iw = (np.minimum(b[:, 3], c1) - np.maximum(b[:, 1], c0)).clip(0)
            inter = ih * iw
            fit = inter / np.maximum(seg_area[cand] + (r1 - r0) * (c1 - c0) - inter, 1)
        pairs.extend((float(f), region.score, k, int(c)) for f, c in zip(fit, cand, strict=True))
    core = np.full(len(regions), -1)
    taken = ~free
    for _, _, k, seg in sorted(pairs, key=lambda p: (-p[0], -p[1], p[2], p[3])):
        if core[k] < 0 and not taken[seg]:
            core[k] = seg
            taken[seg] = True
    for k in np.flatnonzero(core >= 0):
        seg_class[core[k]] = regions[k].class_id
        seg_instance[core[k]] = k + 1
    claims: dict[int, list[int]] = {}
    for k, cand in enumerate(candidates):
        if core[k] < 0:
            continue
        for seg in cand:
            if not taken[seg]:
                claims.setdefault(int(seg), []).append(k)
    if not claims:
        return seg_class, seg_instance
    # Objects are connected: a region grows from its core through the claimed segments that come
    # within ``gap`` of what it already holds (a leg under a table top, a chair's back above its
    # seat), nearest first across all regions, and no farther than its class reaches from the core.
    # A chair standing near a table, inside the table's box but apart from it, is not taken.
    points = _segment_points(geometry, stats, max_points=400)
    involved = sorted({*claims, *(int(c) for c in core[core >= 0])})
    trees: dict[int, Any] = {}  # built when first needed: most pairs are apart by their boxes
    near: dict[tuple[int, int], float] = {}

    def distance(a: int, b: int) -> float:
        key = (a, b) if a < b else (b, a)
        if key not in near:
            if a not in trees:
                trees[a] = spatial.cKDTree(points[a])
            # Only distances within the gap count (farther is never offered): the bound prunes the search.
            near[key] = float(trees[a].query(points[b], k=1, distance_upper_bound=gap * (1 + 1e-9))[0].min())
        return near[key]

    # Nearest first across all regions: a heap of (distance, segment, region), each pair's distance
    # the least to what the region holds so far, lowered as the region grows (stale entries skipped).
    # It takes the pairs in the order a scan of every open pair per step would, at a fraction of the
    # distance queries (the scan took 60 % of the detector's time on a real kitchen).
    reachable: dict[int, list[int]] = {}
    for seg in sorted(claims):
        for k in claims[seg]:
            if np.linalg.norm(stats.centroid[seg] - stats.centroid[core[k]]) <= regions[k].extent:
                reachable.setdefault(k, []).append(seg)
    open_segments = set(claims)
    nearest: dict[tuple[int, int], float] = {}
    heap: list[tuple[float, int, int]] = []

    # Boxes farther apart than the gap hold no points within it: no k-d tree query needed. Which
    # boxes are within the gap of which, for every pair at once (a list of lists: the loop below
    # looks pairs up thousands of times a frame).
    position = {seg: i for i, seg in enumerate(involved)}
    low = np.array([points[seg].min(axis=0) for seg in involved])
    high = np.array([points[seg].max(axis=0) for seg in involved])
    apart = np.maximum(np.maximum(low[:, None] - high[None], low[None] - high[:, None]), 0.0)
    boxes_near = (np.einsum("ijk,ijk->ij", apart, apart) <= gap * gap).tolist()

    def offer(seg: int, k: int, member: int) -> None:
        if not boxes_near[position[seg]][position[member]]:
            return
        d = distance(seg, member)
        if d <= gap and d < nearest.get((seg, k), np.inf):
            nearest[seg, k] = d
            heapq.heappush(heap, (d, seg, k))

    for k in np.flatnonzero(core >= 0):
        for seg in reachable.get(int(k), []):
            offer(seg, int(k), int(core[k]))
    while heap:
        d, seg, k = heapq.heappop(heap)
        if seg not in open_segments or nearest[seg, k] != d:
            continue
        seg_class[seg] = regions[k].class_id
        seg_instance[seg] = k + 1
        open_segments.discard(seg)
        for other in reachable[k]:
            if other in open_segments:
                offer(other, k, seg)
    return seg_class, seg_instance


def _segment_points(geometry: FrameGeometry, stats: SegmentStats, max_points: int = 0) -> dict[int, np.ndarray]:
    """World points of every segment (the same world frame as ``stats``); at most ``max_points`` each
    (an even subsample) when set."""
    labels = geometry.segments.ravel()
    pts = stats.world_points
    order = np.argsort(labels, kind="stable")
    ids, starts = np.unique(labels[order], return_index=True)
    bounds = np.append(starts, len(order))
    out = {}
    for j, i in enumerate(ids):
        if i <= 0:
            continue
        sel = order[bounds[j] : bounds[j + 1]]
        if max_points and len(sel) > max_points:
            sel = sel[np.linspace(0, len(sel) - 1, max_points).astype(int)]
        out[int(i)] = pts[sel]
    return out


def to_frame(values: np.ndarray, stride: int, shape: tuple[int, int]) -> np.ndarray:
    """Coarse-grid values back at the frame's resolution (nearest cell)."""
    h, w = shape
    rows = np.minimum(np.arange(h) // stride, values.shape[0] - 1)
    cols = np.minimum(np.arange(w) // stride, values.shape[1] - 1)
    return values[rows][:, cols]


def floor_height(stream, params: DepthSegmentsConfig, tilt_deg: float = 20.0, samples: int = 8) -> float | None:
    """The floor's height in a stream's world frame: 0 where the source put it there (gravity alignment,
    synthetic scenes), else the lowest height holding a fifth of the upward-facing planar surface seen in
    a sample of frames; None when no frame shows an upward-facing surface."""
    if "gravity_alignment" in stream.metadata or "scene_spec" in stream.metadata:
        return 0.0
    frames = stream.frames
    picks = np.unique(np.linspace(0, len(frames) - 1, min(samples, len(frames))).round().astype(int))
    heights, weights = [], []
    cos_t = np.cos(np.radians(tilt_deg))
    for i in picks:
        frame = frames[int(i)]
        geometry = frame_geometry(np.asarray(frame.depth), stream.intrinsics, params)
        stats = segment_stats(geometry, np.asarray(frame.pose))
        length = np.linalg.norm(stats.normal, axis=1)
        up = (length > 0.8) & (stats.normal[:, 2] / np.maximum(length, 1e-12) > cos_t)
        up[0] = False
        heights.extend(stats.centroid[up, 2].tolist())
        weights.extend(stats.cells[up].tolist())
    if not heights:
        return None
    order = np.argsort(heights)
    h = np.asarray(heights)[order]
    w = np.asarray(weights)[order]
    for k in range(len(h)):
        if w[np.abs(h - h[k]) <= 0.05].sum() >= 0.2 * w.sum():
            return float(h[k])
    return float(h[0])


def refine_labels(
    depth: np.ndarray,
    camera_to_world: np.ndarray,
    intrinsics: CameraIntrinsics,
    regions: list[Region],
    floor: float,
    stuff_ids: dict[str, int],
    seg_params: DepthSegmentsConfig,
    layout_params: LayoutConfig,
    inside_ratio: float = 0.5,
    gap: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """(class image, instance image) of one frame at its resolution: the regions (boxes or masks) take
    their objects' depth segments, floor, wall and ceiling come from gravity-aligned planes."""
    geometry = frame_geometry(depth, intrinsics, seg_params)
    stats = segment_stats(geometry, camera_to_world)
    layout = layout_segments(stats, floor, layout_params)
    seg_class, seg_instance = assign_regions(geometry, stats, layout, regions, inside_ratio, gap)
    for name, class_id in stuff_ids.items():
        seg_class[layout[name]] = class_id
    shape = np.asarray(depth).shape[:2]
    return (
        to_frame(seg_class[geometry.segments], geometry.stride, shape),
        to_frame(seg_instance[geometry.segments], geometry.stride, shape),
    )
