"""TSDF integration shared by the ``tsdf`` and ``semantic_tsdf`` mappers: an Open3D
VoxelBlockGrid with colour (and any label attributes a mapper adds), fed one posed RGB-D frame at a
time, and its surface extracted in an order that does not depend on Open3D's threads."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import StageConfig
from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import invert
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Geometry
from stratamap.core.map.sensors import CameraIntrinsics

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")
trimesh = lazy_module("trimesh")


def label_stride(configured: int | None, width: int) -> int:
    """Pixel stride of label fusion: about one sample per 2 cm voxel at 2-3 m whatever the resolution."""
    return configured if configured is not None else max(1, round(width / 160))


QUANTUM = 1e-5  # 10 micrometres: far below any voxel size, so keys are exact for TSDF surfaces


def _grid_keys(points: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(int64 key per point on a 10 um grid, the grid coordinates of each point), or None when the
    extent is too large to pack three coordinates into 63 bits. The grid is fixed in the world (not
    placed at the points' minimum), so a point keeps its grid position whatever the others are."""
    q = np.rint(points / QUANTUM).astype(np.int64)
    rel = q - q.min(0)
    span = rel.max(0) + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2**62:
        return None
    return (rel[:, 0] * span[1] + rel[:, 1]) * span[2] + rel[:, 2], q


def position_order(points: np.ndarray, colors: np.ndarray | None = None) -> np.ndarray:
    """An order of points by position (x, then y, then z on a 10 um grid; then colour; then exact
    position), so clouds extracted in thread-dependent order compare equal: the order is total on
    the values, never left to the order the points came in."""
    if len(points) == 0:
        return np.zeros(0, np.int64)
    colour_bits = None if colors is None else np.ascontiguousarray(colors, dtype=np.float32).view(np.uint32)
    packed = _grid_keys(points)
    if packed is None:
        keys = [points[:, 2], points[:, 1], points[:, 0]]
        if colour_bits is not None:
            keys = [colour_bits[:, k] for k in (2, 1, 0)] + keys
        return np.lexsort(keys)
    keys = packed[0]
    # Most keys are distinct: one plain sort, then only the few points sharing a grid cell sorted by the
    # rest. Those are points a hair apart (a voxel's surface crossing on two edges at its corner): their
    # colours may tie as well, and their order must then come from their exact positions.
    order = np.argsort(keys)
    sorted_keys = keys[order]
    same = sorted_keys[1:] == sorted_keys[:-1]
    if not same.any():
        return order
    tied = np.zeros(len(keys), bool)
    tied[1:] = same
    tied[:-1] |= same
    at = np.flatnonzero(tied)  # runs of equal keys, each contiguous in the sorted order
    members = order[at]
    exact = np.ascontiguousarray(points[members], dtype=np.float64).view(np.uint64)
    rest = [exact[:, 2], exact[:, 1], exact[:, 0]]
    if colour_bits is not None:
        rest += [colour_bits[members, k] for k in (2, 1, 0)]
    order[at] = members[np.lexsort([*rest, sorted_keys[at]])]
    return order


