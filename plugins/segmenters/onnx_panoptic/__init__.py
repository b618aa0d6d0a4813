"""Segmenter ``onnx_panoptic``: a 2D instance/panoptic network run per frame with onnxruntime (CPU).

Preprocessing (resize or letterbox to the network's input, channel order, scale, mean and std,
an optional depth channel) and the output layout come from the config, so Mask R-CNN exports
(the ONNX model zoo's), YOLOv8/YOLO11-seg exports and stratamap's own semantic + boundary model
all plug in; see :mod:`stratamap.plugins.segmenters.onnx_panoptic.adapters`. The network's class names are mapped to the
map's vocabulary by name (``class_map`` renames, e.g. ``dining table: table``); unmapped classes
become ``unknown``.

With no ``model`` given, the model shipped with stratamap is used: ``panoptic_small.onnx``, a
small network trained on synthetic renders only (``scripts/train_panoptic.py``; its inputs,
outputs and held-out accuracy are in ``panoptic_small.json`` beside it).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import upright_turns
from stratamap.core.map.sensors import FrameLabels, FrameSegmentation, PackedFrames
from stratamap.plugins.segmenters import _depth

SHIPPED = Path(__file__).resolve().parent / "models" / "panoptic_small.onnx"

#: The 80 COCO classes in the order Mask R-CNN (zoo, 1-based with background 0) and YOLO (0-based) use.
COCO = (
    "person bicycle car motorcycle airplane bus train truck boat traffic_light fire_hydrant stop_sign parking_meter "
    "bench bird cat "
    "dog horse sheep cow elephant bear zebra giraffe backpack umbrella handbag tie suitcase frisbee skis snowboard "
    "sports_ball kite "
    "baseball_bat baseball_glove skateboard surfboard tennis_racket bottle wine_glass cup fork knife spoon bowl banana "
    "apple sandwich "
    "orange broccoli carrot hot_dog pizza donut cake chair couch potted_plant bed dining_table toilet tv laptop mouse "
    "remote keyboard "
    "cell_phone microwave oven toaster sink refrigerator book clock vase scissors teddy_bear hair_drier toothbrush"
).split()
#: COCO names that are map classes under another name.
COCO_TO_MAP = {
    "couch": "sofa",
    "potted_plant": "plant",
    "dining_table": "table",
    "tv": "monitor",
    "refrigerator": "fridge",
}


class ONNXPanopticConfig(StageConfig):
    path_fields = ("model",)

    model: str | None = Field(
        default=None, description="ONNX file; default: the shipped panoptic_small.onnx (synthetic-trained)."
    )
    layout: Literal["auto", "maskrcnn", "yolo_seg", "semantic_boundary"] = Field(
        default="auto",
        description="Output layout; auto reads it from the model's JSON sidecar (MODEL.json), else from its outputs.",
    )
    classes: list[str] | None = Field(
        default=None,
        description=(
            "Network class names by output index (default: the sidecar's, else COCO with background first for "
            "maskrcnn)."
        ),
    )
    class_map: dict[str, str] = Field(
        default_factory=dict, description="Rename network classes to map classes, e.g. {'dining table': 'table'}."
    )
    input_size: tuple[int, int] | None = Field(
        default=None, description="Network input (width, height); default: from the model's input shape."
    )
    resize: Literal["stretch", "letterbox"] = Field(
        default="stretch", description="letterbox keeps the aspect ratio and pads (YOLO exports expect it)."
    )
    channel_order: Literal["rgb", "bgr"] = Field(default="rgb", description="Colour channel order the network expects.")
    scale: float = Field(
        default=1.0 / 255.0, gt=0.0, description="Pixel values are multiplied by this before mean and std."
    )
    mean: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="Subtracted per channel after scaling."
    )
    std: tuple[float, float, float] = Field(default=(1.0, 1.0, 1.0), description="Divided per channel after the mean.")
    depth_channel: bool | None = Field(
        default=None,
        description=(
            "Append depth (metres / depth_scale) as a 4th channel; default: when the model has 4 input channels."
        ),
    )
    depth_scale: float = Field(default=5.0, gt=0.0, description="Depth is divided by this for the depth channel.")
    score_threshold: float = Field(
        default=0.5, ge=0.0, le=1.0, description="Detections scoring less are dropped (maskrcnn, yolo_seg)."
    )
    mask_threshold: float = Field(
        default=0.5, ge=0.0, le=1.0, description="Mask probability above which a pixel belongs to the detection."
    )
    iou_threshold: float = Field(default=0.7, ge=0.0, le=1.0, description="Non-maximum suppression IoU (yolo_seg).")
    boundary_threshold: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Boundary probability above which a pixel separates instances (semantic_boundary).",
    )
    min_pixels: int = Field(
        default=12,
        ge=1,
        description=(
            "Instances smaller than this (network pixels) are absorbed by their neighbours (semantic_boundary; 12 "
            "chosen "
            "on held-out walks: a cup is ~20)."
        ),
    )
    speckle_pixels: int = Field(
        default=0,
        ge=0,
        description=(
            "Class regions smaller than this (network pixels) take the class around them (semantic_boundary; 0: off, "
            "the default: the tsdf mapper's per-voxel class votes average specks out and a cup is a speck at 160 x "
            "120; 60 suits frame-level use)."
        ),
    )
    merge_depth_gap: float = Field(
        default=0.06,
        ge=0.0,
        le=0.5,
        description=(
            "Instances whose seam is continuous in depth (steps under this fraction of the depth) merge into one "
            "(semantic_boundary; 0: off; 0.06 chosen on held-out synthetic walks)."
        ),
    )
    merge_bridges: Literal["any", "smaller"] = Field(
        default="smaller",
        description=(
            "Which depth-continuous chains merge two instances of a class (semantic_boundary): 'any'; 'smaller': "
            "only through "
            "instances of other classes each smaller than both (a chair's post bridges seat and base, a table under "
            "two cups does not)."
        ),
    )
    min_region_score: float = Field(
        default=0.8,
        ge=0.0,
        le=1.0,
        description=(
            "Class regions whose mean top class probability is below this are left unknown (semantic_boundary; 0: off; "
            "0.8 chosen on held-out synthetic walks)."
        ),
    )
    depth_refine: bool = Field(
        default=False,
        description=(
            "Refine the network's instances with per-frame depth segmentation, as the detector segmenter does: "
            "each mask takes the depth segments lying mostly inside it (not the wall or floor it spills onto), and "
            "floor, wall and ceiling come from gravity-aligned planes (needs depth and poses)."
        ),
    )
    threads: int = Field(default=2, ge=1, description="onnxruntime intra-op threads.")


def load_sidecar(model: Path) -> dict[str, Any]:
    side = model.with_suffix(".json")
    if side.is_file():
        try:
            return json.loads(read_data_text(side, "network sidecar"))
        except json.JSONDecodeError as exc:
            raise DataError(f"{side}: not valid JSON ({exc})") from exc
    return {}


# Outputs each layout reads, in order: (how many at least, what they are).
LAYOUT_OUTPUTS = {
    "semantic_boundary": (2, "2 (class logits (1, C, H, W), boundary logits (1, 1, H, W))"),
    "maskrcnn": (4, "4 (boxes, labels, scores, masks)"),
    "yolo_seg": (2, "2 (detections (1, 4 + classes + k, anchors), prototype masks (1, k, h, w))"),
}


class ONNXPanopticSegmenter(Segmenter[ONNXPanopticConfig]):
    """Per-frame classes and instances from an ONNX network (Mask R-CNN, YOLO-seg, or semantic + boundary)."""

    name = "onnx_panoptic"
    Config = ONNXPanopticConfig
    requires = frozenset({"frames"})
    provides = frozenset({"frame_labels"})

    def _session(self, path: Path):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.config.threads
        opts.inter_op_num_threads = 1
        try:
            return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph types
            raise DataError(f"onnx_panoptic: {path} cannot be loaded by onnxruntime ({exc})") from exc

    def segment(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        path = Path(cfg.model).expanduser() if cfg.model else SHIPPED
        if not path.is_file():
            raise DataError(f"onnx_panoptic: model file not found: {path}")
        side = load_sidecar(path)
        session = self._session(path)
        inp = session.get_inputs()[0]
        shape = list(inp.shape)
        channels = shape[1] if isinstance(shape[1], int) else 3
        if cfg.input_size is not None:
            width, height = cfg.input_size
        elif isinstance(shape[2], int) and isinstance(shape[3], int):
            height, width = shape[2], shape[3]
        else:
            raise DataError(
                f"onnx_panoptic: {path.name} has a dynamic input size {shape}; set input_size: [width, height]"
            )
        depth_channel = cfg.depth_channel if cfg.depth_channel is not None else channels == 4
        outputs = [o.name for o in session.get_outputs()]
        layout = cfg.layout if cfg.layout != "auto" else side.get("layout") or self._guess_layout(outputs)
        if layout not in LAYOUT_OUTPUTS:
            raise DataError(
                f"onnx_panoptic: {path.with_suffix('.json').name} names layout {layout!r}; expected one of "
                f"{sorted(LAYOUT_OUTPUTS)}"
            )
        if len(outputs) < LAYOUT_OUTPUTS[layout][0]:
            raise DataError(
                f"onnx_panoptic: {path.name} has outputs {outputs}, but the {layout!r} layout reads "
                f"{LAYOUT_OUTPUTS[layout][1]}; "
                "set layout: to the one the model was exported with"
            )
        vocab = data.ground_truth.vocabulary if data.ground_truth is not None else (data.map.vocabulary or None)
        if vocab is None:
            from stratamap.core.map.vocabulary import Vocabulary

            vocab = Vocabulary.default()
        names = cfg.classes or side.get("classes") or (["background", *COCO] if layout == "maskrcnn" else COCO)
        renames = {**COCO_TO_MAP, **cfg.class_map}
        class_map = np.array(
            [vocab.id(renames.get(n, n)) if renames.get(n, n) in vocab else 0 for n in names], np.int64
        )
        is_thing = np.array(vocab.is_thing)
        stream = data.stream
        assert stream is not None
        if not stream.frames:
            raise DataError(
                "onnx_panoptic: the stream has no RGB-D frames (point clouds need a 3D segmenter such as `clusters`)"
            )
        floor = None
        if cfg.depth_refine:
            missing = [f.index for f in stream.frames if f.pose is None or f.depth is None]
            if missing or stream.intrinsics is None:
                raise DataError(
                    f"onnx_panoptic: depth_refine needs depth, poses and intrinsics; frames {missing[:5]} of "
                    f"{stream.name!r} lack depth or a pose"
                )
            floor = _depth.floor_height(stream, _depth.DepthSegmentsConfig())
            if floor is None:
                self.warn("depth_refine: no upward-facing surface in the frames: no floor labelled")
                floor = float("-inf")
        out = FrameLabels(segmenter=self.name, frames=PackedFrames(), tracked_instances=False)
        for frame in self.progress(stream.frames, description="onnx_panoptic"):
            rgb = np.asarray(frame.rgb)
            if depth_channel and frame.depth is None:
                raise DataError(
                    f"onnx_panoptic: frame {frame.index} of {stream.name!r} has no depth image, but {path.name} "
                    "takes RGB-D input"
                )
            # The network learned level views: a frame of a camera held turned is segmented turned upright.
            turns = upright_turns(frame.pose)
            depth = None if frame.depth is None else np.ascontiguousarray(np.rot90(np.asarray(frame.depth), turns))
            tensor, undo, depth_in = self._prepare(
                np.ascontiguousarray(np.rot90(rgb, turns)), depth, width, height, cfg, depth_channel
            )
            result = session.run(None, {inp.name: tensor})
            try:
                cls, ins = self._decode(layout, result, class_map, is_thing, depth_in, width, height, cfg)
            except (ValueError, IndexError) as exc:  # outputs of the right number but the wrong shapes
                raise DataError(
                    f"onnx_panoptic: {path.name} on frame {frame.index}: its outputs do not fit the {layout!r} "
                    f"layout ({exc})"
                ) from exc
            cls, ins = np.rot90(undo(cls), -turns), np.rot90(undo(ins), -turns)
            if cfg.depth_refine:
                cls, ins = self._refine(frame, stream, cls, ins, vocab, floor)
            out.frames.append(FrameSegmentation(frame.index, cls.astype(np.uint16), ins.astype(np.int32)))
        self.note(
            "model", {"path": str(path), "layout": layout, "input": [width, height], "depth_channel": depth_channel}
        )
        return {"frame_labels": out}

    @staticmethod
    def _decode(
        layout: str,
        result: list,
        class_map: np.ndarray,
        is_thing: np.ndarray,
        depth_in: Any,
        width: int,
        height: int,
        cfg: ONNXPanopticConfig,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(class image, instance image) at the network's resolution from one frame's outputs."""
        from stratamap.plugins.segmenters.onnx_panoptic import adapters as adapters

        if layout == "semantic_boundary":
            cls, ins, _ = adapters.semantic_boundary(
                result[0],
                result[1],
                class_map,
                is_thing,
                cfg.boundary_threshold,
                cfg.min_pixels,
                cfg.speckle_pixels,
                depth=depth_in,
                merge_depth_gap=cfg.merge_depth_gap,
                min_region_score=cfg.min_region_score,
                merge_bridges=cfg.merge_bridges,
            )
        elif layout == "maskrcnn":
            boxes, labels, scores, masks = result[:4]
            cls, ins, _ = adapters.maskrcnn(
                boxes, labels, scores, masks, (height, width), class_map, cfg.score_threshold, cfg.mask_threshold
            )
        else:
            cls, ins, _ = adapters.yolo_seg(
                result[0],
                result[1],
                (height, width),
                class_map,
                cfg.score_threshold,
                cfg.mask_threshold,
                cfg.iou_threshold,
            )
        return cls, ins

    @staticmethod
    def _refine(frame: Any, stream: Any, cls: np.ndarray, ins: np.ndarray, vocab: Any, floor: float):
        """The network's instances as regions for per-frame depth segmentation; its stuff where the
        planes name none."""
        regions = []
        for iid in np.unique(ins[ins > 0]):
            mask = ins == iid
            class_id = int(np.bincount(cls[mask].astype(np.int64)).argmax())
            if class_id == 0 or not vocab.is_thing[class_id]:
                continue
            regions.append(_depth.Region(class_id, 1.0, mask=mask, extent=_depth.class_reach(vocab.name(class_id))))
        stuff = _depth.stuff_class_ids(vocab)
        ref_cls, ref_ins = _depth.refine_labels(
            np.asarray(frame.depth),
            np.asarray(frame.pose),
            stream.intrinsics,
            regions,
            floor,
            stuff,
            _depth.DepthSegmentsConfig(),
            _depth.LayoutConfig(),
        )
        network_stuff = ~np.asarray(vocab.is_thing)[cls.astype(np.int64)] & (cls > 0)
        keep = (ref_cls == 0) & network_stuff
        ref_cls[keep] = cls[keep]
        return ref_cls, ref_ins

    @staticmethod
    def _guess_layout(outputs: list[str]) -> str:
        if len(outputs) >= 4:
            return "maskrcnn"
        if len(outputs) == 2 and any("boundary" in o for o in outputs):
            return "semantic_boundary"
        return "yolo_seg"

    @staticmethod
    def _prepare(
        rgb: np.ndarray,
        depth: np.ndarray | None,
        width: int,
        height: int,
        cfg: ONNXPanopticConfig,
        depth_channel: bool = True,
    ):
        """The network input (1, C, H, W) float32 (depth as a 4th channel if ``depth_channel``), a
        function taking label images back to the frame, and the depth at the network's resolution
        (metres, 0 where unknown or padded; None without depth)."""
        from PIL import Image

        h0, w0 = rgb.shape[:2]
        if cfg.resize == "letterbox":
            s = min(width / w0, height / h0)
            nw, nh = max(1, round(w0 * s)), max(1, round(h0 * s))
            ox, oy = (width - nw) // 2, (height - nh) // 2
        else:
            nw, nh, ox, oy = width, height, 0, 0
        img = np.asarray(Image.fromarray(rgb).resize((nw, nh), Image.BILINEAR), np.float32)
        if cfg.channel_order == "bgr":
            img = img[..., ::-1]
        img = (img * cfg.scale - np.asarray(cfg.mean, np.float32)) / np.asarray(cfg.std, np.float32)
        planes = [img]
        net_depth = None
        if depth is not None:
            d = np.asarray(
                Image.fromarray(np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)).resize(
                    (nw, nh), Image.NEAREST
                ),
                np.float32,
            )
            net_depth = np.zeros((height, width), np.float32)
            net_depth[oy : oy + nh, ox : ox + nw] = d
            if depth_channel:
                planes.append((d / cfg.depth_scale)[..., None])
        stacked = np.concatenate(planes, axis=2)
        canvas = np.full(
            (height, width, stacked.shape[2]), 0.0 if cfg.resize == "stretch" else 114.0 * cfg.scale, np.float32
        )
        canvas[oy : oy + nh, ox : ox + nw] = stacked
        tensor = canvas.transpose(2, 0, 1)[None].copy()

        def undo(labels: np.ndarray) -> np.ndarray:
            crop = labels[oy : oy + nh, ox : ox + nw]
            rows = np.minimum((np.arange(h0) * nh / h0).astype(int), nh - 1)
            cols = np.minimum((np.arange(w0) * nw / w0).astype(int), nw - 1)
            return crop[rows][:, cols]

        return tensor, undo, net_depth


@hookimpl
def stratamap_register_segmenters():
    return [ONNXPanopticSegmenter]
