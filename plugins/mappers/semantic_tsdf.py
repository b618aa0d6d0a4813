"""Mapper ``semantic_tsdf``: TSDF fusion with per-voxel Bayesian class fusion (Kimera-Semantics style).

Every voxel a labelled pixel falls in keeps a log-probability per class. An observation of class
z updates it with the measurement model p(z | c) = ``p_correct`` if z = c, else
(1 - ``p_correct``) / (K - 1); the voxel's class is the argmax. Class probabilities live in an
Open3D hash map keyed by voxel, so only observed voxels cost memory. Like Kimera, it labels
classes only; split them into objects with the ``instance_clusters`` mapper.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import VOXEL_NEIGHBOURS
from stratamap.core.geometry.transforms import apply
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Semantics
from stratamap.plugins.mappers._volume import FrameSkips, IntegrationConfig, TSDFVolume, label_stride

o3c = lazy_module("open3d.core")


class SemanticTSDFConfig(IntegrationConfig):
    p_correct: float = Field(
        default=0.8, gt=0.0, lt=1.0, description="Probability that the segmenter's class is right (measurement model)."
    )


class SemanticTSDFMapper(Mapper[SemanticTSDFConfig]):
    """TSDF fusion with per-voxel Bayesian class probabilities (Kimera-Semantics); classes, no instances."""

    name = "semantic_tsdf"
    Config = SemanticTSDFConfig
    requires = frozenset({"frames", "frame_labels"})
    optional = frozenset({"ground_truth"})
    provides = frozenset({"geometry", "semantics"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        stream, labels = data.stream, data.frame_labels
        assert stream is not None and labels is not None
        if stream.intrinsics is None:
            raise DataError(f"semantic_tsdf: the stream {stream.name!r} has no camera intrinsics")
        vocab = data.ground_truth.vocabulary if data.ground_truth is not None else data.map.vocabulary
        n_classes = len(vocab)
        device = o3c.Device("CPU:0")
        volume = TSDFVolume(cfg, stream.intrinsics)
        probs = o3c.HashMap(200000, o3c.int32, (3,), o3c.float32, (n_classes,), device)
        # log p(z|c): the observed class gains log(p / q) over the others (q = (1 - p) / (K - 1)).
        gain = np.float32(np.log(cfg.p_correct * (n_classes - 1) / (1 - cfg.p_correct)))
        intr = stream.intrinsics
        integrated = 0
        skips = FrameSkips("semantic_tsdf")
        for frame in self.progress(stream.frames, description="semantic TSDF"):
            depth, reason = volume.usable_depth(frame)
            if depth is None or not volume.integrate(depth, frame.rgb, frame.pose):
                skips.add(reason or volume.out_of_range, frame.index)
                continue
            integrated += 1
            seg = labels.frames[frame.index]
            if not seg.labelled:
                continue
            pts, pix = intr.backproject(
                np.where(depth <= cfg.depth_max, depth, 0), stride=label_stride(cfg.label_stride, intr.width)
            )
            cls = seg.class_ids.reshape(-1)[pix].astype(np.int64)
            keep = cls > 0
            if not keep.any():
                continue
            keys = o3c.Tensor(np.round(apply(frame.pose, pts[keep]) / cfg.voxel_size).astype(np.int32))
            probs.activate(keys)
            buf, found = probs.find(keys)
            idx = buf.numpy().astype(np.int64).reshape(-1)[found.numpy().reshape(-1)]
            table = probs.value_tensor().numpy()
            np.add.at(table, (idx, cls[keep][found.numpy().reshape(-1)]), gain)

        skips.finish(self, integrated, len(stream.frames), stream.name)
        self.note("frames_integrated", integrated)

        geometry = volume.surface()
        points = geometry.points
        if len(points) == 0:
            raise DataError(
                f"semantic_tsdf: no surface of {stream.name!r} was seen by {volume.views_needed} of its "
                f"{integrated} frames (min_frames); lower min_frames, or give more or larger frames"
            )
        table = probs.value_tensor().numpy()
        base = np.round(points / cfg.voxel_size).astype(np.int64)
        class_ids = np.zeros(len(points), np.int32)
        for offset in VOXEL_NEIGHBOURS:
            todo = np.flatnonzero(class_ids == 0)
            if len(todo) == 0:
                break
            buf, found = probs.find(o3c.Tensor((base[todo] + offset).astype(np.int32)))
            ok = found.numpy().reshape(-1)
            rows = table[buf.numpy().astype(np.int64).reshape(-1)[ok]]
            best = rows.argmax(1)
            best[rows.max(1) <= 0] = 0
            class_ids[todo[ok]] = best
        semantics = Semantics(class_ids, np.zeros(len(points), np.int32), vocab)
        return {"geometry": geometry, "semantics": semantics}


@hookimpl
def stratamap_register_mappers():
    return [SemanticTSDFMapper]
