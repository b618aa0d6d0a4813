"""Per-frame depth segmentation: objects cut from what they stand on and stand before, layout from
gravity-aligned planes, and detections that take their object's segments but not their spill."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.geometry.transforms import invert
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.plugins.segmenters import _depth

o3d = pytest.importorskip("open3d")
trimesh = pytest.importorskip("trimesh")

INTRINSICS = CameraIntrinsics(width=320, height=240, fx=280.0, fy=280.0, cx=160.0, cy=120.0)


def _look_at(eye, target) -> np.ndarray:
    """Camera (optical frame: x right, y down, z forward) to world."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], 1)
    pose[:3, 3] = eye
    return pose


def _render(meshes, pose):
    scene = o3d.t.geometry.RaycastingScene()
    ids = [
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(m.vertices, np.float32)), o3d.core.Tensor(np.asarray(m.faces, np.uint32))
        )
        for m in meshes
    ]
    rays = scene.create_rays_pinhole(
        o3d.core.Tensor(INTRINSICS.matrix), o3d.core.Tensor(invert(pose)), INTRINSICS.width, INTRINSICS.height
    )
    hit = scene.cast_rays(rays)
    depth = hit["t_hit"].numpy()
    gid = hit["geometry_ids"].numpy().astype(np.int64)
    ok = np.isfinite(depth)
    which = np.full(depth.shape, -1)
    for k, i in enumerate(ids):
        which[ok & (gid == i)] = k
    return np.where(ok, depth, 0).astype(np.float32), which


def _room():
    floor = trimesh.creation.box((6, 6, 0.02), trimesh.transformations.translation_matrix((2, 0, -0.01)))
    wall = trimesh.creation.box((0.02, 6, 2.6), trimesh.transformations.translation_matrix((3.5, 0, 1.3)))
    crate = trimesh.creation.box((0.5, 0.5, 0.5), trimesh.transformations.translation_matrix((1.8, 0.0, 0.25)))
    return [floor, wall, crate]


@pytest.fixture(scope="module")
def view():
    pose = _look_at(np.array([0.0, 0.0, 1.2]), [2.0, 0.0, 0.4])
    depth, which = _render(_room(), pose)
    geometry = _depth.frame_geometry(depth, INTRINSICS, _depth.DepthSegmentsConfig(stride=1))
    stats = _depth.segment_stats(geometry, pose)
    layout = _depth.layout_segments(stats, 0.0, _depth.LayoutConfig())
    return depth, which, geometry, stats, layout


def _majority(segments, mask):
    ids, counts = np.unique(segments[mask & (segments > 0)], return_counts=True)
    return ids[np.argmax(counts)], counts.max() / max(mask.sum(), 1)


def test_an_object_is_cut_from_the_floor_it_stands_on_and_the_wall_behind(view):
    _, which, geometry, _, _ = view
    seg = geometry.segments
    floor_id, floor_share = _majority(seg, which == 0)
    wall_id, wall_share = _majority(seg, which == 1)
    assert floor_share > 0.8 and wall_share > 0.8 and floor_id != wall_id
    crate = which == 2
    assert np.isin(seg[crate], [floor_id, wall_id]).mean() < 0.05
    # the crate's visible faces meet in convex edges: they stay together
    crate_id, crate_share = _majority(seg, crate)
    assert crate_share > 0.8


def test_layout_comes_from_gravity_aligned_planes(view):
    _, which, geometry, _, layout = view
    seg = geometry.segments
    floor_id, _ = _majority(seg, which == 0)
    wall_id, _ = _majority(seg, which == 1)
    crate_id, _ = _majority(seg, which == 2)
    assert layout["floor"][floor_id] and not layout["wall"][floor_id]
    assert layout["wall"][wall_id] and not layout["floor"][wall_id]
    assert not any(layout[name][crate_id] for name in ("floor", "wall", "ceiling"))


def test_a_box_takes_its_object_and_not_what_it_spills_onto(view):
    _, which, geometry, stats, layout = view
    rows, cols = np.nonzero(which == 2)
    pad = 25  # the detector's box is loose: it covers floor and wall around the crate
    box = (cols.min() - pad, rows.min() - pad, cols.max() + pad, rows.max() + pad)
    region = _depth.Region(class_id=16, score=0.9, box=box, extent=0.6)
    seg_class, seg_instance = _depth.assign_regions(geometry, stats, layout, [region])
    cls = seg_class[geometry.segments]
    crate = which == 2
    assert (cls[crate] == 16).mean() > 0.9
    assert (cls[which == 0] == 16).mean() < 0.02 and (cls[which == 1] == 16).mean() < 0.02
    assert set(np.unique(seg_instance[geometry.segments][cls == 16])) == {1}


