"""Mapper ``tsdf``: Open3D VoxelBlockGrid TSDF fusion with panoptic label fusion.

Geometry: colored surface points and a triangle mesh extracted from the TSDF.
Semantics and instances (when a segmenter ran): panoptic fusion as in the functional-scenes paper
(see :mod:`stratamap.plugins.mappers.tsdf.panoptic_fusion`): per-frame segments associated to global segment labels by
3D overlap, counts Phi(l, c, p), label merging by shared-voxel ratio, instance merging, and
extraction of panoptic entities. Segment labels live in the TSDF's own voxel blocks, so label
fusion adds little to integration (``benchmarks/mapping_throughput.py`` measures how little).
With ``instances: masks`` the map's instances come instead from per-voxel class votes and 3D
pieces re-joined by the frames' masks (:mod:`stratamap.plugins.mappers.tsdf.mask_instances`), for learned segmenters.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import closing
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, hookimpl
from stratamap.core.errors import ConfigError, DataError
from stratamap.core.geometry.points import VOXEL_NEIGHBOURS
from stratamap.core.geometry.transforms import apply
from stratamap.core.lazy import lazy_module
from stratamap.core.map.instances import (
    instances_from_semantics,
    merge_overlapping_instances,
    veto_implausible_classes,
)
from stratamap.core.map.layers import Semantics
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.parallel import ahead
from stratamap.core.stages import warn_renamed
from stratamap.plugins.mappers._volume import FrameSkips, IntegrationConfig, TSDFVolume, label_stride
from stratamap.plugins.mappers.tsdf.config import RENAMED, Pieces
from stratamap.plugins.mappers.tsdf.mask_instances import MaskInstanceParams, MaskObservations, mask_instances
from stratamap.plugins.mappers.tsdf.panoptic_fusion import PanopticParams, PanopticState

o3c = lazy_module("open3d.core")


def vote_stride(configured: int | None, intrinsics: CameraIntrinsics, voxel_size: float, depth_max: float) -> int:
    """Pixel stride of the per-voxel class votes ('masks'): the widest at which neighbouring samples
    still fall at most a voxel apart at depth_max, so that every voxel a frame sees in range gets
    that frame's vote. Denser sampling adds no weight: a voxel votes once per frame."""
    if configured is not None:
        return configured
    return max(1, int(voxel_size * min(intrinsics.fx, intrinsics.fy) / depth_max + 1e-9))


