"""The shipped photograph-trained detector: its file, its decoders, and what it finds in a real office."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.plugins.segmenters.detector import adapters
from stratamap.plugins.segmenters.detector.adapters import InputTransform, SSDAnchors
from stratamap.plugins.segmenters.detector.box_detector import SHIPPED, SHIPPED_MODEL, BoxDetector, read_sidecar
from tests.conftest import REPO, shared_data

SIDECAR = json.loads(SHIPPED.read_text())


def test_shipped_model_loads_in_plain_onnxruntime_with_the_documented_input_and_outputs():
    import onnxruntime as ort

    session = ort.InferenceSession(str(SHIPPED_MODEL), providers=["CPUExecutionProvider"])
    (inp,) = session.get_inputs()
    assert inp.name == "normalized_input_image_tensor"
    assert inp.shape == [1, 3, 300, 300]
    outputs = {o.name: o.shape for o in session.get_outputs()}
    assert outputs == {"raw_outputs/box_encodings": [1, 1917, 4], "raw_outputs/class_predictions": [1, 1917, 24]}
    boxes, logits = session.run(None, {inp.name: np.zeros((1, 3, 300, 300), np.float32)})
    assert np.isfinite(boxes).all() and np.isfinite(logits).all()


def test_sidecar_sha256_and_provenance_match_the_shipped_files():
    data = SHIPPED_MODEL.read_bytes()
    assert hashlib.sha256(data).hexdigest() == SIDECAR["sha256"] == SIDECAR["provenance"]["onnx_sha256"]
    assert len(data) < 12_000_000  # fp16 weights: the fp32 conversion is 20 MB
    assert SIDECAR["labels"][0] == "???" and len(SIDECAR["labels"]) == 24
    assert {"Chair", "Table", "Desk", "Laptop", "Computer monitor", "Mug", "Bottle", "Book"} <= set(SIDECAR["labels"])
    license_text = (SHIPPED.parent / "LICENSE").read_text()
    assert "Apache License" in license_text and "Version 2.0, January 2004" in license_text
    assert SIDECAR["provenance"]["npm_package"] in (SHIPPED.parent / "README.md").read_text()
    assert read_sidecar(SHIPPED).layout == "ssd"


def test_anchors_match_mediapipe_ssd_layers():
    anchors = SSDAnchors().generate()
    assert anchors.shape == (1917, 4)
    assert SSDAnchors().layer_sizes() == [(19, 19), (10, 10), (5, 5), (3, 3), (2, 2), (1, 1)]
    assert [len(SSDAnchors().boxes_per_cell(i)) for i in range(6)] == [3, 6, 6, 6, 6, 6]
    assert ((anchors[:, :2] > 0) & (anchors[:, :2] < 1)).all()
    # lowest layer: 0.1 square boxes, then scale 0.2 at 2:1 and 1:2, column (x) before row within a row
    np.testing.assert_allclose(anchors[0], [0.5 / 19, 0.5 / 19, 0.1, 0.1])
    np.testing.assert_allclose(anchors[1, 2:] * anchors[1, 3:1:-1], [0.04, 0.04])  # w * h = scale**2
    np.testing.assert_allclose(anchors[3, :2], [1.5 / 19, 0.5 / 19])
    # the last anchor: the 1x1 layer's interpolated box, sqrt(0.95 * 1.0) square, centred
    np.testing.assert_allclose(anchors[-1], [0.5, 0.5, np.sqrt(0.95), np.sqrt(0.95)])
    np.testing.assert_allclose(anchors[1083], [0.05, 0.05, 0.35, 0.35])  # second layer, first box: scale 0.35, 1:1


def _encode(box, anchor, scales=(10.0, 10.0, 5.0, 5.0)):
    """The TF Object Detection API's FasterRcnnBoxCoder, by hand: (ty, tx, th, tw) of a normalised box."""
    x1, y1, x2, y2 = box
    cx, cy, w, h = (x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1
    ax, ay, aw, ah = anchor
    sy, sx, sh, sw = scales
    return [sy * (cy - ay) / ah, sx * (cx - ax) / aw, sh * np.log(h / ah), sw * np.log(w / aw)]


def test_ssd_decodes_a_hand_encoded_box_back_into_original_pixels():
    anchors = SSDAnchors().generate()
    enc = np.zeros((1917, 4), np.float32)
    logits = np.full((1917, 24), -10.0, np.float32)
    box = (0.2, 0.3, 0.6, 0.9)  # normalised x1 y1 x2 y2
    enc[1500] = _encode(box, anchors[1500])
    logits[1500, 5] = 2.0  # sigmoid 0.881
    logits[1500, 0] = 9.0  # background never becomes a detection
    names = SIDECAR["labels"]
    found = adapters.ssd(
        enc[None], logits[None], anchors, names, InputTransform.stretch((640, 480), (300, 300)), (300, 300)
    )
    assert found.labels == ["Chair"]
    np.testing.assert_allclose(found.scores, [1 / (1 + np.exp(-2.0))], rtol=1e-6)
    np.testing.assert_allclose(found.boxes[0], [0.2 * 640, 0.3 * 480, 0.6 * 640, 0.9 * 480], atol=1e-3)


def test_ssd_suppresses_per_class_and_keeps_other_labels_on_the_same_object():
    anchors = SSDAnchors().generate()
    enc = np.zeros((1917, 4))
    logits = np.full((1917, 24), -10.0)
    box = (0.1, 0.1, 0.5, 0.5)
    for k in (1100, 1106):  # two anchors predicting nearly the same box
        enc[k] = _encode(box, anchors[k])
    enc[1106] = _encode((0.11, 0.1, 0.51, 0.5), anchors[1106])
    logits[1100, 15], logits[1106, 15], logits[1106, 7] = 1.0, 0.5, 0.0  # table twice, desk once (0.5)
    found = adapters.ssd(enc, logits, anchors, SIDECAR["labels"], InputTransform((1, 1)), (1, 1))
    assert found.labels == ["Table", "Desk"]
    np.testing.assert_allclose(found.scores, [1 / (1 + np.exp(-1.0)), 0.5])


def test_nms_keeps_the_best_of_overlapping_boxes_and_all_disjoint_ones():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30], [0, 0, 10, 10]], float)
    scores = np.array([0.5, 0.9, 0.4, 0.5])
    assert adapters.nms(boxes, scores, 0.5).tolist() == [1, 2]
    assert adapters.nms(boxes, scores, 0.95).tolist() == [1, 0, 2]  # identical boxes 0 and 3: IoU 1
    assert adapters.nms(np.zeros((0, 4)), np.zeros(0), 0.5).tolist() == []