def test_the_more_confident_detection_keeps_a_contested_object(view):
    _, which, geometry, stats, layout = view
    rows, cols = np.nonzero(which == 2)
    box = (cols.min() - 5, rows.min() - 5, cols.max() + 5, rows.max() + 5)
    weak = _depth.Region(class_id=5, score=0.4, box=box)
    strong = _depth.Region(class_id=16, score=0.8, box=box)
    seg_class, _ = _depth.assign_regions(geometry, stats, layout, [weak, strong])
    assert (seg_class[geometry.segments][which == 2] == 16).mean() > 0.9


def test_labels_go_back_to_the_frame_resolution():
    coarse = np.arange(12).reshape(3, 4)
    full = _depth.to_frame(coarse, 2, (6, 8))
    assert full.shape == (6, 8)
    assert (full[::2, ::2] == coarse).all() and (full[1::2, 1::2] == coarse).all()


def test_stride_keeps_the_segmentation(view):
    depth, which, _, _, _ = view
    pose = _look_at(np.array([0.0, 0.0, 1.2]), [2.0, 0.0, 0.4])
    geometry = _depth.frame_geometry(depth, INTRINSICS, _depth.DepthSegmentsConfig(stride=2))
    seg = _depth.to_frame(geometry.segments, 2, depth.shape)
    crate_id, share = _majority(seg, which == 2)
    floor_id, _ = _majority(seg, which == 0)
    assert share > 0.75 and crate_id != floor_id
    stats = _depth.segment_stats(geometry, pose)
    assert _depth.layout_segments(stats, 0.0, _depth.LayoutConfig())["floor"][floor_id]


def test_a_learned_mask_that_spills_is_refined_to_its_object(view):
    """onnx_panoptic's depth_refine: a mask grown over the floor and wall around the crate keeps the crate."""
    from types import SimpleNamespace

    from stratamap.core.map.vocabulary import Vocabulary
    from stratamap.plugins.segmenters.onnx_panoptic import ONNXPanopticSegmenter

    depth, which, _, _, _ = view
    pose = _look_at(np.array([0.0, 0.0, 1.2]), [2.0, 0.0, 0.4])
    vocab = Vocabulary.default()
    from scipy import ndimage

    spill = ndimage.binary_dilation(which == 2, iterations=20)
    cls = np.where(spill, vocab.id("box"), vocab.id("floor")).astype(np.uint16)
    ins = np.where(spill, 1, 0).astype(np.int32)
    frame = SimpleNamespace(depth=depth, pose=pose)
    stream = SimpleNamespace(intrinsics=INTRINSICS)
    ref_cls, ref_ins = ONNXPanopticSegmenter._refine(frame, stream, cls, ins, vocab, 0.0)
    crate, floor, wall = which == 2, which == 0, which == 1
    assert (ref_cls[crate] == vocab.id("box")).mean() > 0.9
    assert np.bincount(ref_ins[crate])[1:].max() > 0.9 * crate.sum()  # one instance holds the crate
    for surface, name in ((floor, "floor"), (wall, "wall")):
        spilt = spill & surface
        assert (ref_cls[spilt] == vocab.id("box")).mean() < 0.05, name  # the spill is gone...
        # ...and mostly named by the planes (the cut bands along the crate's edges stay unknown)
        assert (ref_cls[spilt] == vocab.id(name)).mean() > 0.6, name


def test_a_box_around_two_more_confident_boxes_of_its_class_is_dropped():
    """Real frames (TUM's two chairs at a desk): a weak "chair" box spans both chairs, each boxed more
    confidently. It frames a group, not a chair (it would take what lies between them: their bases);
    a weak box around one chair's back, mostly inside its box, is a duplicate; a box of another class
    around both, and a weak chair box holding one chair's box and empty floor, stay."""
    left = _depth.Region(class_id=5, score=0.69, box=(10, 250, 255, 480))
    right = _depth.Region(class_id=5, score=0.5, box=(376, 208, 528, 430))
    group = _depth.Region(class_id=5, score=0.44, box=(28, 215, 501, 474))
    back = _depth.Region(class_id=5, score=0.35, box=(20, 255, 200, 400))
    table = _depth.Region(class_id=16, score=0.4, box=(0, 200, 560, 470))
    wide = _depth.Region(class_id=5, score=0.3, box=(300, 200, 639, 479))
    kept = _depth.suppress_duplicates([group, back, right, left, table, wide])
    assert [r.score for r in kept] == [0.69, 0.5, 0.4, 0.3]
