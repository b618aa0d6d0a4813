"""Small trained models shipped as an ONNX file beside a JSON sidecar (the file's name, its sha256,
what the model reads), run by onnxruntime on one thread so that the scores are the same on every
machine. scikit-learn trains them (the ``train`` extra); the runtime never imports it."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.documents import read_data_text
from stratamap.core.errors import DataError
from stratamap.core.lazy import lazy_module

ort = lazy_module("onnxruntime")


def read_sidecar(sidecar: Path, what: str, required: tuple[str, ...]) -> dict[str, Any]:
    """The sidecar's JSON object; a one-line DataError naming it when it is unreadable or lacks one
    of ``required`` (``what``: e.g. "naming-model")."""
    try:
        side = json.loads(read_data_text(sidecar, f"{what} sidecar"))
    except ValueError as exc:
        raise DataError(f"{sidecar}: not a readable {what} sidecar (JSON) ({exc})") from exc
    if not isinstance(side, dict) or not set(required) <= side.keys():
        keys = ", ".join(required[:-1]) + f" and {required[-1]}"
        raise DataError(f"{sidecar}: a {what} sidecar needs {keys}")
    return side


class OnnxModel:
    """The ONNX file a sidecar names (beside it), checked against the sidecar's ``sha256`` where it
    has one, in a one-thread onnxruntime session (``what``: e.g. "naming model", for errors)."""

    def __init__(self, sidecar: Path, side: dict[str, Any], what: str) -> None:
        path = Path(sidecar).parent / str(side["model"])
        try:
            blob = path.read_bytes()
        except OSError as exc:
            raise DataError(f"{path}: the {what} is missing ({exc.strerror})") from exc
        if side.get("sha256") and hashlib.sha256(blob).hexdigest() != side["sha256"]:
            raise DataError(f"{path}: its sha256 is not the sidecar's (a corrupt or replaced model)")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1  # one thread: the same scores on every machine run
        opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(blob, sess_options=opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidProtobuf types
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise DataError(f"{path}: not an ONNX model onnxruntime can load ({first})") from exc
        self.input = self.session.get_inputs()[0].name
        self.path = path

    def probabilities(self, features: np.ndarray, n_classes: int) -> np.ndarray:
        """(rows, n_classes): each row's probability of each class (a classifier's second output, as
        skl2onnx writes it, with or without its ZipMap)."""
        if not len(features):
            return np.zeros((0, n_classes), np.float32)
        outputs = self.session.run(None, {self.input: np.asarray(features, np.float32)})
        probs = outputs[1] if len(outputs) > 1 else outputs[0]
        if isinstance(probs, list):  # skl2onnx's ZipMap output: one {class index: probability} per row
            probs = [[row[k] for k in sorted(row)] for row in probs]
        return np.asarray(probs, np.float32).reshape(len(features), n_classes)