def test_centernet_rows_map_back_through_the_resize_and_skip_padding():
    rows = np.array([[[51.2, 102.4, 256.0, 512.0, 0.18, 56], [0, 0, 5, 5, 0.05, 0], [1, 1, 2, 2, 0.9, np.nan]]])
    found = adapters.centernet(rows, ["c"] * 56 + ["chair"], InputTransform.stretch((640, 480), (512, 512)))
    assert found.labels == ["chair"]
    np.testing.assert_allclose(found.boxes, [[64.0, 96.0, 320.0, 480.0]])


def test_yolo_head_undoes_the_letterbox_and_suppresses_duplicates():
    transform = InputTransform.letterbox((1280, 720), (640, 640))  # scale 0.5, 140 px bands above and below
    head = np.zeros((1, 4 + 2, 3))
    head[0, :4, 0] = [320, 320, 100, 50]
    head[0, :4, 1] = [322, 320, 100, 50]  # a near duplicate, lower score
    head[0, :4, 2] = [100, 200, 40, 40]
    head[0, 4:, 0] = [0.9, 0.1]
    head[0, 4:, 1] = [0.6, 0.0]
    head[0, 4:, 2] = [0.0, 0.7]
    found = adapters.yolo(head, ["chair", "table"], transform)
    assert found.labels == ["chair", "table"]
    np.testing.assert_allclose(found.boxes[0], [540.0, 310.0, 740.0, 410.0])
    np.testing.assert_allclose(found.boxes[1], [160.0, 80.0, 240.0, 160.0])


def test_gfl_head_reads_each_sides_distance_as_its_distributions_mean():
    """NanoDet's head: per level, scores per cell (row-major, centre at (col + 0.5) * stride) and per
    side a distribution over 0..reg_max strides; the distance is its mean, not its peak."""
    reg_max, big = 4, 30.0
    scores = [np.zeros((1, 8 * 8, 2)), np.zeros((1, 4 * 4, 2))]
    dists = [np.zeros((1, 8 * 8, 4 * (reg_max + 1))), np.zeros((1, 4 * 4, 4 * (reg_max + 1)))]
    cell = 3 * 8 + 2  # column 2, row 3 of the stride-8 level: centre (20, 28)
    scores[0][0, cell, 1] = 0.8
    sides = dists[0][0, cell].reshape(4, reg_max + 1)
    sides[0, 1] = big  # left: 1 stride
    sides[1, [1, 2]] = big  # top: half on 1, half on 2 strides -> 1.5 (a peak would read 1 or 2)
    sides[2, 3] = big  # right: 3 strides
    sides[3, 0] = big  # bottom: 0
    scores[1][0, 5, 0] = 0.2  # below the threshold
    found = adapters.gfl(
        [*scores, *dists],
        strides=(8, 16),
        reg_max=reg_max,
        names=["cup", "chair"],
        transform=InputTransform.stretch((128, 64), (64, 64)),
        input_size=(64, 64),
    )
    assert found.labels == ["chair"]
    np.testing.assert_allclose(found.boxes, [[24.0, 16.0, 88.0, 28.0]], atol=1e-6)
    np.testing.assert_allclose(found.scores, [0.8])
    with pytest.raises(ValueError, match="level 1 has 16 cells"):
        adapters.gfl(
            [*scores, *dists],
            strides=(8, 8),
            reg_max=reg_max,
            names=["a", "b"],
            transform=InputTransform.stretch((64, 64), (64, 64)),
            input_size=(64, 64),
        )