def first_of_each(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(values, return_index=True)`` for non-negative integers: the distinct values, sorted,
    and where each first occurs. Each value packed with its position into one integer (no two equal),
    so that a plain sort of the keys gives the order of the stable argsort np.unique takes, which is
    the slower sort."""
    n = len(values)
    bits = max(1, (n - 1).bit_length())
    if n == 0 or int(values.min()) < 0 or int(values.max()) >= 1 << (62 - bits):
        return np.unique(values, return_index=True)
    keys = (values.astype(np.int64) << bits) | np.arange(n, dtype=np.int64)
    keys.sort()
    distinct = keys >> bits
    starts = np.ones(n, bool)
    starts[1:] = distinct[1:] != distinct[:-1]
    return distinct[starts], keys[starts] & ((1 << bits) - 1)


class TSDFConfig(IntegrationConfig):
    renamed: ClassVar[Mapping[str, str]] = RENAMED  # the flat piece_* keys of the release before

    associate_ratio: float = Field(
        default=0.2, gt=0, le=1, description="Min overlap Pi(s, l) / |s| to associate a frame segment with a label."
    )
    merge_ratio: float = Field(
        default=0.5, gt=0, le=1, description="Shared-voxel ratio above which a segment's two labels vote to merge."
    )
    merge_votes: int = Field(default=2, ge=1, description="Frames of merge votes before two labels merge.")
    instance_merge_ratio: float = Field(
        default=0.3, gt=0, le=1, description="Share of a label's votes two instances must each hold to merge (eq. 5)."
    )
    fragment_touch: float = Field(
        default=1.5,
        ge=0.0,
        description=(
            "'labels': same-class instances never segmented apart in one frame merge when their points come this "
            "close, "
            "in voxels (0 turns it off)."
        ),
    )
    min_instance_points: int = Field(default=30, ge=1, description="Instances with fewer surface points are dropped.")
    overlap_merge: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description=(
            "Two objects do not fill the same space: instances whose gravity-aligned boxes overlap at this 3D IoU "
            "or more become one (the class most of its points hold); 0 turns it off."
        ),
    )
    size_veto: bool = Field(
        default=False,
        description=(
            "Class size priors (core/map/priors.py) veto impossible labels: an instance too large for its class "
            "(a 2.2 m chair) takes its next most voted class that fits, else 'object'. Off by default: on the "
            "segmentation benchmark's held-out walks it lowered onnx_panoptic's map PQ from 0.835 to 0.808."
        ),
    )
    instances: Literal["labels", "masks"] = Field(
        default="labels",
        description=(
            "How map instances are extracted. 'labels' (the papers'): each label's class and instance (Voxblox++ eq. "
            "6) plus fragment "
            "merging. 'masks' (for learned segmenters): each point's class by its voxel's per-frame class votes; the "
            "label instances "
            "cut into connected pieces and re-joined where the frames' 2D masks keep covering them together (one "
            "frame's mask over "
            "two chairs does not fuse them)."
        ),
    )
    read_ahead: int = Field(
        default=2,
        ge=0,
        le=16,
        description=(
            "Frames read, depth-checked and label-unpacked ahead of the integration, in one background thread (0: "
            "one loop, no thread); decoding leaves the GIL while Open3D integrates the frame before. The map is the "
            "same either way."
        ),
    )
    pieces: Pieces = Field(
        default_factory=Pieces,
        description="With instances: masks, how the label instances are cut into 3D pieces, re-joined and dropped.",
    )


class TSDFMapper(Mapper[TSDFConfig]):
    """TSDF fusion of RGB-D frames (Open3D VoxelBlockGrid) with panoptic label fusion."""

    name = "tsdf"
    Config = TSDFConfig
    requires = frozenset({"frames"})
    optional = frozenset({"frame_labels", "ground_truth"})
    provides = frozenset({"geometry", "semantics", "instances"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        warn_renamed(self)
        stream = data.stream
        assert stream is not None
        if stream.intrinsics is None:
            raise DataError(f"tsdf: the stream {stream.name!r} has no camera intrinsics")
        labels = data.frame_labels
        if labels is not None and len(labels) != len(stream.frames):
            raise DataError(f"tsdf: {len(labels)} label images for {len(stream.frames)} frames")
        volume = TSDFVolume(
            cfg,
            stream.intrinsics,
            extra=[("label", o3c.int32, 1), ("conf", o3c.int16, 1)] if labels is not None else [],
        )
        vbg = volume.grid
        vocab = data.ground_truth.vocabulary if data.ground_truth is not None else data.map.vocabulary
        if cfg.instances == "masks":  # before integration, not after minutes of it
            named = {
                "pieces.max_length.{}": cfg.pieces.max_length,
                "pieces.min_points_by_class.{}": cfg.pieces.min_points_by_class,
                "pieces.stacked_classes: {!r}": cfg.pieces.stacked_classes,
            }
            problems = [
                (f"tsdf.{key.format(name)}", f"not a class of the map's vocabulary {list(vocab.names)}")
                for key, names in named.items()
                for name in sorted(set(names) - set(vocab.names))
            ]
            if problems:
                raise ConfigError(problems)
        state = PanopticState(
            PanopticParams(cfg.associate_ratio, cfg.merge_ratio, cfg.merge_votes, cfg.instance_merge_ratio),
            vocab,
            voxels_per_block=cfg.block_resolution**3,
        )
        observations = MaskObservations()
        intr = stream.intrinsics
        integrated = 0
        skips = FrameSkips("tsdf")

        def read(k: int) -> tuple[Any, tuple[np.ndarray | None, str], Any]:
            """Frame ``k``, its usable depth and its labels, read (and decoded, unpacked) a few frames
            ahead of the integration in a thread."""
            frame = stream.frames[k]
            return frame, volume.usable_depth(frame), labels.frames[frame.index] if labels is not None else None

        frames = (
            ahead(range(len(stream.frames)), read, depth=cfg.read_ahead)
            if cfg.read_ahead
            else ((k, read(k)) for k in range(len(stream.frames)))
        )
        with closing(frames):  # ended here, also on an error (not later by the garbage collector)
            for _, (frame, (depth, reason), seg) in self.progress(
                frames, total=len(stream.frames), description="TSDF integration"
            ):
                if depth is None or not volume.integrate(depth, frame.rgb, frame.pose):
                    skips.add(reason or volume.out_of_range, frame.index)
                    continue
                integrated += 1
                if seg is not None and seg.labelled:
                    self._fuse_labels(vbg, state, observations, depth, seg, intr, frame.pose, cfg)
        skips.finish(self, integrated, len(stream.frames), stream.name)

        geometry = volume.surface()
        if len(geometry.points) == 0:
            raise DataError(
                f"tsdf: no surface of {stream.name!r} was seen by {volume.views_needed} of its "
                f"{integrated} frames (min_frames); lower min_frames, or give more or larger frames"
            )
        points, colors = geometry.points, geometry.colors
        self.note("frames_integrated", integrated)
        self.note("surface_views_needed", volume.views_needed)
        out: dict[str, Any] = {"geometry": geometry}
        if labels is None:
            return out

        merged = state.merge_instances()
        classes, instances = state.label_table()
        point_labels = self._point_labels(vbg, points, cfg)
        point_class, point_instance = classes[point_labels], instances[point_labels]
        fragments: dict[int, int] = {}
        if cfg.instances == "masks":
            point_class, point_instance = mask_instances(
                points,
                point_class,
                point_instance,
                observations,
                vocab,
                cfg.voxel_size,
                MaskInstanceParams(**cfg.pieces.model_dump()),
            )
        elif cfg.fragment_touch > 0:
            fragments = state.merge_fragments(point_class, point_instance, points, cfg.fragment_touch * cfg.voxel_size)
        # Instances too small to keep leave no fragments behind in the semantics layer either.
        ids, sizes = np.unique(point_instance[point_instance > 0], return_counts=True)
        small = ids[sizes < cfg.min_instance_points]
        if len(small):
            drop = np.isin(point_instance, small)
            point_class[drop], point_instance[drop] = 0, 0
        if cfg.overlap_merge > 0:
            point_instance, overlapping = merge_overlapping_instances(points, point_instance, cfg.overlap_merge)
            if overlapping:
                self.note("overlapping_instances_merged", overlapping)
        vetoed: list[dict] = []
        if cfg.size_veto:
            point_class, vetoed = veto_implausible_classes(points, point_class, point_instance, vocab)
        semantics = Semantics(point_class, point_instance, vocab)
        if vetoed:
            self.note("size_vetoes", vetoed)
        self.note(
            "panoptic",
            {
                "segment_labels": state.next_label - 1,
                "labels_merged": len(state.merged_into),
                "instances_merged": len(merged),
                "fragments_merged": len(fragments),
                "small_instances_dropped": len(small),
            },
        )
        out["semantics"] = semantics
        kind = "masks" if cfg.instances == "masks" else "labels"
        naming = ("labels", f"the {labels.segmenter} segmenter's {kind} of each frame, fused in the TSDF")
        out["instances"] = instances_from_semantics(points, colors, semantics, cfg.min_instance_points, naming=naming)
        return out

    @staticmethod
    def _flat_indices(vbg: Any, voxels: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices into the voxel attributes of integer voxel coordinates (and which exist)."""
        if len(voxels) == 0:  # a frame its segmenter labelled nothing in; Open3D's hash map refuses no keys
            return np.zeros(0, np.int64), np.zeros(0, bool)
        block = np.floor_divide(voxels, res)
        local = voxels - block * res
        buf, found = vbg.hashmap().find(o3c.Tensor(block.astype(np.int32)))
        buf = buf.numpy().astype(np.int64).reshape(-1)
        found = found.numpy().reshape(-1)
        flat = buf * res**3 + (local[:, 2] * res + local[:, 1]) * res + local[:, 0]
        return flat, found

    def _fuse_labels(
        self,
        vbg: Any,
        state: PanopticState,
        observations: MaskObservations,
        depth: np.ndarray,
        seg: Any,
        intr: Any,
        pose: np.ndarray,
        cfg: TSDFConfig,
    ) -> None:
        if cfg.instances == "masks":
            stride = vote_stride(cfg.label_stride, intr, cfg.voxel_size, cfg.depth_max)
        else:
            stride = label_stride(cfg.label_stride, intr.width)
        # backproject reads every stride-th pixel only: those are range-limited, not the whole frame.
        sampled = depth[::stride, ::stride]
        d = np.zeros_like(depth)
        d[::stride, ::stride] = np.where(sampled <= cfg.depth_max, sampled, 0)
        pts, pix = intr.backproject(d, stride=stride)
        if len(pts) == 0:
            return
        classes, instances = seg.class_ids.reshape(-1), seg.instance_ids.reshape(-1)
        keep = np.flatnonzero(classes[pix] > 0)
        world = apply(pose, pts[keep])
        voxels = np.round(world / cfg.voxel_size).astype(np.int64)
        flat, found = self._flat_indices(vbg, voxels, cfg.block_resolution)
        found = np.flatnonzero(found)
        flat, first = first_of_each(flat[found])  # one observation per voxel per frame
        taken = found[first]
        pixels = pix[keep[taken]]
        cls, inst = classes[pixels], instances[pixels]
        if cfg.instances == "masks":
            observations.add(voxels[taken], cls, inst)
        label_view = vbg.attribute("label").numpy().reshape(-1)
        conf_view = vbg.attribute("conf").numpy().reshape(-1)
        state.fuse_frame(label_view, conf_view, flat, cls, inst)

    def _point_labels(self, vbg: Any, points: np.ndarray, cfg: TSDFConfig) -> np.ndarray:
        """The segment label of each map point: its voxel's, or the nearest labelled neighbour's."""
        label_view = vbg.attribute("label").numpy().reshape(-1)
        base = np.round(points / cfg.voxel_size).astype(np.int64)
        out = np.zeros(len(points), np.int64)
        for offset in VOXEL_NEIGHBOURS:
            todo = out == 0
            if not todo.any():
                break
            flat, found = self._flat_indices(vbg, base[todo] + offset, cfg.block_resolution)
            lab = np.where(found, label_view[np.where(found, flat, 0)], 0)
            out[np.flatnonzero(todo)] = lab
        return out


@hookimpl
def stratamap_register_mappers():
    return [TSDFMapper]
