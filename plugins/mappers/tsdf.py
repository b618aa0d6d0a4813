"""Mapper ``tsdf``: Open3D VoxelBlockGrid TSDF fusion of RGB-D frames, with per-voxel label votes.

Geometry: colored surface points and a triangle mesh extracted from the TSDF.
Semantics (when a segmenter ran): every frame's labelled pixels vote for a (class, instance) in the
voxel they fall into; each voxel takes its majority, and every geometry point takes the label of the
nearest labelled voxel. Instances: the points of each instance id of a *thing* class, with their
gravity-aligned box. (Panoptic fusion with segment association grows here in the "Mapping" issue.)
"""

from __future__ import annotations

from typing import Any

import numpy as np
import open3d as o3d
import open3d.core as o3c
import trimesh
from pydantic import Field
from scipy.spatial import cKDTree

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry import gravity_aligned_box
from stratamap.core.layers import Geometry, ObjectInstance, ObjectInstances, Semantics
from stratamap.core.transforms import apply, invert

_BIAS = 1 << 20  # voxel coordinates are packed into 21 bits each


def pack_voxel_keys(points: np.ndarray, voxel_size: float) -> np.ndarray:
    idx = np.floor(points / voxel_size).astype(np.int64) + _BIAS
    return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]


def unpack_voxel_centers(keys: np.ndarray, voxel_size: float) -> np.ndarray:
    mask = (1 << 21) - 1
    idx = np.stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask], axis=1) - _BIAS
    return (idx.astype(np.float64) + 0.5) * voxel_size