def test_maskrcnn_boxes_threshold_and_drop_background():
    found = adapters.maskrcnn_boxes(
        np.array([[10, 20, 30, 40], [0, 0, 5, 5], [1, 1, 2, 2]]),
        np.array([2, 1, 0]),
        np.array([0.8, 0.3, 0.99]),
        ["background", "person", "chair"],
        InputTransform.stretch((200, 100), (100, 100)),
    )
    assert found.labels == ["chair"]
    np.testing.assert_allclose(found.boxes, [[20, 20, 60, 40]])


def test_bad_model_and_sidecar_raise_data_errors_naming_the_file(tmp_path):
    bad_model = tmp_path / "junk.onnx"
    bad_model.write_bytes(b"not a model")
    with pytest.raises(DataError, match="junk.onnx"):
        BoxDetector(bad_model, layout="yolo", labels=["a"])
    with pytest.raises(DataError, match="no sidecar"):
        BoxDetector(bad_model)
    side = tmp_path / "det.json"
    side.write_text(json.dumps({**SIDECAR, "layout": "retina"}))
    with pytest.raises(DataError, match=r"det.json: layout"):
        read_sidecar(side)
    side.write_text("{")
    with pytest.raises(DataError, match="det.json: not valid JSON"):
        BoxDetector.from_sidecar(side)
    copy = tmp_path / SHIPPED_MODEL.name
    copy.write_bytes(SHIPPED_MODEL.read_bytes()[:-1] + b"\0")
    (tmp_path / SHIPPED.name).write_text(SHIPPED.read_text())
    with pytest.raises(DataError, match="sha256 differs"):
        BoxDetector(copy)
    model = tmp_path / "good.onnx"
    model.write_bytes(SHIPPED_MODEL.read_bytes())
    wrong_size = {**SIDECAR, "model": "good.onnx", "input": {**SIDECAR["input"], "size": [320, 320]}}
    side.write_text(json.dumps(wrong_size))
    with pytest.raises(DataError, match="input is NCHW 300x300, the sidecar says NCHW 320x320"):
        BoxDetector.from_sidecar(side)
    side.write_text(json.dumps({**SIDECAR, "model": "good.onnx", "ssd": {**SIDECAR["ssd"], "strides": [16, 32]}}))
    with pytest.raises(DataError, match="give 1683 anchors, output raw_outputs/box_encodings has 1917"):
        BoxDetector.from_sidecar(side)
    side.write_text(json.dumps({**SIDECAR, "model": "good.onnx", "layout": "gfl"}))
    with pytest.raises(DataError, match="det.json: gfl: missing"):
        BoxDetector.from_sidecar(side)
    with pytest.raises(DataError, match="layout gfl needs its levels"):
        BoxDetector(model, layout="gfl", labels=["a"])
    with pytest.raises(DataError, match="HxWx3 uint8"):
        BoxDetector(SHIPPED_MODEL).detect(np.zeros((10, 10), np.uint8))


def test_detections_are_repeatable_and_in_original_pixels():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    detector = BoxDetector(SHIPPED_MODEL)
    a, b = detector.detect(image, score_threshold=0.05), detector.detect(image, score_threshold=0.05)
    assert np.array_equal(a.boxes, b.boxes) and a.labels == b.labels and np.array_equal(a.scores, b.scores)
    assert ((a.boxes >= 0) & (a.boxes <= [320, 240, 320, 240])).all()
    assert np.all(np.diff(a.scores) <= 0)


