"""clusters' pass ``cut_below_supports``: what stands on a worktop ends at the worktop (a glossy
worktop mirrors it, and the depth camera measures the image under the surface)."""

from __future__ import annotations

import numpy as np

from stratamap.plugins.segmenters.clusters.config import DEFAULT_PASSES
from tests.plugins.segmenters.test_clusters_recognition import in_room, recognized
from tests.plugins.segmenters.test_layout_planes import box_surface, chair, solids, table

WORKTOP = 0.9


def counter_with_a_mirrored_box(spacing: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """A counter along the x=0 wall (0.6 deep, 0.9 high) and a 0.35 m box standing on its worktop
    against the wall, with the box's mirror image under the worktop (its front face reflected in
    the surface, down to 0.2 m below it), as the depth of a glossy worktop gives it."""
    parts = [
        ("counter", (0.02, 1.0, 0.0), (0.62, 2.6, WORKTOP)),
        ("box", (0.05, 1.6, WORKTOP), (0.35, 2.0, WORKTOP + 0.35)),
    ]
    objects, names = solids(parts, spacing)
    keep = (objects[:, 2] > 1e-6) & ~((names == "counter") & (objects[:, 0] < 0.03))
    front = box_surface((0.35, 1.6, WORKTOP), (0.35, 2.0, WORKTOP + 0.2), spacing, "X")
    image = front * [1.0, 1.0, -1.0] + [0.0, 0.0, 2 * WORKTOP]  # reflected in the worktop's plane
    image = image[image[:, 2] < WORKTOP - 0.04]
    points = np.concatenate([objects[keep], image])
    labels = np.concatenate([names[keep], np.full(len(image), "image")])
    return points, labels


def test_a_box_on_a_glossy_worktop_loses_its_mirror_image():
    """The frames' masks took the box with its image under the worktop: the box ends at the
    worktop, and the image is in no instance."""
    objects, names = counter_with_a_mirrored_box()
    points, names = in_room((objects, names))
    out = recognized(points, names, [(names == "counter", "counter"), ((names == "box") | (names == "image"), "box")])
    sem = out["semantics"]
    box_id = int(np.bincount(sem.instance_ids[names == "box"]).argmax())
    assert box_id > 0
    assert (sem.instance_ids[names == "image"] != box_id).all()
    box = next(inst for inst in out["instances"] if inst.id == box_id)
    assert box.box.bottom_z >= WORKTOP - 0.05


def test_without_the_pass_the_image_stays_in_the_box():
    """The same map with every default pass but ``cut_below_supports``: the box reaches 0.2 m
    through the worktop (what the pass is for)."""
    objects, names = counter_with_a_mirrored_box()
    points, names = in_room((objects, names))
    passes = [p for p in DEFAULT_PASSES if p != "cut_below_supports"]
    masks = [(names == "counter", "counter"), ((names == "box") | (names == "image"), "box")]
    out = recognized(points, names, masks, passes=passes)
    sem = out["semantics"]
    box_id = int(np.bincount(sem.instance_ids[names == "box"]).argmax())
    assert (sem.instance_ids[names == "image"] == box_id).mean() > 0.5


def test_a_chair_pushed_in_under_a_table_keeps_its_legs():
    """A chair pushed in under a table's top: its back rises over the top, but most of it lies below
    the top, so it does not stand on it and nothing of it is cut."""
    objects, names = solids(table(3.0, 2.5) + chair(3.0, 2.8), 0.02)
    keep = objects[:, 2] > 1e-6
    points, names = in_room((objects[keep], names[keep]))
    out = recognized(points, names, [(names == "table", "table"), (names == "chair", "chair")])
    sem = out["semantics"]
    chair_id = int(np.bincount(sem.instance_ids[names == "chair"]).argmax())
    assert chair_id > 0
    assert (sem.instance_ids[names == "chair"] == chair_id).mean() > 0.95
