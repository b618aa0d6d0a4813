"""Segmenters: ONNX layouts run through onnxruntime on graphs built here, the shipped model, and
model-free clusters on synthetic and real (mOSD) point clouds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame, SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

H, W = 48, 64


def graph_model(path: Path, input_shape, outputs: dict[str, np.ndarray], gain_output: str | None = None) -> Path:
    """An ONNX graph whose outputs are constants, except ``gain_output``, which is scaled by the
    input's mean colour (so inference really reads the image: a black image zeroes it)."""
    nodes, outs = [], []
    inp = helper.make_tensor_value_info("images", TensorProto.FLOAT, list(input_shape))
    for name, value in outputs.items():
        const = f"{name}_const"
        nodes.append(
            helper.make_node("Constant", [], [const], value=numpy_helper.from_array(value.astype(np.float32), const))
        )
        if name == gain_output:
            nodes.append(helper.make_node("ReduceMean", ["images"], ["gain"], keepdims=0))
            nodes.append(helper.make_node("Mul", [const, "gain"], [name]))
        else:
            nodes.append(helper.make_node("Identity", [const], [name]))
        outs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, list(value.shape)))
    model = helper.make_model(helper.make_graph(nodes, "g", [inp], outs), opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def frames_data(n: int = 2, color=200) -> PipelineData:
    rgb = np.full((H * 2, W * 2, 3), color, np.uint8)
    depth = np.full((H * 2, W * 2), 2.0, np.float32)
    stream = SensorStream(name="t", frames=[RGBDFrame(k, 0.1 * k, rgb, depth, np.eye(4)) for k in range(n)])
    return PipelineData(stream=stream)


def run(model: Path, data: PipelineData, **params):
    from stratamap.plugins.segmenters.onnx_panoptic import ONNXPanopticSegmenter

    return ONNXPanopticSegmenter(model=str(model), **params).run(data)["frame_labels"]


def test_maskrcnn_layout_pastes_box_masks_most_confident_on_top(tmp_path):
    vocab = Vocabulary.default()
    boxes = np.array([[4, 4, 36, 30], [20, 10, 60, 44], [0, 0, 5, 5]], np.float32)
    labels = np.array([57, 42, 1], np.float32)  # the zoo's 1-based COCO ids: chair, cup, person
    scores = np.array([0.9, 0.8, 0.2], np.float32)
    masks = np.ones((3, 1, 28, 28), np.float32)
    model = graph_model(
        tmp_path / "mrcnn.onnx",
        (1, 3, H, W),
        {"boxes": boxes, "labels": labels, "scores": scores, "masks": masks},
        gain_output="scores",
    )
    out = run(model, frames_data(), layout="maskrcnn")
    seg = out.frames[0]
    assert seg.class_ids.shape == (H * 2, W * 2)
    # The low-scoring third detection is dropped; the overlap belongs to the first (0.9 > 0.8).
    assert set(np.unique(seg.instance_ids)) == {0, 1, 2}
    assert seg.instance_ids[15 * 2, 25 * 2] == 1 and seg.instance_ids[40, 110] == 2
    assert seg.class_ids[15 * 2, 25 * 2] == vocab.id("chair") and seg.class_ids[40, 110] == vocab.id("cup")
    # A black image zeroes the scores through the graph: nothing is detected.
    assert not run(model, frames_data(color=0), layout="maskrcnn").frames[0].instance_ids.any()


def test_yolo_seg_layout_decodes_boxes_nms_and_prototype_masks(tmp_path):
    vocab = Vocabulary.default()
    nc, k, anchors = 80, 4, 6
    det = np.zeros((1, 4 + nc + k, anchors), np.float32)
    # Two overlapping chairs (COCO 56) and one cup (41); the second chair is suppressed by NMS.
    for a, (cx, cy, w, h, c, s, coeff) in enumerate(
        [(16, 24, 24, 40, 56, 0.9, 0), (18, 24, 24, 40, 56, 0.6, 0), (48, 20, 20, 20, 41, 0.8, 1)]
    ):
        det[0, :4, a] = (cx, cy, w, h)
        det[0, 4 + c, a] = s
        det[0, 4 + nc + coeff, a] = 8.0
    protos = np.full((1, k, H // 4, W // 4), 1.0, np.float32)
    model = graph_model(tmp_path / "yolo.onnx", (1, 3, H, W), {"output0": det, "output1": protos})
    seg = run(model, frames_data(), layout="yolo_seg", resize="letterbox", score_threshold=0.25).frames[0]
    ids = set(np.unique(seg.instance_ids)) - {0}
    assert len(ids) == 2
    assert seg.class_ids[24 * 2, 16 * 2] == vocab.id("chair") and seg.class_ids[20 * 2, 48 * 2] == vocab.id("cup")
    assert seg.class_ids[45 * 2, 62 * 2] == 0  # outside every box


def test_semantic_boundary_layout_splits_instances_at_boundaries(tmp_path):
    vocab = Vocabulary.default()
    c = len(vocab.names)
    logits = np.zeros((1, c, H, W), np.float32)
    logits[0, vocab.id("floor")] = 1.0
    logits[0, vocab.id("chair"), 10:40, 5:60] = 5.0
    boundary = np.full((1, 1, H, W), -5.0, np.float32)
    boundary[0, 0, 10:40, 30:33] = 5.0  # a boundary cuts the chair region in two
    model = graph_model(tmp_path / "sb.onnx", (1, 4, H, W), {"class_logits": logits, "boundary_logits": boundary})
    (tmp_path / "sb.json").write_text(json.dumps({"layout": "semantic_boundary", "classes": list(vocab.names)}))
    # Depth merging and the confidence floor off: this checks the boundary split alone.
    labels = run(model, frames_data(), merge_depth_gap=0.0, min_region_score=0.0)
    seg = labels.frames[0]
    left, right = seg.instance_ids[50, 20], seg.instance_ids[50, 100]
    assert left > 0 and right > 0 and left != right
    assert seg.class_ids[5, 5] == vocab.id("floor") and seg.instance_ids[5, 5] == 0
    assert seg.instance_ids[50, 62] in (left, right)  # boundary pixels join a neighbour


def test_bad_model_file_is_named(tmp_path):
    from stratamap.core.errors import DataError

    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(DataError, match="broken.onnx"):
        run(bad, frames_data())
    with pytest.raises(DataError, match="not found"):
        run(tmp_path / "missing.onnx", frames_data())


def test_rgbd_model_on_frames_without_depth_is_named(tmp_path):
    from stratamap.core.errors import DataError

    vocab = Vocabulary.default()
    logits = np.zeros((1, len(vocab.names), H, W), np.float32)
    boundary = np.zeros((1, 1, H, W), np.float32)
    model = graph_model(tmp_path / "rgbd.onnx", (1, 4, H, W), {"class_logits": logits, "boundary_logits": boundary})
    data = frames_data()
    data.stream.frames[1].depth = None
    with pytest.raises(DataError, match="frame 1 .*no depth.*rgbd.onnx"):
        run(model, data, layout="semantic_boundary")


def test_model_that_does_not_fit_its_layout_is_named(tmp_path):
    from stratamap.core.errors import DataError

    vocab = Vocabulary.default()
    logits = np.zeros((1, len(vocab.names), H, W), np.float32)
    boundary = np.zeros((1, 1, H, W), np.float32)
    model = graph_model(tmp_path / "semantic.onnx", (1, 4, H, W), {"class_logits": logits, "boundary_logits": boundary})
    with pytest.raises(
        DataError,
        match=r"semantic\.onnx has outputs \['class_logits', 'boundary_logits'\], but the 'maskrcnn' layout reads 4",
    ):
        run(model, frames_data(), layout="maskrcnn")
    # Two outputs, as YOLO-seg has, but 8 detection rows cannot hold 4 box values, a class and 8 mask coefficients.
    yolo = graph_model(
        tmp_path / "short.onnx",
        (1, 3, H, W),
        {"output0": np.zeros((1, 8, 6), np.float32), "output1": np.ones((1, 8, 12, 16), np.float32)},
    )
    with pytest.raises(DataError, match=r"short\.onnx on frame 0: its outputs do not fit the 'yolo_seg' layout"):
        run(yolo, frames_data(), layout="yolo_seg")
    (tmp_path / "semantic.json").write_text(json.dumps({"layout": "semantic-boundary"}))
    with pytest.raises(DataError, match=r"semantic\.json names layout 'semantic-boundary'"):
        run(model, frames_data())


def test_shipped_model_loads_in_plain_onnxruntime_as_documented():
    from stratamap.plugins.segmenters.onnx_panoptic import SHIPPED

    if not SHIPPED.is_file():
        pytest.skip("the shipped model has not been trained in this checkout")
    meta = json.loads(SHIPPED.with_suffix(".json").read_text())
    assert SHIPPED.stat().st_size < 20e6
    session = ort.InferenceSession(str(SHIPPED), providers=["CPUExecutionProvider"])
    (inp,) = session.get_inputs()
    assert inp.name in meta["inputs"] and list(inp.shape) == meta["inputs"][inp.name]["shape"]
    outs = session.run(None, {inp.name: np.zeros(inp.shape, np.float32)})
    assert [o.name for o in session.get_outputs()] == list(meta["outputs"])
    assert [list(o.shape) for o in outs] == [meta["outputs"][n]["shape"] for n in meta["outputs"]]


def test_semantic_boundary_speckle_filter_removes_stray_classes():
    """A 3-pixel blob of another class inside a region takes the region's class when filtered."""
    from stratamap.plugins.segmenters.onnx_panoptic.adapters import semantic_boundary

    logits = np.zeros((1, 3, 20, 20), np.float32)
    logits[0, 1] = 5.0
    logits[0, 2, 5, 5:8] = 10.0  # three stray pixels of class 2
    bound = np.full((1, 1, 20, 20), -10.0, np.float32)
    ident, thing = np.arange(3), np.array([False, False, True])
    raw, _, _ = semantic_boundary(logits, bound, ident, thing, min_pixels=1, speckle_pixels=0)
    clean, inst, _ = semantic_boundary(logits, bound, ident, thing, min_pixels=1, speckle_pixels=4)
    assert (raw == 2).sum() == 3 and (clean == 2).sum() == 0 and (clean == 1).all() and inst.max() == 0


def test_semantic_boundary_merges_instances_split_at_a_depth_continuous_seam():
    """A spurious boundary across one object (same depth on both sides) is healed; a boundary at
    a depth step (one object in front of another) keeps two instances."""
    from stratamap.plugins.segmenters.onnx_panoptic.adapters import semantic_boundary

    logits = np.zeros((1, 2, 20, 20), np.float32)
    logits[0, 1, 4:16, 2:18] = 10.0  # one thing region
    bound = np.full((1, 1, 20, 20), -10.0, np.float32)
    bound[0, 0, 4:16, 10] = 10.0  # a boundary column splits it in two
    ident, thing = np.arange(2), np.array([False, True])
    flat = np.full((20, 20), 2.0, np.float32)
    split, inst_split, _ = semantic_boundary(logits, bound, ident, thing, min_pixels=1, speckle_pixels=0)
    step = np.where(inst_split == inst_split[10, 17], 3.0, 2.0).astype(
        np.float32
    )  # the right part a metre farther: two objects
    _, inst_flat, _ = semantic_boundary(
        logits, bound, ident, thing, min_pixels=1, speckle_pixels=0, depth=flat, merge_depth_gap=0.06
    )
    _, inst_step, _ = semantic_boundary(
        logits, bound, ident, thing, min_pixels=1, speckle_pixels=0, depth=step, merge_depth_gap=0.06
    )
    region = split == 1
    assert len(np.unique(inst_split[region])) == 2
    assert len(np.unique(inst_flat[region])) == 1
    assert len(np.unique(inst_step[region])) == 2


def test_depth_continuous_merge_counts_seams_between_classes():
    """As documented: every depth-continuous seam counts, so two instances of one class that meet
    only through an instance of another class get one id."""
    from stratamap.plugins.segmenters.onnx_panoptic.adapters import merge_depth_continuous

    ids = np.zeros((6, 9), np.int32)
    ids[1:5, 0:3], ids[1:5, 3:6], ids[1:5, 6:9] = 1, 2, 3  # chair | table | chair, side by side
    flat = np.full(ids.shape, 2.0, np.float32)
    merged = merge_depth_continuous(ids, flat, 0.06)
    assert len(np.unique(merged[1:5])) == 1
    step = np.where(ids == 2, 3.0, 2.0).astype(np.float32)  # the table a metre behind: no seam holds
    assert len(np.unique(merge_depth_continuous(ids, step, 0.06)[1:5])) == 3


def test_depth_continuous_merge_bridges_only_through_smaller_instances():
    """bridges='smaller': two cups standing on one table (continuous seams, the table far larger)
    stay two cups, where 'any' makes them one; a post smaller than both parts of a chair (seat
    above, base below) still joins them."""
    from stratamap.plugins.segmenters.onnx_panoptic.adapters import merge_depth_continuous

    TABLE, CUP, CHAIR, POST = 1, 2, 3, 4
    ids = np.zeros((12, 20), np.int32)
    cls = np.zeros(ids.shape, np.int64)
    ids[6:12, :], cls[6:12, :] = 1, TABLE
    ids[3:6, 2:5], cls[3:6, 2:5] = 2, CUP
    ids[3:6, 14:17], cls[3:6, 14:17] = 3, CUP
    flat = np.full(ids.shape, 2.0, np.float32)
    any_bridge = merge_depth_continuous(ids, flat, 0.06)
    assert any_bridge[4, 3] == any_bridge[4, 15]
    smaller = merge_depth_continuous(ids, flat, 0.06, class_ids=cls, bridges="smaller")
    assert smaller[4, 3] != smaller[4, 15]

    chair = np.zeros((12, 8), np.int32)
    ccls = np.zeros(chair.shape, np.int64)
    chair[0:5, :], ccls[0:5, :] = 1, CHAIR  # seat and back
    chair[5:7, 3:5], ccls[5:7, 3:5] = 2, POST  # the post, called something else
    chair[7:12, :], ccls[7:12, :] = 3, CHAIR  # the base
    merged = merge_depth_continuous(
        chair, np.full(chair.shape, 2.0, np.float32), 0.06, class_ids=ccls, bridges="smaller"
    )
    assert merged[2, 2] == merged[9, 2]
    with pytest.raises(ValueError, match="class_ids"):
        merge_depth_continuous(chair, np.full(chair.shape, 2.0, np.float32), 0.06, bridges="smaller")


def test_semantic_boundary_leaves_unsure_regions_unknown():
    """A region whose mean top probability is under min_region_score becomes class 0 (unknown);
    confident regions keep their class."""
    from stratamap.plugins.segmenters.onnx_panoptic.adapters import semantic_boundary

    logits = np.zeros((1, 3, 20, 20), np.float32)
    logits[0, 1] = 8.0
    logits[0, 2, 2:8, 2:8] = 8.3  # class 2 wins here, but barely (p ~ 0.57)
    bound = np.full((1, 1, 20, 20), -10.0, np.float32)
    ident, thing = np.arange(3), np.array([False, False, True])
    kept, _, _ = semantic_boundary(logits, bound, ident, thing, min_pixels=1, speckle_pixels=0, min_region_score=0.5)
    dropped, inst, _ = semantic_boundary(
        logits, bound, ident, thing, min_pixels=1, speckle_pixels=0, min_region_score=0.8
    )
    assert (kept == 2).sum() == 36
    assert (dropped == 0).sum() == 36 and (
        dropped[
            ~((np.arange(20)[:, None] >= 2) & (np.arange(20)[:, None] < 8) & (np.arange(20) >= 2) & (np.arange(20) < 8))
        ]
        == 1
    ).all()
    assert inst.max() == 0


def test_onnx_panoptic_segments_a_turned_camera_s_frames_upright():
    """A frame of a camera held turned a quarter (a phone recording upright) is segmented turned
    upright: its labels are the level frame's, turned with it (the network learned level views)."""
    from stratamap.core.synthetic import SceneSpec, generate_sequence
    from stratamap.plugins.segmenters.onnx_panoptic import SHIPPED, ONNXPanopticSegmenter

    if not SHIPPED.is_file():
        pytest.skip("the shipped model has not been trained in this checkout")
    seq = generate_sequence(
        SceneSpec.model_validate(
            {"type": "office", "seed": 3, "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 4}}
        )
    )
    quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # turned image axes in the level camera's
    level = [seq.stream.frames[k] for k in (1, 2)]
    turned = []
    for f in level:
        pose = np.array(f.pose, float)
        pose[:3, :3] = pose[:3, :3] @ quarter
        rgb, depth = (np.ascontiguousarray(np.rot90(a, -1)) for a in (f.rgb, f.depth))
        turned.append(RGBDFrame(f.index, f.timestamp, rgb, depth, pose))
    intr = seq.stream.intrinsics
    turned_intr = CameraIntrinsics(intr.height, intr.width, intr.fy, intr.fx, intr.height - 1 - intr.cy, intr.cx)
    labels = [
        ONNXPanopticSegmenter().run(PipelineData(stream=SensorStream("s", intrinsics=i, frames=frames)))["frame_labels"]
        for i, frames in ((intr, level), (turned_intr, turned))
    ]
    for upright, sideways in zip(labels[0].frames, labels[1].frames, strict=True):
        assert (upright.class_ids > 0).any()
        assert np.array_equal(np.rot90(upright.class_ids, -1), sideways.class_ids)
