"""Segmenter ``detector``: a 2D box detector trained on real photographs, made panoptic by per-frame
depth segmentation.

Each frame is cut into geometric segments (depth jumps and concave creases; see
:mod:`stratamap.plugins.segmenters._depth`); floor, walls and ceiling come from the segments'
gravity-aligned planes; every detection, most confident first, takes the free segments lying mostly
inside its box near its largest one. What a box only spills onto (the wall and floor behind a
chair, another object behind it) stays background, so a box detector becomes an instance
segmenter without label bleeding.

With no ``model`` given, the shipped detector is used: MediaPipe's SSD MobileNetV2 trained on Open
Images V4 (24 classes, Apache-2.0), converted to ONNX by ``scripts/build_detector.py``; its
provenance and license are beside it in ``models/``. Detector labels are mapped to the map's
vocabulary by name (``class_map``); a label the vocabulary lacks becomes ``object``, never dropped.
"""

from __future__ import annotations

from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import upright_turns
from stratamap.core.map.keyframes import KeyframeChooser
from stratamap.core.map.sensors import FrameLabels, FrameSegmentation, PackedFrames
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.parallel import ahead
from stratamap.plugins.segmenters import _depth

MODELS = Path(__file__).resolve().parent / "models"
SHIPPED = MODELS / "objectron_ssd_oidv4.onnx"

#: Open Images names of the shipped detector that are map classes under another name.
OPEN_IMAGES_TO_MAP = {
    "Chair": "chair",
    "Table": "table",
    "Desk": "desk",
    "Laptop": "laptop",
    "Computer monitor": "monitor",
    "Mug": "cup",
    "Coffee cup": "cup",
    "Bottle": "bottle",
    "Book": "book",
    "Box": "box",
}


class KeyframesConfig(BaseModel):
    """Label only frames that see enough new surface: the detector and the depth segmentation cost far more a
    frame than the fusion of its depth."""

    model_config = ConfigDict(extra="forbid")

    new_surface: float = Field(
        default=0.0,
        ge=0.0,
        le=1.0,
        description="A frame is labelled when at least this share of its depth pixels lies in cells no labelled "
        "frame saw before it (0: every frame).",
    )
    cell: float = Field(default=0.1, gt=0.0, description="Side (m) of the cells surface is counted in.")
    views: int = Field(
        default=1,
        ge=1,
        le=100,
        description=(
            "Surface counts as new until this many labelled frames saw it: a slow walk's frames then still get "
            "labelled from several viewpoints (1: once)."
        ),
    )


class DetectorConfig(StageConfig):
    path_fields = ("model",)

    model: str | None = Field(
        default=None,
        description="ONNX detector with a JSON sidecar naming its layout; default: the shipped Open Images SSD.",
    )
    score_threshold: float = Field(default=0.3, ge=0.0, le=1.0, description="Detections scoring less are ignored.")
    nms_iou: float = Field(default=0.5, gt=0.0, le=1.0, description="Non-maximum suppression IoU within a class.")
    class_map: dict[str, str] = Field(
        default_factory=dict,
        description="Rename detector labels to map classes, e.g. {'Kitchen appliance': 'appliance'} (adds to the "
        "built-in Open Images renames).",
    )
    inside_ratio: float = Field(
        default=0.5,
        gt=0.0,
        le=1.0,
        description="A segment joins a detection when at least this share of it lies inside the box.",
    )
    reach_scale: float = Field(
        default=1.2,
        gt=0.0,
        description="A segment joins only within this times its class's largest extent (core/map/priors.py) of the "
        "detection's main segment.",
    )
    join_gap: float = Field(
        default=0.1,
        gt=0.0,
        description="A detection grows from its main segment through segments this close (m) to what it holds: "
        "an object's parts touch, a chair standing near a table is apart from it.",
    )
    depth_segments: _depth.DepthSegmentsConfig = Field(
        default_factory=_depth.DepthSegmentsConfig, description="Geometric segmentation of each depth frame."
    )
    layout: _depth.LayoutConfig = Field(
        default_factory=_depth.LayoutConfig, description="Floor, wall and ceiling from planes."
    )
    tiles: int = Field(
        default=1,
        ge=1,
        le=4,
        description=(
            "Also detect on an n x n grid of overlapping crops (n > 1), so that small objects (a mug across the "
            "room) are seen at the detector's input size; a crop's boxes that touch its inner edges are dropped. "
            "Off by default: n x n + 1 detector runs per frame, and no measured gain yet."
        ),
    )
    threads: int = Field(default=1, ge=1, description="onnxruntime intra-op threads (1: bit-for-bit repeatable).")
    read_ahead: int = Field(
        default=2,
        ge=0,
        le=16,
        description=(
            "Frames read and detected ahead, in one background thread, of the depth segmentation (0: one loop, no "
            "thread). The labels are the same either way."
        ),
    )
    keyframes: KeyframesConfig = Field(
        default_factory=KeyframesConfig,
        description="Which frames are labelled (core/map/keyframes.py); every frame is still fused into the geometry.",
    )