def test_real_office_frames_chair_and_table_every_frame_no_false_positive():
    from PIL import Image

    frames = sorted(shared_data("align3d_office", "rgb").glob("*.png"))
    assert len(frames) == 31
    detector = BoxDetector.from_sidecar(SHIPPED)
    for path in frames:
        found = detector.detect(np.asarray(Image.open(path).convert("RGB")), score_threshold=0.3)
        assert "Chair" in found.labels and "Table" in found.labels, path.name
        assert set(found.labels) <= {"Chair", "Table", "Desk"}, (path.name, found.labels)
        chair = found.boxes[found.labels.index("Chair")]
        assert chair[0] < 320 and chair[3] > 400  # the chair stands in the left half, down to the floor
        assert 0.5 < found.scores[found.labels.index("Chair")] < 0.7


@pytest.mark.slow
def test_build_script_reproduces_the_shipped_model(tmp_path):
    """npm pack + tflite2onnx in a fresh venv gives the very bytes that ship (needs npm and the network)."""
    if shutil.which("npm") is None:
        pytest.skip("npm not available")
    probe = subprocess.run(["npm", "view", "@mediapipe/objectron@0.4.1675468480", "version"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip("npm registry not reachable")
    out = tmp_path / "models"
    subprocess.run(
        [sys.executable, str(REPO / "scripts" / "build_detector.py"), "--out", str(out), "--venv", str(tmp_path / "v")],
        check=True,
        timeout=600,
    )
    for name in (SHIPPED_MODEL.name, SHIPPED.name, "LICENSE", "README.md"):
        assert (out / name).read_bytes() == (SHIPPED.parent / name).read_bytes(), name
    assert Path(out / SHIPPED_MODEL.name).stat().st_size == SHIPPED_MODEL.stat().st_size


def _turned(pose: np.ndarray, turns: int) -> np.ndarray:
    """The pose of a camera turned so that its image is ``np.rot90(image, -turns)`` of the level one's."""
    quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # turned image axes in the level camera's
    out = np.array(pose, float)
    out[:3, :3] = out[:3, :3] @ np.linalg.matrix_power(quarter, turns)
    return out


#: A camera held level looking along +y (image right = +x, image down = -z).
LEVEL = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 1.2], [0, 0, 0, 1]])


def test_quarter_turns_bring_a_turned_camera_upright():
    """Held level: none; turned (a phone held upright) or upside down: the turns np.rot90 needs; pitched
    down steeply or without a pose: none."""
    from stratamap.core.geometry.transforms import upright_turns

    assert upright_turns(LEVEL) == 0 and upright_turns(None) == 0
    for turns in (1, 2, 3):
        assert upright_turns(_turned(LEVEL, turns)) == turns
    pitched = LEVEL.copy()
    pitched[:3, :3] = LEVEL[:3, :3] @ np.array(
        [[1.0, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]]
    )
    assert upright_turns(pitched) == 0 and upright_turns(_turned(pitched, 1)) == 1
    down = LEVEL.copy()
    down[:3, :3] = [[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]  # looking straight down at the floor
    assert upright_turns(down) == 0


def test_a_camera_held_turned_is_detected_on_its_image_turned_upright():
    """A frame of a camera held on its side (a phone recording upright) or upside down: the detector
    runs on the image turned upright, and its boxes are in the frame's own pixels. On the real office's
    frame turned, the detector as it is finds a "Vehicle", nothing, or three weak chairs and no table."""
    from PIL import Image

    from stratamap.core.geometry.transforms import upright_turns
    from stratamap.plugins.segmenters.detector import detect_upright

    level = LEVEL
    image = np.asarray(Image.open(sorted(shared_data("align3d_office", "rgb").glob("*.png"))[0]).convert("RGB"))
    detector = BoxDetector.from_sidecar(SHIPPED)
    upright = detect_upright(detector, image, 0, 0.3, 0.5, 1)
    assert {"Chair", "Table"} <= set(upright.labels)
    for turns in (1, 2, 3):
        pose = _turned(level, turns)
        assert upright_turns(pose) == turns
        frame = np.ascontiguousarray(np.rot90(image, -turns))
        found = detect_upright(detector, frame, upright_turns(pose), 0.3, 0.5, 1)
        assert found.labels == upright.labels and np.array_equal(found.scores, upright.scores)
        # Each box, drawn on the frame and turned upright with it, covers the upright image's box.
        for box, want in zip(found.boxes, upright.boxes, strict=True):
            mask = np.zeros(frame.shape[:2], bool)
            x0, y0, x1, y1 = np.round(box).astype(int)
            mask[y0:y1, x0:x1] = True
            rows, cols = np.nonzero(np.rot90(mask, turns))
            assert np.allclose([cols.min(), rows.min(), cols.max() + 1, rows.max() + 1], want, atol=1.5), (
                turns,
                box,
                want,
            )
