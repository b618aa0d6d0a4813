"""Segmenter ``oracle``: per-frame labels taken from the ground truth (the upper bound for ablations)."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.map.sensors import FrameLabels


class OracleConfig(StageConfig):
    min_pixels: int = Field(
        default=0,
        ge=0,
        description="Drop instance labels covering fewer pixels than this in a frame (simulates detector misses).",
    )


class OracleSegmenter(Segmenter[OracleConfig]):
    """Ground-truth class and instance images (consistent instance ids across frames)."""

    name = "oracle"
    Config = OracleConfig
    requires = frozenset({"frames", "ground_truth"})
    provides = frozenset({"frame_labels"})

    def segment(self, data: PipelineData) -> dict[str, Any]:
        import numpy as np

        gt = data.ground_truth
        stream = data.stream
        if stream is None or not len(stream.frames):
            raise DataError(
                "oracle: the source gave no camera frames; the oracle labels RGB-D frames (a point cloud's labels "
                "are ground truth for evaluation, not per-frame labels)"
            )
        if gt is None:
            raise DataError(
                f"oracle: no ground truth for {stream.name!r}: the oracle needs per-frame labels from a gt/ folder "
                "beside the sequence (gt/class/*.png, gt/instance/*.png and gt/scene.json, as `stratamap synth` "
                "writes them; the tum source loads it when load_ground_truth is true)"
            )
        if not len(gt.frame_labels):
            raise DataError(
                f"oracle: the ground truth of {stream.name!r} has no per-frame labels (no gt/class/ and gt/instance/ "
                "images); sequences written by `stratamap synth` have them"
            )
        if len(gt.frame_labels) != len(stream.frames):
            raise DataError(
                f"oracle: the ground truth has labels for {len(gt.frame_labels)} frames but the stream has "
                f"{len(stream.frames)}; the labels must come with the sequence"
            )
        out = FrameLabels(segmenter=self.name, tracked_instances=True)
        for seg in self.progress(gt.frame_labels, description="oracle labels"):
            if self.config.min_pixels > 0:
                ids, counts = np.unique(seg.instance_ids, return_counts=True)
                small = ids[(counts < self.config.min_pixels) & (ids > 0)]
                if len(small):
                    mask = np.isin(seg.instance_ids, small)
                    seg = type(seg)(
                        seg.frame_index, np.where(mask, 0, seg.class_ids), np.where(mask, 0, seg.instance_ids)
                    )
            out.frames.append(seg)
        return {"frame_labels": out}


@hookimpl
def stratamap_register_segmenters():
    return [OracleSegmenter]