def detect_tiled(detector: Any, rgb: np.ndarray, score_threshold: float, nms_iou: float, tiles: int) -> Any:
    """Detections on the whole image and on ``tiles`` x ``tiles`` crops overlapping by a quarter of a
    crop (slicing-aided detection), merged by per-class NMS. Boxes a crop cuts (touching an edge of the
    crop inside the image) are dropped: the whole image or a neighbouring crop sees those objects."""
    from stratamap.plugins.segmenters.detector.adapters import Detections, nms

    found = detector.detect(rgb, score_threshold, nms_iou)
    if tiles <= 1:
        return found
    h, w = rgb.shape[:2]
    boxes, labels, scores = [found.boxes], list(found.labels), [found.scores]
    cw, ch = w / (tiles - (tiles - 1) * 0.25), h / (tiles - (tiles - 1) * 0.25)
    margin = 2.0
    for r in range(tiles):
        for c in range(tiles):
            x0, y0 = int(round(c * cw * 0.75)), int(round(r * ch * 0.75))
            x1, y1 = min(w, int(round(x0 + cw))), min(h, int(round(y0 + ch)))
            crop = detector.detect(np.ascontiguousarray(rgb[y0:y1, x0:x1]), score_threshold, nms_iou)
            if not len(crop):
                continue
            b = crop.boxes + [x0, y0, x0, y0]
            cut = (
                ((b[:, 0] <= x0 + margin) & (x0 > 0))
                | ((b[:, 1] <= y0 + margin) & (y0 > 0))
                | ((b[:, 2] >= x1 - margin) & (x1 < w))
                | ((b[:, 3] >= y1 - margin) & (y1 < h))
            )
            keep = ~cut
            boxes.append(b[keep])
            labels.extend(label for label, k in zip(crop.labels, keep, strict=True) if k)
            scores.append(crop.scores[keep])
    all_boxes, all_scores = np.vstack(boxes), np.concatenate(scores)
    kept: list[int] = []
    for label in sorted(set(labels)):
        idx = np.flatnonzero(np.array(labels) == label)
        kept.extend(idx[nms(all_boxes[idx], all_scores[idx], nms_iou)].tolist())
    kept.sort(key=lambda i: (-all_scores[i], i))
    return Detections(all_boxes[kept], [labels[i] for i in kept], all_scores[kept])


def detect_upright(
    detector: Any, rgb: np.ndarray, turns: int, score_threshold: float, nms_iou: float, tiles: int
) -> Any:
    """:func:`detect_tiled` on the image turned upright (``turns``: :func:`upright_turns`), boxes in the
    frame's own pixels: the detector learned photographs taken level, and finds a chair on its side
    much less often."""
    from stratamap.plugins.segmenters.detector.adapters import Detections

    if turns == 0:
        return detect_tiled(detector, rgb, score_threshold, nms_iou, tiles)
    h, w = rgb.shape[:2]
    found = detect_tiled(detector, np.ascontiguousarray(np.rot90(rgb, turns)), score_threshold, nms_iou, tiles)
    x0, y0, x1, y1 = found.boxes.T
    if turns == 1:  # the turned image's (x, y) is the frame's (w - y, x)
        back = np.c_[w - y1, x0, w - y0, x1]
    elif turns == 2:  # (w - x, h - y)
        back = np.c_[w - x1, h - y1, w - x0, h - y0]
    else:  # (y, h - x)
        back = np.c_[y0, h - x1, y1, h - x0]
    return Detections(back.reshape(-1, 4), found.labels, found.scores)


def vocabulary_class(label: str, renames: dict[str, str], vocab: Vocabulary) -> str:
    """The map class of a detector label: renamed, else the label itself in snake case, else ``object``."""
    name = renames.get(label)
    if name is None:
        name = label.strip().lower().replace(" ", "_")
    return name if name in vocab else "object"


