"""An ONNX object detector run on the CPU: image in, :class:`~.adapters.Detections` out.

A detector is an ONNX file and a JSON sidecar beside it (``MODEL.json``) that says how to feed it
and how to read it: input size, layout, colour order and normalisation, the output layout
(``ssd``, ``centernet``, ``yolo``, ``maskrcnn_boxes``), label names in output order and, for
``ssd``, the anchor and box-coder settings. :data:`SHIPPED` is the detector that ships with
stratamap: MediaPipe's Objectron SSD MobileNetV2 trained on real photographs (Open Images V4, 24
labels), converted by ``scripts/build_detector.py``; see ``models/README.md`` for its provenance.

    detector = BoxDetector(SHIPPED_MODEL)  # or BoxDetector.from_sidecar(SHIPPED)
    found = detector.detect(rgb, score_threshold=0.3)  # HxWx3 uint8 -> boxes in rgb's pixels, labels, scores
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.lazy import lazy_module
from stratamap.plugins.segmenters.detector import adapters
from stratamap.plugins.segmenters.detector.adapters import Detections, InputTransform, SSDAnchors

ort = lazy_module("onnxruntime")
Image = lazy_module("PIL.Image")

MODELS = Path(__file__).resolve().parent / "models"
#: Sidecar of the shipped detector (MediaPipe Objectron SSD MobileNetV2, Open Images V4, 24 labels).
SHIPPED = MODELS / "objectron_ssd_oidv4.json"
SHIPPED_MODEL = MODELS / "objectron_ssd_oidv4.onnx"

Layout = Literal["ssd", "centernet", "yolo", "maskrcnn_boxes", "gfl"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class InputSpec(_Strict):
    """How an RGB image becomes the network input."""

    size: tuple[int, int] = Field(description="Network input (width, height) in pixels.")
    tensor_layout: Literal["NCHW", "NHWC"] = Field(description="Axis order of the input tensor.")
    channel_order: Literal["rgb", "bgr"] = Field(default="rgb", description="Colour order the network expects.")
    resize: Literal["stretch", "letterbox"] = Field(
        default="stretch", description="stretch to the input size, or keep the aspect ratio and pad (YOLO)."
    )
    mean: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="Subtracted from 0-255 pixel values, per channel (network order)."
    )
    std: tuple[float, float, float] = Field(
        default=(1.0, 1.0, 1.0), description="Divides the pixel values after the mean, per channel."
    )
    pad_value: int = Field(default=114, ge=0, le=255, description="Grey level of letterbox borders.")


class SSDSpec(_Strict):
    """MediaPipe ``SsdAnchorsCalculator`` options plus the box coder of an SSD export."""

    strides: tuple[int, ...] = Field(description="Stride of each feature map, lowest layer first.")
    min_scale: float = Field(gt=0, description="Anchor scale of the lowest layer.")
    max_scale: float = Field(gt=0, description="Anchor scale of the highest layer.")
    aspect_ratios: tuple[float, ...] = Field(description="Aspect ratios (width / height) of each cell's anchors.")
    reduce_boxes_in_lowest_layer: bool = Field(description="Lowest layer: 3 boxes (0.1 at 1:1, scale at 2:1, 1:2).")
    interpolated_scale_aspect_ratio: float = Field(
        description="Aspect ratio of the extra anchor at sqrt(scale * next scale); 0 for none."
    )
    anchor_offset: tuple[float, float] = Field(default=(0.5, 0.5), description="Anchor centre (x, y) in a cell.")
    box_coder_scales: tuple[float, float, float, float] = Field(
        description="Box coder scales (y, x, h, w) of the encodings (ty, tx, th, tw)."
    )
    background_classes: tuple[int, ...] = Field(default=(0,), description="Score columns that are not objects.")


class GFLSpec(_Strict):
    """The feature levels of a Generalized Focal Loss head (NanoDet)."""

    strides: tuple[int, ...] = Field(min_length=1, description="Stride of each level, in the outputs' level order.")
    reg_max: int = Field(ge=1, description="Distances per side run over 0..reg_max strides (reg_max + 1 bins).")


class DetectorSidecar(_Strict):
    """The JSON sidecar of a detector (``MODEL.json``)."""

    name: str = Field(description="What the detector is, in words.")
    model: str = Field(description="ONNX file name, relative to the sidecar.")
    sha256: str | None = Field(default=None, description="sha256 of the ONNX file; checked on load when given.")
    layout: Layout = Field(description="Output layout; see stratamap.plugins.segmenters.detector.adapters.")
    labels: list[str] = Field(min_length=1, description="Label names by output class index.")
    input: InputSpec = Field(description="Input preprocessing.")
    outputs: list[str] | None = Field(default=None, description="Output names in the order the layout reads them.")
    ssd: SSDSpec | None = Field(default=None, description="Anchor and box-coder settings (layout ssd only).")
    gfl: GFLSpec | None = Field(default=None, description="Feature levels (layout gfl only).")
    license: str | None = Field(default=None, description="SPDX licence of the weights.")
    provenance: dict[str, Any] = Field(default_factory=dict, description="Where the weights came from, how converted.")


def read_sidecar(path: str | Path) -> DetectorSidecar:
    path = Path(path)
    try:
        raw = json.loads(read_data_text(path, "detector sidecar"))
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not valid JSON ({exc})") from exc
    try:
        side = DetectorSidecar.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or "(top level)"
        raise DataError(
            f"{path}: {key}: {err['msg']} ({len(exc.errors())} problem(s) in the detector sidecar)"
        ) from exc
    if side.layout == "ssd" and side.ssd is None:
        raise DataError(f"{path}: ssd: missing; layout ssd needs the anchor and box-coder settings")
    if side.layout == "gfl" and side.gfl is None:
        raise DataError(f"{path}: gfl: missing; layout gfl needs the strides and reg_max of its levels")
    return side


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class BoxDetector:
    """Runs a box detector with onnxruntime on the CPU and decodes its boxes.

    ``BoxDetector(model.onnx)`` reads the sidecar ``model.json`` beside the model when there is one;
    keyword arguments override it (a model without a sidecar needs at least ``layout`` and
    ``labels``). One intra-op thread (the default) makes the outputs bit-for-bit repeatable.
    """

    def __init__(
        self,
        model_path: str | Path,
        *,
        sidecar: str | Path | None = None,
        layout: Layout | None = None,
        labels: list[str] | None = None,
        input_spec: InputSpec | None = None,
        outputs: list[str] | None = None,
        ssd: SSDSpec | None = None,
        gfl: GFLSpec | None = None,
        score_threshold: float = 0.3,
        nms_iou: float = 0.5,
        max_detections: int = 100,
        threads: int = 1,
    ):
        self.model_path = Path(model_path)
        if not self.model_path.is_file():
            raise DataError(f"{self.model_path}: detector model not found")
        side_path = Path(sidecar) if sidecar is not None else self.model_path.with_suffix(".json")
        side = read_sidecar(side_path) if sidecar is not None or side_path.is_file() else None
        if (
            side is not None
            and side.sha256 is not None
            and (side_path.parent / side.model).resolve() == self.model_path.resolve()
        ):
            if file_sha256(self.model_path) != side.sha256:
                raise DataError(
                    f"{self.model_path}: sha256 differs from {side_path.name}'s {side.sha256} (corrupt or replaced)"
                )
        layout = layout or (side.layout if side else None)
        labels = labels or (side.labels if side else None)
        if layout is None or not labels:
            raise DataError(
                f"{self.model_path}: no sidecar {side_path.name} beside it; give layout and labels "
                "(and input_spec when the input shape is not fixed)"
            )
        ssd = ssd or (side.ssd if side else None)
        if layout == "ssd" and ssd is None:
            raise DataError(
                f"{self.model_path}: layout ssd needs anchor settings (the sidecar's ssd, or ssd=SSDSpec(...))"
            )
        gfl = gfl or (side.gfl if side else None)
        if layout == "gfl" and gfl is None:
            raise DataError(f"{self.model_path}: layout gfl needs its levels (the sidecar's gfl, or gfl=GFLSpec(...))")
        self.layout: Layout = layout
        self.labels = list(labels)
        self.ssd = ssd
        self.gfl = gfl
        self.score_threshold = float(score_threshold)
        self.nms_iou = float(nms_iou)
        self.max_detections = int(max_detections)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        try:
            self.session = ort.InferenceSession(
                str(self.model_path), sess_options=opts, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph/InvalidProtobuf types
            raise DataError(f"{self.model_path}: not an ONNX model onnxruntime can load ({exc})") from exc
        inputs = self.session.get_inputs()
        if len(inputs) != 1:
            raise DataError(f"{self.model_path}: expected one image input, the model has {len(inputs)}")
        self.input_name = inputs[0].name
        self.input_spec = input_spec or (side.input if side else None) or self._spec_from_shape(inputs[0].shape)
        expected = self._spec_from_shape(inputs[0].shape, required=False)
        if expected is not None and (expected.size, expected.tensor_layout) != (
            tuple(self.input_spec.size),
            self.input_spec.tensor_layout,
        ):
            raise DataError(
                f"{self.model_path}: input is {expected.tensor_layout} {expected.size[0]}x{expected.size[1]}, "
                f"the sidecar says {self.input_spec.tensor_layout} {self.input_spec.size[0]}x{self.input_spec.size[1]}"
            )
        names = [o.name for o in self.session.get_outputs()]
        wanted = outputs or (side.outputs if side else None) or names
        needed = 2 * len(gfl.strides) if gfl is not None and layout == "gfl" else adapters.LAYOUT_OUTPUTS[layout]
        missing = [n for n in wanted if n not in names]
        if missing or len(wanted) < needed:
            raise DataError(
                f"{self.model_path}: layout {layout} reads {needed} output(s); the model has {names}"
                + (f", not {missing}" if missing else "")
            )
        self.output_names = list(wanted[:needed])
        if ssd is not None:
            self.anchors = SSDAnchors(
                input_size=self.input_spec.size,
                strides=ssd.strides,
                min_scale=ssd.min_scale,
                max_scale=ssd.max_scale,
                aspect_ratios=ssd.aspect_ratios,
                reduce_boxes_in_lowest_layer=ssd.reduce_boxes_in_lowest_layer,
                interpolated_scale_aspect_ratio=ssd.interpolated_scale_aspect_ratio,
                anchor_offset=ssd.anchor_offset,
            ).generate()
            rows = {o.name: o.shape for o in self.session.get_outputs()}[self.output_names[0]]
            if isinstance(rows[-2], int) and rows[-2] != len(self.anchors):
                raise DataError(
                    f"{self.model_path}: the ssd settings give {len(self.anchors)} anchors, output "
                    f"{self.output_names[0]} has {rows[-2]} boxes"
                )

    def _spec_from_shape(self, shape: list[Any], required: bool = True) -> InputSpec | None:
        if len(shape) == 4 and shape[1] == 3 and isinstance(shape[2], int) and isinstance(shape[3], int):
            return InputSpec(size=(shape[3], shape[2]), tensor_layout="NCHW")
        if len(shape) == 4 and shape[3] == 3 and isinstance(shape[1], int) and isinstance(shape[2], int):
            return InputSpec(size=(shape[2], shape[1]), tensor_layout="NHWC")
        if not required:
            return None
        raise DataError(
            f"{self.model_path}: input shape {shape} is not a fixed 1x3xHxW or 1xHxWx3 image; give input_spec"
        )

    @classmethod
    def from_sidecar(cls, path: str | Path = SHIPPED, **kwargs: Any) -> BoxDetector:
        """The detector a sidecar describes (default: the shipped one); its model file sits beside it."""
        path = Path(path)
        return cls(path.parent / read_sidecar(path).model, sidecar=path, **kwargs)

    def preprocess(self, rgb: np.ndarray) -> tuple[np.ndarray, InputTransform]:
        """The network input for an HxWx3 uint8 RGB image, and how its pixels map back."""
        rgb = np.asarray(rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.shape[0] < 1 or rgb.shape[1] < 1:
            raise DataError(f"detector input: expected an HxWx3 uint8 RGB image, got {rgb.dtype} {rgb.shape}")
        spec = self.input_spec
        image_size = (rgb.shape[1], rgb.shape[0])
        if spec.resize == "stretch":
            transform = InputTransform.stretch(image_size, spec.size)
            pixels = np.asarray(Image.fromarray(rgb).resize(spec.size, Image.BILINEAR))
        else:
            transform = InputTransform.letterbox(image_size, spec.size)
            canvas = Image.new("RGB", spec.size, (spec.pad_value,) * 3)
            canvas.paste(Image.fromarray(rgb).resize(transform.inner_size, Image.BILINEAR), transform.pad)
            pixels = np.asarray(canvas)
        if spec.channel_order == "bgr":
            pixels = pixels[..., ::-1]
        x = (pixels.astype(np.float32) - np.float32(spec.mean)) / np.float32(spec.std)
        x = x.transpose(2, 0, 1) if spec.tensor_layout == "NCHW" else x
        return np.ascontiguousarray(x[None], np.float32), transform

    def raw_outputs(self, rgb: np.ndarray) -> tuple[list[np.ndarray], InputTransform]:
        """The network's outputs (in the order the layout reads them) for one image."""
        x, transform = self.preprocess(rgb)
        return self.session.run(self.output_names, {self.input_name: x}), transform

    def detect(self, rgb: np.ndarray, score_threshold: float | None = None, nms_iou: float | None = None) -> Detections:
        """Boxes in ``rgb``'s pixels, with the network's label names and scores, most confident first.

        ``score_threshold`` and ``nms_iou`` default to the detector's own.
        """
        outs, transform = self.raw_outputs(rgb)
        threshold = self.score_threshold if score_threshold is None else float(score_threshold)
        iou = self.nms_iou if nms_iou is None else float(nms_iou)
        common = {"score_threshold": threshold, "max_detections": self.max_detections}
        if self.layout == "ssd":
            assert self.ssd is not None
            return adapters.ssd(
                *outs,
                anchors=self.anchors,
                names=self.labels,
                transform=transform,
                input_size=self.input_spec.size,
                box_coder_scales=self.ssd.box_coder_scales,
                background_classes=self.ssd.background_classes,
                iou_threshold=iou,
                **common,
            )
        if self.layout == "centernet":
            return adapters.centernet(*outs, names=self.labels, transform=transform, iou_threshold=iou, **common)
        if self.layout == "gfl":
            assert self.gfl is not None
            return adapters.gfl(
                outs,
                strides=self.gfl.strides,
                reg_max=self.gfl.reg_max,
                names=self.labels,
                transform=transform,
                input_size=self.input_spec.size,
                iou_threshold=iou,
                **common,
            )
        if self.layout == "yolo":
            return adapters.yolo(*outs, names=self.labels, transform=transform, iou_threshold=iou, **common)
        return adapters.maskrcnn_boxes(*outs, names=self.labels, transform=transform, **common)

    __call__ = detect
