"""Segmenter ``oracle``: per-frame labels taken from the ground truth (the upper bound for ablations)."""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.map.sensors import FrameLabels, FrameSegmentation, MappedFrames


class OracleConfig(StageConfig):
    min_pixels: int = Field(
        default=0,
        ge=0,
        description="Drop instance labels covering fewer pixels than this in a frame (simulates detector misses).",
    )


def drop_small_instances(seg: FrameSegmentation, min_pixels: int) -> FrameSegmentation:
    """The frame's labels without the instances covering fewer than ``min_pixels`` pixels."""
    ids, counts = np.unique(seg.instance_ids, return_counts=True)
    small = ids[(counts < min_pixels) & (ids > 0)]
    if not len(small):
        return seg
    mask = np.isin(seg.instance_ids, small)
    return FrameSegmentation(seg.frame_index, np.where(mask, 0, seg.class_ids), np.where(mask, 0, seg.instance_ids))


class OracleSegmenter(Segmenter[OracleConfig]):
    """Ground-truth class and instance images (consistent instance ids across frames)."""

    name = "oracle"
    Config = OracleConfig
    requires = frozenset({"frames", "ground_truth"})
    provides = frozenset({"frame_labels"})

    def segment(self, data: PipelineData) -> dict[str, Any]:
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
        # Labels are read from the ground truth when a mapper reads them, frame by frame: a long walk's
        # label images are never all held at once (they are re-read, or re-rendered, on access).
        frames = gt.frame_labels
        if self.config.min_pixels > 0:
            frames = MappedFrames(gt.frame_labels, partial(drop_small_instances, min_pixels=self.config.min_pixels))
        out = FrameLabels(segmenter=self.name, frames=frames, tracked_instances=True)
        return {"frame_labels": out}


@hookimpl
def stratamap_register_segmenters():
    return [OracleSegmenter]