class DetectorSegmenter(Segmenter[DetectorConfig]):
    """Per-frame panoptic labels from a photograph-trained box detector and depth segmentation."""

    name = "detector"
    Config = DetectorConfig
    requires = frozenset({"frames"})
    provides = frozenset({"frame_labels"})

    def _detector(self):
        from stratamap.plugins.segmenters.detector.box_detector import BoxDetector

        path = Path(self.config.model).expanduser() if self.config.model else SHIPPED
        if not path.is_file():
            raise DataError(f"detector: model file not found: {path}")
        return path, BoxDetector(path, threads=self.config.threads)

    def segment(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        stream = data.stream
        if stream is None or not stream.frames:
            raise DataError(
                "detector: the stream has no RGB-D frames (point clouds need a 3D segmenter such as `clusters`)"
            )
        if stream.intrinsics is None:
            raise DataError(f"detector: {stream.name!r} has no camera intrinsics")
        missing = [f.index for f in stream.frames if f.pose is None]
        if missing:
            raise DataError(
                f"detector: frames {missing[:5]} of {stream.name!r} have no pose; the source must give poses "
                "(ground truth or odometry) so that floor and walls can be told by gravity"
            )
        vocab = data.ground_truth.vocabulary if data.ground_truth is not None else Vocabulary.default()
        renames = {**OPEN_IMAGES_TO_MAP, **cfg.class_map}
        path, detector = self._detector()
        seg_params = cfg.depth_segments
        lay = cfg.layout
        floor = lay.floor_height
        if floor is None:
            floor = _depth.floor_height(stream, seg_params, lay.tilt_deg)
            if floor is None:
                self.warn("no upward-facing surface in the frames: no floor labelled")
                floor = float("-inf")
        stuff = _depth.stuff_class_ids(vocab)
        out = FrameLabels(segmenter=self.name, frames=PackedFrames(), tracked_instances=False)
        counts: dict[str, int] = {}
        keyframe = KeyframeChooser(
            stream.intrinsics, cfg.keyframes.new_surface, cfg.keyframes.cell, views=cfg.keyframes.views
        )

        def read_and_detect(k: int) -> tuple[Any, Any]:
            """Frame ``k`` and its detections (None: not a keyframe). Runs a frame ahead of the depth
            segmentation below, in a thread: reading, decoding and the network's inference leave the
            GIL, the depth segmentation is numpy, and on two cores the two overlap."""
            frame = stream.frames[k]
            if not keyframe(np.asarray(frame.depth), np.asarray(frame.pose)):
                return frame, None
            found = detect_upright(
                detector, np.asarray(frame.rgb), upright_turns(frame.pose), cfg.score_threshold, cfg.nms_iou, cfg.tiles
            )
            return frame, found

        labelled = 0
        frames = (
            ahead(range(len(stream.frames)), read_and_detect, depth=cfg.read_ahead)
            if cfg.read_ahead
            else ((k, read_and_detect(k)) for k in range(len(stream.frames)))
        )
        with closing(frames):  # ended here, also on an error (not later by the garbage collector)
            for _, (frame, detections) in self.progress(frames, total=len(stream.frames), description="detector"):
                if detections is None:
                    out.frames.append(FrameSegmentation.unlabelled(frame.index))
                    continue
                labelled += 1
                regions = []
                for box, label, score in zip(detections.boxes, detections.labels, detections.scores, strict=True):
                    name = vocabulary_class(label, renames, vocab)
                    counts[name] = counts.get(name, 0) + 1
                    extent = _depth.class_reach(name, cfg.reach_scale)
                    regions.append(
                        _depth.Region(vocab.id(name), float(score), box=tuple(map(float, box)), extent=extent)
                    )
                regions = _depth.suppress_duplicates(regions)
                cls, ins = _depth.refine_labels(
                    np.asarray(frame.depth),
                    np.asarray(frame.pose),
                    stream.intrinsics,
                    regions,
                    floor,
                    stuff,
                    seg_params,
                    lay,
                    cfg.inside_ratio,
                    cfg.join_gap,
                )
                out.frames.append(FrameSegmentation(frame.index, cls.astype(np.uint16), ins.astype(np.int32)))
        self.note("model", {"path": str(path), "floor_height": round(float(floor), 4), "detections": counts})
        self.note(
            "keyframes",
            {
                "labelled": labelled,
                "frames": len(out.frames),
                "new_surface": cfg.keyframes.new_surface,
                "views": cfg.keyframes.views,
            },
        )
        return {"frame_labels": out}


@hookimpl
def stratamap_register_segmenters():
    return [DetectorSegmenter]
