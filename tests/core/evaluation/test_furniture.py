"""The furniture family: one-to-one matching at furniture scale, class-aware recall, and the share
of the map one instance takes (a room collapsed into one object is caught)."""

from __future__ import annotations

import numpy as np
import trimesh

from stratamap.core.evaluation.furniture import at_furniture_scale, evaluate_furniture
from stratamap.core.geometry.boxes import OrientedBox
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import Completion, Joint, ObjectInstance, ObjectInstances, Part, Semantics


def truth(oid: int, cls: str, center, size, yaw: float = 0.0) -> GroundTruthObject:
    c = np.asarray(center, float)
    return GroundTruthObject(oid, cls, trimesh.creation.box(extents=size), make_pose(c, yaw))


def predicted(iid: int, cls: str, center, size, yaw: float = 0.0, n: int = 100) -> ObjectInstance:
    box = OrientedBox(np.asarray(center, float), yaw, np.asarray(size, float))
    pts = np.random.default_rng(iid).uniform(-0.5, 0.5, (n, 3)) * box.size + box.center
    return ObjectInstance(iid, cls, pts, box)


ROOM = [
    truth(1, "table", [0.0, 0.0, 0.375], [1.6, 0.9, 0.75]),
    truth(2, "chair", [1.2, 0.0, 0.45], [0.5, 0.5, 0.9]),
    truth(3, "cabinet", [3.0, 2.0, 0.45], [1.0, 0.5, 0.9]),
    truth(4, "cup", [0.0, 0.0, 0.8], [0.08, 0.08, 0.1]),  # not furniture: never scored
]


def test_every_piece_found_and_named_scores_one():
    found = ObjectInstances(
        [
            predicted(10, "table", [0.02, 0.0, 0.37], [1.55, 0.92, 0.74]),
            predicted(11, "chair", [1.2, 0.05, 0.45], [0.5, 0.45, 0.9]),
            predicted(12, "cabinet", [3.0, 2.0, 0.45], [0.95, 0.5, 0.9]),
            predicted(13, "cup", [0.0, 0.0, 0.8], [0.08, 0.08, 0.1]),
        ]
    )
    res = evaluate_furniture(found, ROOM)
    assert (res["ground_truth"], res["predicted"], res["matched"]) == (3, 3, 3)
    assert res["recall"] == res["precision"] == res["recall_class_aware"] == 1.0


def test_a_blob_over_the_room_counts_against_precision_and_takes_the_map():
    blob = predicted(20, "object", [1.5, 1.0, 0.45], [4.5, 3.0, 0.9], n=900)
    chair = predicted(21, "chair", [1.2, 0.0, 0.45], [0.5, 0.5, 0.9], n=100)
    inst = ObjectInstances([blob, chair])
    ids = np.r_[np.full(900, 20), np.full(100, 21), np.zeros(1000, int)]
    sem = Semantics(np.zeros(len(ids), int), ids)
    res = evaluate_furniture(inst, ROOM, sem, len(ids))
    assert res["predicted"] == 2  # the unnamed blob is furniture-sized
    assert res["matched"] == 1 and res["precision"] == 0.5 and abs(res["recall"] - 1 / 3) < 1e-9
    assert res["largest_instance"] == "instance 20" and abs(res["largest_share"] - 0.45) < 1e-9


def test_matching_is_one_to_one_and_needs_iou():
    two_on_one = ObjectInstances(
        [
            predicted(30, "table", [0.0, 0.0, 0.375], [1.6, 0.9, 0.75]),
            predicted(31, "table", [0.05, 0.0, 0.375], [1.5, 0.9, 0.75]),
            predicted(32, "cabinet", [3.7, 2.0, 0.45], [1.0, 0.5, 0.9]),  # 0.7 m off: IoU 0.18, a miss
        ]
    )
    res = evaluate_furniture(two_on_one, ROOM)
    assert res["matched"] == 1 and res["predicted"] == 3
    assert res["by_class"]["cabinet"]["found"] == 0


def test_wrong_names_count_for_the_agnostic_figures_only():
    res = evaluate_furniture(ObjectInstances([predicted(40, "shelf", [3.0, 2.0, 0.45], [1.0, 0.5, 0.9])]), ROOM)
    assert res["matched"] == 1 and res["recall_class_aware"] == 0.0


def test_small_unnamed_things_are_not_furniture():
    box = OrientedBox(np.zeros(3), 0.0, np.array([0.3, 0.2, 0.2]))
    assert not at_furniture_scale("object", box)
    assert at_furniture_scale("object", OrientedBox(np.zeros(3), 0.0, np.array([0.6, 0.3, 0.5])))
    assert at_furniture_scale("chair", box)


def test_the_refined_box_of_a_table_whose_legs_are_hidden_is_scored():
    top_only = predicted(50, "table", [0.0, 0.0, 0.69], [1.6, 0.9, 0.12])  # the chairs hide its legs
    inst = ObjectInstances([top_only])
    assert evaluate_furniture(inst, ROOM)["matched"] == 0
    refined = OrientedBox(np.array([0.0, 0.0, 0.375]), 0.0, np.array([1.6, 0.9, 0.75]))
    assert evaluate_furniture(inst, ROOM, boxes={50: refined})["matched"] == 1


def _with_drawer(iid: int, cls: str, center, size) -> ObjectInstance:
    """An instance whose completion is a body with one drawer on a slide, its front on the -y side."""
    inst = predicted(iid, cls, center, size)
    size = np.asarray(size, float)
    pose = make_pose(np.asarray(center, float) - [0, 0, size[2] / 2], 0.0)
    body = trimesh.creation.box(size, make_pose((0.0, 0.0, size[2] / 2)))
    front = make_pose((0.0, -size[1] / 2, size[2] * 0.75))
    drawer = trimesh.creation.box((size[0] * 0.8, 0.02, size[2] * 0.3))
    inst.completion = Completion(
        body,
        pose,
        "test",
        parts=[Part("body", body), Part("drawer", drawer, front)],
        joints=[Joint("slide", "prismatic", "body", "drawer", front, np.array([0.0, -1.0, 0.0]), 0.0, 0.3)],
    )
    return inst


def test_joints_on_labelled_storage_and_elsewhere_are_counted_apart():
    on_cabinet = _with_drawer(30, "cabinet", [3.0, 2.0, 0.45], [1.0, 0.5, 0.9])
    on_the_table = _with_drawer(31, "object", [0.0, 0.0, 0.9], [0.4, 0.1, 0.3])  # a rack on the table
    res = evaluate_furniture(ObjectInstances([on_cabinet, on_the_table]), ROOM)
    assert (res["joints_on_storage"], res["joints_elsewhere"]) == (1, 1)
    assert (
        evaluate_furniture(ObjectInstances([predicted(32, "cabinet", [3, 2, 0.45], [1, 0.5, 0.9])]), ROOM)[
            "joints_on_storage"
        ]
        == 0
    )