def canonical_mesh(
    vertices: np.ndarray, faces: np.ndarray, vertex_colors: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The same mesh whatever order Open3D's threads produced it in: vertices merged where they
    coincide (marching cubes emits duplicates at block borders) and sorted by position on a 10 um
    grid, duplicate (integer) colours averaged (integer sums: order-free), faces sorted."""
    if len(vertices) == 0:
        return vertices, faces, vertex_colors
    packed = _grid_keys(vertices)
    if packed is None:
        unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        first = None
    else:
        keys, q = packed
        # Duplicates share their key and so their grid position: which of them sorts first does not
        # matter, and an unstable sort is faster than the stable one np.unique(return_index) takes.
        order = np.argsort(keys)
        sorted_keys = keys[order]
        starts = np.ones(len(keys), bool)
        starts[1:] = sorted_keys[1:] != sorted_keys[:-1]
        inverse = np.empty(len(keys), np.int64)
        inverse[order] = np.cumsum(starts) - 1
        first = order[starts]
        unique = q[first] * QUANTUM
    colors = None if vertex_colors is None else _merged_colours(vertex_colors, inverse, len(unique), first)
    return unique, _sorted_faces(inverse[faces], len(unique)), colors


def _merged_colours(vertex_colors: np.ndarray, inverse: np.ndarray, n: int, first: np.ndarray | None) -> np.ndarray:
    """Per merged vertex, the rounded integer mean of its vertices' colours. A TSDF mesh has few
    duplicates (a few dozen in 300,000 vertices): the others keep their colour as it is, which is
    what the mean of one gives, and only the merged ones are summed."""
    count = np.bincount(inverse, minlength=n)
    if first is None:
        first = np.empty(n, np.int64)
        first[inverse] = np.arange(len(inverse))
    colors = vertex_colors[first]
    is_merged = count > 1
    merged = np.flatnonzero(is_merged)
    if len(merged):
        members = np.flatnonzero(is_merged[inverse])
        group = (np.cumsum(is_merged) - 1)[inverse[members]]
        acc = np.stack(
            [
                np.bincount(group, weights=vertex_colors[members, k], minlength=len(merged)).astype(np.int64)
                for k in range(vertex_colors.shape[1])
            ],
            axis=1,
        )
        size = count[merged][:, None]
        colors[merged] = ((2 * acc + size) // (2 * size)).astype(vertex_colors.dtype)
    return colors


def _sorted_faces(faces: np.ndarray, n: int) -> np.ndarray:
    """Faces (vertex indices below ``n``) in lexicographic order. Each face packed into one integer
    (equal keys: equal rows) and the keys sorted and unpacked: no argsort, no gather of rows."""
    if len(faces) == 0:
        return faces
    bits = max(1, int(n - 1).bit_length())
    if 3 * bits > 63:
        return faces[np.lexsort(faces.T[::-1])]
    mask = np.int64((1 << bits) - 1)
    keys = (faces[:, 0] << (2 * bits)) | (faces[:, 1] << bits) | faces[:, 2]
    keys.sort()
    out = np.empty(faces.shape, np.int64)
    out[:, 0] = keys >> (2 * bits)
    out[:, 1] = (keys >> bits) & mask
    out[:, 2] = keys & mask
    return out


class IntegrationConfig(StageConfig):
    """TSDF integration settings shared by the ``tsdf`` and ``semantic_tsdf`` mappers."""

    voxel_size: float = Field(default=0.02, gt=0.001, le=0.5, description="Voxel edge length, metres.")
    truncation_voxels: float = Field(
        default=4.0,
        gt=1.0,
        le=20.0,
        description="TSDF truncation distance in voxels (Open3D's trunc_voxel_multiplier).",
    )
    depth_max: float = Field(
        default=5.0, gt=0.1, description="Ignore depth beyond this range, metres (noise grows with range)."
    )
    depth_min: float = Field(default=0.1, ge=0.0, description="Ignore depth closer than this, metres.")
    block_resolution: int = Field(
        default=8,
        ge=4,
        le=32,
        description="Voxels per block edge of the hash map (8: little memory spent on free space).",
    )
    block_count: int = Field(
        default=20000, ge=1000, description="Initial number of hashed blocks (the hash map grows as needed)."
    )
    label_stride: int | None = Field(
        default=None,
        ge=1,
        le=16,
        description=(
            "Every n-th pixel (in x and y) takes part in label fusion. Default: width / 160 (4 at 640 px); for the "
            "tsdf mapper's "
            "'masks' extraction, the widest stride that still samples every voxel at depth_max, voxel_size * fx / "
            "depth_max "
            "(2 for 2 cm voxels and a Kinect-like camera at 5 m)."
        ),
    )
    extract_mesh: bool = Field(
        default=True, description="Also extract a triangle mesh (marching cubes) into the geometry layer."
    )
    min_frames: int = Field(
        default=4,
        ge=1,
        description=(
            "A surface voxel is kept when at least this many frames saw it (Open3D's default weight threshold, "
            "more than 3: a few frames' outliers are dropped); a sequence of fewer frames keeps what all of them "
            "saw, so that one frame still makes a map."
        ),
    )
    min_view_share: float = Field(
        default=1.0,
        ge=0.0,
        le=1.0,
        description=(
            "Nor more frames than this share of those that saw the typical surface voxel (the median near the "
            "surface): min_frames is there to drop outliers, not the typical surface, which a sparse sequence "
            "(keyframes, a stride, a fast walk) sees fewer times than min_frames. 0: min_frames alone."
        ),
    )


#: Open3D finds the blocks a frame touches from every 4th pixel in x and y (``down_factor`` in
#: ``VoxelBlockGrid::GetUniqueBlockCoordinates``), and aborts when none is: a frame whose depth in
#: range lies only between those pixels cannot be integrated either.
TOUCH_STRIDE = 4
#: Frame numbers a warning or error lists before it says how many more there are (the run's notes list all).
LISTED_FRAMES = 12


def frame_list(indices: Sequence[int]) -> str:
    """``3, 4, 7-12`` (runs of consecutive frames as ranges), the first ``LISTED_FRAMES`` of them."""
    runs: list[list[int]] = []
    for k in sorted(indices):
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    parts = [str(a) if a == b else f"{a}-{b}" for a, b in runs]
    more = len(parts) - LISTED_FRAMES
    return ", ".join(parts[:LISTED_FRAMES]) + (f" and {more} more runs of frames" if more > 0 else "")


class FrameSkips:
    """The frames a mapper left out, by why: one bad frame of a recording (a view down a corridor with
    nothing within depth_max, a frame odometry lost) is left out and reported, never fatal; only a
    sequence with no usable frame at all is an error."""

    def __init__(self, mapper: str):
        self.mapper = mapper
        self.by_reason: dict[str, list[int]] = {}

    def add(self, reason: str, index: int) -> None:
        self.by_reason.setdefault(reason, []).append(int(index))

    def __len__(self) -> int:
        return sum(len(v) for v in self.by_reason.values())

    def summary(self) -> str:
        return "; ".join(
            f"{len(idx)} with {reason} (frame{'s' if len(idx) > 1 else ''} {frame_list(idx)})"
            for reason, idx in self.by_reason.items()
        )

    def finish(self, stage: Any, used: int, total: int, stream: str) -> None:
        """Warn and note what was skipped, or raise when no frame was usable."""
        if used == 0:
            what = f"its {total} frames" if total != 1 else "its only frame"
            detail = f": {self.summary()}" if len(self) else ""
            raise DataError(f"{self.mapper}: no usable RGB-D frame in {what} of {stream!r}{detail}")
        if len(self):
            stage.warn(f"skipped {len(self)} of {total} frames: {self.summary()}")
            stage.note("frames_skipped", {reason: list(idx) for reason, idx in self.by_reason.items()})


#: Voxels whose truncated signed distance is under this share of the truncation band lie near a
#: surface; their weights are the views the surface had.
NEAR_SURFACE = 0.3
#: Blocks of a map sampled for its typical views (a 20,000-block sample is 10 million voxels).
VIEW_SAMPLE_BLOCKS = 20_000
#: Blocks read at a time to find the typical views (256 blocks of 8^3 voxels: 0.8 MB of weights and TSDF).
VIEW_CHUNK_BLOCKS = 256


class TSDFVolume:
    """A TSDF with colour in an Open3D VoxelBlockGrid, plus ``extra`` voxel attributes
    (name, dtype, channels) that a mapper fuses labels into."""

    def __init__(
        self, cfg: IntegrationConfig, intrinsics: CameraIntrinsics, extra: Sequence[tuple[str, Any, int]] = ()
    ):
        self.cfg = cfg
        self.intrinsics = intrinsics
        # 16-bit weights and colours (the pair Open3D integrates besides float/float; colours are kept on 0-255
        # either way and averaged in integers): 18 bytes a voxel with labels instead of 28, most of a large map.
        names, dtypes, channels = ["tsdf", "weight", "color"], [o3c.float32, o3c.uint16, o3c.uint16], [1, 1, 3]
        for name, dtype, n in extra:
            names.append(name)
            dtypes.append(dtype)
            channels.append(n)
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            attr_names=tuple(names),
            attr_dtypes=tuple(dtypes),
            attr_channels=tuple(channels),
            voxel_size=cfg.voxel_size,
            block_resolution=cfg.block_resolution,
            block_count=cfg.block_count,
            device=o3c.Device("CPU:0"),
        )
        self._K = o3c.Tensor(intrinsics.matrix, o3c.float64)
        self.frames = 0
        self.views_needed: int | None = None  # set by surface()

    def valid_depth(self, frame: Any, mapper: str) -> np.ndarray:
        """The frame's depth with non-finite and too-near pixels zeroed (float32)."""
        intr = self.intrinsics
        depth = np.asarray(frame.depth, dtype=np.float32)
        if depth.shape != (intr.height, intr.width):
            raise DataError(
                f"{mapper}: frame {frame.index} depth is {depth.shape[1]}x{depth.shape[0]}, intrinsics say "
                f"{intr.width}x{intr.height}"
            )
        return np.where(np.isfinite(depth) & (depth >= self.cfg.depth_min), depth, 0.0).astype(np.float32)

    @property
    def out_of_range(self) -> str:
        """Why a frame with no depth Open3D can integrate is skipped."""
        return f"no depth within depth_min-depth_max ({self.cfg.depth_min:g}-{self.cfg.depth_max:g} m)"

    def usable_depth(self, frame: Any) -> tuple[np.ndarray | None, str]:
        """The frame's depth as :meth:`valid_depth` gives it, or None and why the frame cannot be
        integrated: a depth image of another size than the camera's, a colour image of another size
        than its depth, no depth in range, or no pose (or one with NaNs)."""
        intr = self.intrinsics
        size = f"{intr.width}x{intr.height}"
        depth = np.asarray(frame.depth)
        if depth.shape != (intr.height, intr.width):
            return None, f"depth {'x'.join(map(str, depth.shape[::-1]))}, the intrinsics say {size}"
        rgb = np.asarray(frame.rgb)
        if rgb.shape[:2] != depth.shape:
            return None, f"a colour image of {'x'.join(map(str, rgb.shape[1::-1]))}, its depth {size}"
        depth = self.valid_depth(frame, "tsdf")
        touched = depth[::TOUCH_STRIDE, ::TOUCH_STRIDE]
        if not np.any((touched > 0) & (touched < self.cfg.depth_max)):
            return None, self.out_of_range
        if frame.pose is None:
            return None, "no pose (enable odometry, or provide poses)"
        pose = np.asarray(frame.pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            return None, "a pose that is not a finite 4x4 matrix"
        return depth, ""

    def integrate(self, depth: np.ndarray, rgb: np.ndarray, pose: np.ndarray) -> bool:
        """Fuse one frame (depth from :meth:`valid_depth`, camera-to-world ``pose``); False when
        Open3D found no block the frame touches (nothing was fused)."""
        cfg = self.cfg
        extrinsic = o3c.Tensor(invert(pose), o3c.float64)
        depth_img = o3d.t.geometry.Image(o3c.Tensor(depth))
        color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0))
        try:
            coords = self.grid.compute_unique_block_coordinates(
                depth_img, self._K, extrinsic, 1.0, cfg.depth_max, cfg.truncation_voxels
            )
        except RuntimeError as exc:
            # usable_depth() checks the pixels Open3D 0.20 samples; another version may sample others.
            if "No block is touched" in str(exc):
                return False
            raise
        self.grid.integrate(
            coords, depth_img, color_img, self._K, self._K, extrinsic, 1.0, cfg.depth_max, cfg.truncation_voxels
        )
        self.frames += 1
        return True

    def _views_needed(self) -> int:
        """Frames that must have seen a surface voxel for it to be kept: ``min_frames``, at most the frames
        integrated, and at most ``min_view_share`` of the frames that saw the typical voxel near the surface.
        A video sees its surfaces dozens of times (the real align3d clip: 31 of 31 frames, the median); a
        40-frame walk read every fifth frame sees them twice, and ``min_frames`` alone kept 2 % of it. A
        lower share keeps more of a sparse sequence and more of what few frames saw: on Open3D's five
        rendered living-room frames, a lamp's stem seen by three joined the armchair beside it."""
        cfg = self.cfg
        needed = max(1, min(cfg.min_frames, self.frames))
        if cfg.min_view_share <= 0 or needed == 1:
            return needed
        hashmap = self.grid.hashmap()
        active = np.sort(hashmap.active_buf_indices().numpy().astype(np.int64))
        if len(active) == 0:
            return needed
        # A large map's median from a sample of its blocks, chosen by their coordinates (not by Open3D's
        # buffer order, which depends on threads) so that the same map gives the same threshold.
        if len(active) > VIEW_SAMPLE_BLOCKS:
            keys = hashmap.key_tensor().numpy()[active].astype(np.int64)
            mixed = (keys[:, 0] * 73856093) ^ (keys[:, 1] * 19349663) ^ (keys[:, 2] * 83492791)
            active = active[mixed % (len(active) // VIEW_SAMPLE_BLOCKS + 1) == 0]
        voxels = self.cfg.block_resolution**3
        weight_blocks = self.grid.attribute("weight").numpy().reshape(-1, voxels)
        tsdf_blocks = self.grid.attribute("tsdf").numpy().reshape(-1, voxels)
        # A few hundred blocks at a time: their copies and masks stay in the cache, where those of a whole
        # map's voxels at once did not (the median does not depend on the order of the values).
        parts = []
        for start in range(0, len(active), VIEW_CHUNK_BLOCKS):
            rows = active[start : start + VIEW_CHUNK_BLOCKS]
            weights, tsdf = weight_blocks[rows].ravel(), tsdf_blocks[rows].ravel()
            parts.append(weights[(weights >= 1) & (np.abs(tsdf) < NEAR_SURFACE)])
        near = np.concatenate(parts)
        if len(near) == 0:
            return needed
        typical = float(np.median(near))
        return int(max(1, min(needed, np.floor(cfg.min_view_share * typical))))

    def surface(self) -> Geometry:
        """Surface points (sorted by position, so runs are reproducible) and, if configured, the mesh."""
        # Each frame adds 1 to the weight of the voxels it sees; Open3D keeps weights above the threshold.
        self.views_needed = self._views_needed()
        weight = self.views_needed - 0.5
        # On all threads: Open3D computes each point from its own voxel and neighbour alone, and emits the
        # points in an order that depends on the threads. The runs once seen to differ were points tied
        # in the sort (same grid cell, same colour) left in that order; position_order's order is total
        # on the values, so the sorted cloud is the same whatever their number (a test checks it).
        pcd = self.grid.extract_point_cloud(weight)
        points = pcd.point.positions.numpy().astype(np.float64)
        raw_colors = pcd.point.colors.numpy() if "colors" in pcd.point else None
        order = position_order(points, raw_colors)
        points = points[order]
        colors = None if raw_colors is None else np.clip(raw_colors[order], 0, 1)
        mesh = None
        if self.cfg.extract_mesh:
            # On all threads: the canonical mesh comes out the same whatever their number (a test checks it).
            tmesh = self.grid.extract_triangle_mesh(weight)
            verts = tmesh.vertex.positions.numpy().astype(np.float64)
            faces = tmesh.triangle.indices.numpy().astype(np.int64)
            vcol = None
            if "colors" in tmesh.vertex:
                vcol = (np.clip(tmesh.vertex.colors.numpy(), 0, 1) * 255).astype(np.uint8)
            verts, faces, vcol = canonical_mesh(verts, faces, vcol)
            mesh = trimesh.Trimesh(verts, faces, vertex_colors=vcol, process=False)
        return Geometry(points=points, colors=colors, mesh=mesh, voxel_size=self.cfg.voxel_size)