def canonical_mesh(
    vertices: np.ndarray, faces: np.ndarray, vertex_colors: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vertices sorted lexicographically and faces sorted, so equal surfaces compare equal."""
    order = np.lexsort(vertices.T[::-1])
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    faces = rank[faces]
    faces = faces[np.lexsort(faces.T[::-1])] if len(faces) else faces
    return vertices[order], faces, None if vertex_colors is None else vertex_colors[order]


class LabelVotes:
    """Counts of (voxel, label) observations, reduced as they arrive so memory stays bounded."""

    def __init__(self) -> None:
        self._keys = np.zeros(0, np.int64)
        self._labels = np.zeros(0, np.int64)
        self._counts = np.zeros(0, np.int64)
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_size = 0

    @staticmethod
    def _reduce(keys: np.ndarray, labels: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        order = np.lexsort((labels, keys))
        keys, labels, counts = keys[order], labels[order], counts[order]
        start = np.ones(len(keys), bool)
        start[1:] = (keys[1:] != keys[:-1]) | (labels[1:] != labels[:-1])
        idx = np.flatnonzero(start)
        return keys[idx], labels[idx], np.add.reduceat(counts, idx) if len(idx) else counts[:0]

    def add(self, keys: np.ndarray, labels: np.ndarray) -> None:
        if len(keys) == 0:
            return
        self._pending.append(self._reduce(keys, labels, np.ones(len(keys), np.int64)))
        self._pending_size += len(self._pending[-1][0])
        if self._pending_size > 4_000_000:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        parts = [(self._keys, self._labels, self._counts), *self._pending]
        self._keys, self._labels, self._counts = self._reduce(*(np.concatenate(p) for p in zip(*parts, strict=True)))
        self._pending, self._pending_size = [], 0

    def majority(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per voxel: (keys, winning label, its share of the votes)."""
        self._flush()
        if len(self._keys) == 0:
            return self._keys, self._labels, np.zeros(0)
        # Sort by key, then by count descending: the first row of each key wins (ties: smallest label).
        order = np.lexsort((self._labels, -self._counts, self._keys))
        keys, labels, counts = self._keys[order], self._labels[order], self._counts[order]
        first = np.ones(len(keys), bool)
        first[1:] = keys[1:] != keys[:-1]
        starts = np.flatnonzero(first)
        totals = np.add.reduceat(counts, starts)
        return keys[starts], labels[starts], counts[starts] / totals


LABEL_SHIFT = 32  # label = class_id << 32 | instance_id


class TSDFConfig(StageConfig):
    voxel_size: float = Field(default=0.02, gt=0.001, le=0.5, description="Voxel edge length, metres.")
    truncation_voxels: float = Field(
        default=4.0, gt=1.0, le=20.0, description="TSDF truncation distance in voxels (Open3D's trunc_voxel_multiplier)."
    )
    depth_max: float = Field(default=5.0, gt=0.1, description="Ignore depth beyond this range, metres (noise grows with range).")
    depth_min: float = Field(default=0.1, ge=0.0, description="Ignore depth closer than this, metres.")
    block_resolution: int = Field(default=16, ge=4, le=32, description="Voxels per block edge of the hash map.")
    block_count: int = Field(default=40000, ge=1000, description="Initial number of hashed blocks (grows as needed).")
    label_stride: int = Field(default=2, ge=1, le=8, description="Every n-th pixel (in x and y) votes for voxel labels.")
    min_instance_points: int = Field(default=30, ge=1, description="Instances with fewer surface points are dropped.")
    cluster_tolerance: float = Field(
        default=0.05, gt=0.0, description="When instance ids are not tracked across frames: DBSCAN radius splitting a class into objects, metres."
    )
    extract_mesh: bool = Field(default=True, description="Also extract a triangle mesh (marching cubes) into the geometry layer.")


class TSDFMapper(Mapper):
    """TSDF fusion of RGB-D frames (Open3D VoxelBlockGrid) with per-voxel majority-vote labels."""

    name = "tsdf"
    Config = TSDFConfig
    requires = frozenset({"frames"})
    optional = frozenset({"frame_labels"})
    provides = frozenset({"geometry", "semantics", "instances"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg: TSDFConfig = self.config  # type: ignore[assignment]
        stream = data.stream
        assert stream is not None
        if stream.intrinsics is None:
            raise DataError(f"tsdf: the stream {stream.name!r} has no camera intrinsics")
        labels = data.frame_labels
        device = o3c.Device("CPU:0")
        vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=cfg.voxel_size,
            block_resolution=cfg.block_resolution,
            block_count=cfg.block_count,
            device=device,
        )
        intr = stream.intrinsics
        K = o3c.Tensor(intr.matrix, o3c.float64)
        votes = LabelVotes() if labels is not None else None
        integrated = 0
        for frame in self.progress(stream.frames, description="TSDF integration"):
            if frame.pose is None:
                raise DataError(f"tsdf: frame {frame.index} of {stream.name!r} has no pose; enable odometry or provide poses")
            depth = np.asarray(frame.depth, dtype=np.float32)
            if depth.shape != (intr.height, intr.width):
                raise DataError(
                    f"tsdf: frame {frame.index} depth is {depth.shape[1]}x{depth.shape[0]}, intrinsics say {intr.width}x{intr.height}"
                )
            depth = np.where(np.isfinite(depth) & (depth >= cfg.depth_min), depth, 0.0).astype(np.float32)
            if not np.any(depth > 0):
                self.warn(f"frame {frame.index} has no valid depth; skipped")
                continue
            extrinsic = o3c.Tensor(invert(frame.pose), o3c.float64)
            depth_img = o3d.t.geometry.Image(o3c.Tensor(depth))
            color_img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(frame.rgb.astype(np.float32) / 255.0)))
            coords = vbg.compute_unique_block_coordinates(
                depth_img, K, extrinsic, 1.0, cfg.depth_max, cfg.truncation_voxels
            )
            vbg.integrate(coords, depth_img, color_img, K, K, extrinsic, 1.0, cfg.depth_max, cfg.truncation_voxels)
            integrated += 1
            if votes is not None:
                seg = labels.frames[frame.index]
                self._vote(votes, depth, seg, intr, frame.pose, cfg)
        if integrated == 0:
            raise DataError(f"tsdf: no frame of {stream.name!r} had valid depth and a pose")

        # Open3D walks its hash map in a thread-dependent order: sort so runs are reproducible.
        pcd = vbg.extract_point_cloud()
        points = pcd.point.positions.numpy().astype(np.float64)
        order = np.lexsort(points.T[::-1])
        points = points[order]
        colors = np.clip(pcd.point.colors.numpy()[order], 0, 1) if "colors" in pcd.point else None
        mesh = None
        if cfg.extract_mesh:
            tmesh = vbg.extract_triangle_mesh()
            verts = tmesh.vertex.positions.numpy().astype(np.float64)
            faces = tmesh.triangle.indices.numpy().astype(np.int64)
            vcol = None
            if "colors" in tmesh.vertex:
                vcol = (np.clip(tmesh.vertex.colors.numpy(), 0, 1) * 255).astype(np.uint8)
            verts, faces, vcol = canonical_mesh(verts, faces, vcol)
            mesh = trimesh.Trimesh(verts, faces, vertex_colors=vcol, process=False)
        geometry = Geometry(points=points, colors=colors, mesh=mesh, voxel_size=cfg.voxel_size)
        self.note("frames_integrated", integrated)
        out: dict[str, Any] = {"geometry": geometry}
        if votes is None:
            return out

        semantics = self._label_points(points, votes, cfg, data)
        if not labels.tracked_instances:
            semantics = self._cluster_instances(points, semantics, cfg)
        out["semantics"] = semantics
        out["instances"] = self._instances(points, colors, semantics, cfg)
        return out

    @staticmethod
    def _vote(votes: LabelVotes, depth: np.ndarray, seg: Any, intr: Any, pose: np.ndarray, cfg: TSDFConfig) -> None:
        d = depth.copy()
        d[d > cfg.depth_max] = 0
        pts, flat = intr.backproject(d, stride=cfg.label_stride)
        if len(pts) == 0:
            return
        cls = seg.class_ids.reshape(-1)[flat].astype(np.int64)
        inst = seg.instance_ids.reshape(-1)[flat].astype(np.int64)
        keep = cls > 0
        world = apply(pose, pts[keep])
        votes.add(pack_voxel_keys(world, cfg.voxel_size), (cls[keep] << LABEL_SHIFT) | inst[keep])

    def _label_points(self, points: np.ndarray, votes: LabelVotes, cfg: TSDFConfig, data: PipelineData) -> Semantics:
        keys, labels, _ = votes.majority()
        class_ids = np.zeros(len(points), np.int32)
        instance_ids = np.zeros(len(points), np.int32)
        vocab = data.ground_truth.vocabulary if data.ground_truth is not None else data.map.vocabulary
        if len(keys) and len(points):
            tree = cKDTree(unpack_voxel_centers(keys, cfg.voxel_size))
            dist, idx = tree.query(points, distance_upper_bound=2.0 * cfg.voxel_size)
            hit = np.isfinite(dist)
            lab = labels[idx[hit]]
            class_ids[hit] = (lab >> LABEL_SHIFT).astype(np.int32)
            instance_ids[hit] = (lab & ((1 << LABEL_SHIFT) - 1)).astype(np.int32)
        stuff = ~np.asarray(vocab.is_thing)[np.clip(class_ids, 0, len(vocab) - 1)]
        instance_ids[stuff] = 0
        return Semantics(class_ids, instance_ids, vocab)

    @staticmethod
    def _cluster_instances(points: np.ndarray, sem: Semantics, cfg: TSDFConfig) -> Semantics:
        """Without tracked ids, split each thing class into spatial clusters (DBSCAN)."""
        instance_ids = np.zeros_like(sem.instance_ids)
        next_id = 1
        for cid in np.unique(sem.class_ids):
            if cid <= 0 or not sem.vocabulary.is_thing[cid]:
                continue
            sel = np.flatnonzero(sem.class_ids == cid)
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[sel]))
            lab = np.asarray(pc.cluster_dbscan(eps=cfg.cluster_tolerance, min_points=5))
            for c in np.unique(lab[lab >= 0]):
                instance_ids[sel[lab == c]] = next_id
                next_id += 1
        return Semantics(sem.class_ids, instance_ids, sem.vocabulary)

    @staticmethod
    def _instances(points: np.ndarray, colors: np.ndarray | None, sem: Semantics, cfg: TSDFConfig) -> ObjectInstances:
        out = ObjectInstances()
        for iid in np.unique(sem.instance_ids):
            if iid <= 0:
                continue
            sel = sem.instance_ids == iid
            if sel.sum() < cfg.min_instance_points:
                continue
            cls = np.bincount(sem.class_ids[sel]).argmax()
            pts = points[sel]
            out.add(
                ObjectInstance(
                    id=int(iid),
                    class_name=sem.vocabulary.name(cls),
                    points=pts,
                    colors=None if colors is None else colors[sel],
                    box=gravity_aligned_box(pts),
                    score=float((sem.class_ids[sel] == cls).mean()),
                )
            )
        return out


@hookimpl
def stratamap_register_mappers():
    return [TSDFMapper]
