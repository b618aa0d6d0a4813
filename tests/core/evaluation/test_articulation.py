"""The articulation family (core/evaluation/articulation.py): joint matching on hand-made joints,
true joints' world frames on a small model with a known hinge, predicted joints from an articulated
completion, and the opening check on tiny MJCF scenes written by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from stratamap.core.evaluation.articulation import (
    WorldJoint,
    evaluate_articulation,
    match_joints,
    opening_check,
    predicted_joints,
    score_joints,
    true_joints,
)
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.groundtruth import GroundTruth, GroundTruthObject
from stratamap.core.map.layers import Completion, Joint, ObjectInstance, ObjectInstances, OrientedBox, Part


def door(pivot=(0.0, 0.0, 0.5), axis=(0, 0, -1), width=0.5, height=0.7) -> WorldJoint:
    """A door in the x-z plane hinged on its left edge at ``pivot``: its panel spans +x from the hinge."""
    pivot = np.asarray(pivot, float)
    center = pivot + [width / 2, -0.01, 0.0]
    return WorldJoint(
        "door", "revolute", np.asarray(axis, float) / np.linalg.norm(axis), pivot, 0.0, 1.6, 1,
        center, np.eye(3), np.array([width, 0.02, height]),
    )  # fmt: skip


def drawer(z: float, height: float = 0.18, name: str = "drawer") -> WorldJoint:
    """A drawer 0.5 wide and 0.4 deep whose front (facing -y) is centred at x = 0 and height ``z``."""
    center = np.array([0.0, 0.2, z])
    return WorldJoint(
        name, "prismatic", np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, z]), 0.0, 0.35, 1,
        center, np.eye(3), np.array([0.5, 0.4, height]),
    )  # fmt: skip


def moved(j: WorldJoint, **changes) -> WorldJoint:
    out = WorldJoint(**{**j.__dict__})
    for key, value in changes.items():
        setattr(out, key, np.asarray(value, float) if key != "type" else value)
    return out


# ------------------------------------------------------------------------------------ matching


def test_exact_joints_match_with_f1_one():
    truth = [door(), drawer(0.2), drawer(0.4)]
    result = score_joints(truth, [moved(j) for j in truth])
    assert result["f1"] == pytest.approx(1.0)
    assert (result["true_joints"], result["predicted_joints"], result["matched_joints"]) == (3, 3, 3)
    assert result["by_type"]["revolute"]["matched_joints"] == 1
    assert result["by_type"]["prismatic"]["matched_joints"] == 2
    assert result["axis_error_deg_median"] == pytest.approx(0.0)
    assert result["pivot_error_m_median"] == pytest.approx(0.0)
    assert len(result["per_joint"]) == 3 and all(row["match"] is not None for row in result["per_joint"])


def test_the_axis_sign_does_not_matter_but_20_degrees_do():
    truth = door()
    flipped = moved(truth, axis=[0, 0, 1])
    assert len(match_joints([truth], [flipped])) == 1
    # ...but that door swings into its cabinet, and a drawer put in backwards slides into it.
    assert score_joints([truth], [flipped])["opens_same_way"] == 0
    assert score_joints([truth], [moved(truth)])["opens_same_way_share"] == pytest.approx(1.0)
    backwards = moved(drawer(0.2), axis=[0, 1, 0])
    result = score_joints([drawer(0.2)], [backwards])
    assert result["matched_joints"] == 1 and result["opens_same_way_share"] == 0.0
    tilted = moved(truth, axis=[np.sin(np.radians(20)), 0, -np.cos(np.radians(20))])
    assert match_joints([truth], [tilted]) == []
    slightly = moved(truth, axis=[np.sin(np.radians(5)), 0, -np.cos(np.radians(5))])
    (_, _, errors), *_ = match_joints([truth], [slightly])
    assert errors["axis_error_deg"] == pytest.approx(5.0)


def test_a_hinge_line_10_cm_off_does_not_match_4_cm_does():
    truth = door()
    # Moving the pivot along the axis changes nothing: it is the same line.
    along = moved(truth, pivot=truth.pivot + [0, 0, 0.3])
    assert len(match_joints([truth], [along])) == 1
    far = moved(truth, pivot=truth.pivot + [0.1, 0, 0])  # the hinge on the wrong side of a 10 cm stile
    assert match_joints([truth], [far]) == []
    near = moved(truth, pivot=truth.pivot + [0.0, -0.04, 0])
    result = score_joints([truth], [near])
    assert result["matched_joints"] == 1 and result["pivot_error_m_median"] == pytest.approx(0.04)


def test_a_drawer_cannot_match_the_drawer_below_it():
    upper, lower = drawer(0.4, name="upper"), drawer(0.2, name="lower")
    # The map has one drawer where the upper one is: it is not the lower drawer, whatever its axis.
    found = moved(upper)
    assert match_joints([lower], [found]) == []
    result = score_joints([upper, lower], [found])
    assert result["matched_joints"] == 1 and result["per_joint"][0]["match"] is not None
    # A slide with its part in the right place but a front 8 cm lower than the true one's centre
    # still lies on the 18 cm front.
    assert len(match_joints([lower], [moved(lower, part_center=lower.part_center + [0, 0, -0.08])])) == 1
    # Without the true part's size, centres within 0.25 m pass.
    unsized = moved(lower)
    unsized.part_axes = unsized.part_size = None
    assert len(match_joints([unsized], [moved(lower, part_center=lower.part_center + [0.2, 0, 0])])) == 1
    assert match_joints([unsized], [moved(lower, part_center=lower.part_center + [0.3, 0, 0])]) == []


def test_matching_is_one_to_one_and_by_type():
    truth = door()
    twice = [moved(truth), moved(truth, pivot=truth.pivot + [0, -0.02, 0])]
    result = score_joints([truth], twice)
    assert result["matched_joints"] == 1
    assert result["precision"] == pytest.approx(0.5) and result["recall"] == pytest.approx(1.0)
    # The exact one is taken (least error); the other is listed as an unmatched prediction.
    assert result["pivot_error_m_median"] == pytest.approx(0.0)
    assert result["per_joint"][-1]["truth"] is None
    slide = moved(truth, type="prismatic")
    assert match_joints([truth], [slide]) == []
    none = score_joints([truth], [])
    assert none["recall"] == 0.0 and none["f1"] == 0.0 and none["axis_error_deg_median"] is None


# ------------------------------------------------------------------------------------ world frames


def hinged_object(pose: np.ndarray) -> GroundTruthObject:
    """A 0.6 x 0.5 x 0.8 cabinet whose door (0.56 wide, 0.7 tall, its front at y = -0.25) hangs on a
    helper link: body -> slider (a fixed offset out of the front) -> door, hinged on its left edge
    about -z (opening outwards)."""
    body = trimesh.creation.box((0.6, 0.5, 0.8), make_pose((0, 0, 0.4)))
    slider = Joint("slide_out", "fixed", "body", "slider", make_pose((-0.28, -0.25, 0.0)), np.array([1.0, 0, 0]))
    hinge = Joint("hinge", "revolute", "slider", "door", make_pose((0.0, -0.02, 0.4)), np.array([0, 0, -1.0]), 0, 1.6)
    return GroundTruthObject(
        7, "cabinet", body, pose, joints=[slider, hinge],
        part_boxes={"door": [[-0.28, -0.27, 0.05], [0.28, -0.25, 0.75]]},
    )  # fmt: skip


def test_true_joint_world_frame_through_a_helper_link():
    pose = make_pose((2.0, 1.0, 0.0), np.pi / 2)  # turned to face +x
    (j,) = true_joints([hinged_object(pose)])
    # The hinge in the object frame: (-0.28, -0.27, 0.4); turned by 90 degrees: (0.27, -0.28), plus (2, 1).
    assert j.type == "revolute" and j.object_id == 7
    assert np.allclose(j.pivot, [2.27, 0.72, 0.4])
    assert np.allclose(j.axis, [0, 0, -1])
    assert np.allclose(j.part_center, [2.26, 1.0, 0.4])
    assert (j.lower, j.upper) == (0.0, 1.6)


def test_true_joints_of_a_generated_cabinet_and_their_part_boxes():
    """A generated model's door, placed by a pose: the hinge is on the door's edge, and the part box
    PlacedObject.to_ground_truth writes is the door panel with its handle."""
    from stratamap.core.synthetic.models import Builder, Model
    from stratamap.core.synthetic.scene import PlacedObject

    b = Builder(np.random.default_rng(0))
    b.box("carcass", (0.6, 0.5, 0.8), (0, 0, 0.4), (0.5, 0.5, 0.5))
    b.door("door", -0.3, 0.3, 0.05, 0.75, -0.25, 0.02, (0.8, 0.8, 0.8), hinge="left")
    model = Model("m", "cabinet", "cabinet", {}, b.parts, b.joints)
    pose = make_pose((1.0, 2.0, 0.0), np.pi)
    gt = PlacedObject(3, model, pose, "floor").to_ground_truth()
    lo, hi = np.asarray(gt.part_boxes["door"])
    assert lo[0] == pytest.approx(-0.298) and hi[0] == pytest.approx(0.298)  # the panel, 2 mm inside its opening
    assert lo[1] < -0.27 - 0.02  # the handle stands off the front
    (j,) = true_joints([gt])
    # Hinge at (-0.3, -0.27, 0.4) in the object frame; turned half a turn: (0.3, 0.27), plus (1, 2).
    assert np.allclose(j.pivot, [1.3, 2.27, 0.4])
    assert np.allclose(j.axis, [0, 0, -1])
    assert j.part_center[1] > 2.27  # the door (and its handle) in front of the turned cabinet, at +y


def test_predicted_joints_from_an_articulated_completion_match_the_truth():
    pose = make_pose((2.0, 1.0, 0.0), np.pi / 2)
    gt = hinged_object(pose)
    # The completion: the body in the object frame, the door in its link frame (the hinge's).
    door_frame = gt.joints[0].origin @ gt.joints[1].origin
    panel = trimesh.creation.box((0.56, 0.02, 0.7), make_pose((0.0, -0.26, 0.4)))
    panel.apply_transform(np.linalg.inv(door_frame))
    completion = Completion(
        gt.mesh, pose, "test", parts=[Part("body", gt.mesh), Part("door", panel, door_frame)], joints=list(gt.joints)
    )
    inst = ObjectInstance(
        7, "cabinet", np.zeros((1, 3)), OrientedBox(pose[:3, 3] + [0, 0, 0.4], np.pi / 2, [0.6, 0.5, 0.8])
    )
    inst.completion = completion
    (p,) = predicted_joints(ObjectInstances([inst]))
    (t,) = true_joints([gt])
    assert p.object_id == 7
    assert np.allclose(p.pivot, t.pivot) and np.allclose(p.axis, t.axis)
    assert np.allclose(p.part_center, t.part_center, atol=1e-6)
    assert evaluate_articulation(ObjectInstances([inst]), [gt])["f1"] == pytest.approx(1.0)
    # No map objects: recall 0, nothing predicted.
    empty = evaluate_articulation(None, [gt])
    assert empty["recall"] == 0.0 and empty["predicted_joints"] == 0


def test_evaluate_adds_the_family_only_for_articulated_ground_truth():
    from stratamap.core.evaluation.metrics import evaluate
    from stratamap.core.stages import PipelineData

    pose = make_pose((2.0, 1.0, 0.0))
    data = PipelineData(ground_truth=GroundTruth(objects=[hinged_object(pose)]))
    assert evaluate(data)["articulation"]["true_joints"] == 1
    plain = GroundTruthObject(1, "table", trimesh.creation.box((1, 1, 1)), pose)
    assert "articulation" not in evaluate(PipelineData(ground_truth=GroundTruth(objects=[plain])))


def test_part_boxes_are_read_back_and_optional(tmp_path):
    from stratamap.core.io.groundtruth import load_ground_truth

    (tmp_path / "meshes").mkdir()
    trimesh.creation.box((1, 1, 1)).export(tmp_path / "meshes" / "1.ply")
    record = {"id": 1, "class": "cabinet", "mesh": "meshes/1.ply", "pose": np.eye(4).tolist()}
    boxed = {**record, "id": 2, "part_boxes": {"door": [[0, 0, 0], [0.5, 0.02, 0.7]]}}
    (tmp_path / "scene.json").write_text(json.dumps({"objects": [record, boxed]}))
    old, new = load_ground_truth(tmp_path, []).objects
    assert old.part_boxes == {}
    assert new.part_boxes == {"door": [[0.0, 0.0, 0.0], [0.5, 0.02, 0.7]]}


# ------------------------------------------------------------------------------------ MuJoCo

DOOR_SCENE = """<mujoco>
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    {wall}
    <body name="cabinet" pos="0 0 0">
      <geom name="carcass" type="box" size="0.25 0.25 0.4" pos="0.25 0.25 0.4"/>
      <body name="door" pos="0 -0.005 0">
        <joint name="hinge" type="hinge" axis="0 0 -1" range="0 1.6"/>
        <geom name="panel" type="box" size="0.245 0.01 0.35" pos="0.25 -0.01 0.4" mass="1"/>
      </body>
      <body name="drawer" pos="0.7 0 0.6">
        <joint name="slide" type="slide" axis="0 -1 0" range="0 0.3"/>
        <geom name="drawer_front" type="box" size="0.1 0.01 0.05" pos="0 -0.01 0" mass="1"/>
      </body>
      <body name="lazy_susan" pos="0.7 0.3 0.2">
        <joint name="spin" type="hinge" axis="0 0 1"/>
        <geom type="cylinder" size="0.1 0.01" mass="1"/>
      </body>
    </body>
    <body name="box" pos="-1 1 0.1">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_opening_check_passes_a_free_door_and_fails_one_that_hits_a_wall(tmp_path):
    pytest.importorskip("mujoco")
    free = tmp_path / "free.xml"
    free.write_text(DOOR_SCENE.format(wall=""))
    result = opening_check(free, settle_seconds=0.2)
    assert (result["joints_checked"], result["opens_clean"], result["unlimited_joints"]) == (2, 2, 1)
    assert result["opens_clean_share"] == pytest.approx(1.0) and result["failures"] == []
    assert result["free_bodies"] == 1 and result["rest_max_displacement_m"] < 0.01
    # A wall 40 cm in front of the cabinet: the 50 cm door swings into it, the drawer (30 cm out) does not.
    walled = tmp_path / "walled.xml"
    walled.write_text(DOOR_SCENE.format(wall='<geom name="wall" type="box" size="0.3 0.05 1" pos="0.2 -0.45 1"/>'))
    result = opening_check(walled, settle_seconds=None)
    assert result["opens_clean"] == 1 and result["opens_clean_share"] == pytest.approx(0.5)
    (failure,) = result["failures"]
    assert failure["joint"] == "hinge" and failure["opened_to"] == pytest.approx(1.44)
    assert list(failure["hits"]) == ["wall"] and failure["hits"]["wall"] > 0.01
    assert "rest_max_displacement_m" not in result


def test_opening_check_counts_only_what_opening_causes(tmp_path):
    """A drawer front already touching a neighbour at rest (1.5 cm into it) opens cleanly: the
    contact gets no deeper as it slides out."""
    pytest.importorskip("mujoco")
    scene = tmp_path / "touching.xml"
    scene.write_text(DOOR_SCENE.format(wall='<geom name="trim" type="box" size="0.02 0.2 0.05" pos="0.805 -0.1 0.6"/>'))
    result = opening_check(scene, settle_seconds=None)
    assert result["opens_clean"] == 2, result["failures"]


def test_recall_on_large_fronts_counts_doors_and_drawers_by_their_front():
    from stratamap.core.evaluation.articulation import front_area

    assert front_area(door()) == pytest.approx(0.5 * 0.7)
    assert front_area(drawer(0.3, height=0.18)) == pytest.approx(0.5 * 0.18)  # across the slide
    truth = [door(), drawer(0.3, height=0.25, name="deep"), drawer(0.6, height=0.1, name="shallow")]
    scores = score_joints(truth, [door()])
    assert scores["large_joints"] == 2 and scores["recall_large"] == pytest.approx(0.5)


def test_the_real_cabinets_hand_labels_are_four_stacked_slides_out_of_its_front():
    """benchmarks/articulation/tum_fr3_cabinet: the real TUM cabinet's drawers as the scorer reads them,
    levelled as the tum source levels the recording: four slides along one axis, out of the face, their
    fronts stacked bottom to top without overlap, within the cabinet's box."""
    from stratamap.core.io.groundtruth import load_ground_truth
    from tests.conftest import REPO

    folder = REPO / "benchmarks" / "articulation" / "tum_fr3_cabinet"
    gt = load_ground_truth(folder, [], (480, 640))
    (cabinet,) = gt.objects
    joints = true_joints(gt.objects)
    assert [j.type for j in joints] == ["prismatic"] * 4
    axes = np.array([j.axis for j in joints])
    assert np.allclose(axes, axes[0], atol=1e-9) and abs(axes[0][2]) < 0.05
    box = cabinet.box()
    out_of_front = axes[0] @ (joints[0].pivot - box.center)
    assert out_of_front > 0.3 * box.size[:2].min()  # the pivots lie on the face the slides leave by
    bands = sorted((b[0][2], b[1][2]) for b in cabinet.part_boxes.values())
    assert all(lo < hi <= nxt + 1e-6 for (lo, hi), (nxt, _) in zip(bands, bands[1:], strict=False))
    assert bands[0][0] >= -1e-6 and bands[-1][1] <= box.size[2] + 1e-6


def _walk(eye, forward, depth_m: float, frames: int = 3):
    """A stream of ``frames`` identical frames from ``eye`` looking along ``forward`` (level), each
    measuring ``depth_m`` everywhere (a wall square to the view)."""
    from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame, SensorStream

    z_c = np.asarray(forward, float) / np.linalg.norm(forward)
    y_c = np.array([0.0, 0.0, -1.0])
    pose = np.eye(4)
    pose[:3, :3] = np.stack([np.cross(y_c, z_c), y_c, z_c], axis=1)
    pose[:3, 3] = eye
    intr = CameraIntrinsics(160, 120, 120.0, 120.0, 80.0, 60.0)
    depth = np.full((120, 160), depth_m, np.float32)
    rgb = np.zeros((120, 160, 3), np.uint8)
    return SensorStream("walk", intr, [RGBDFrame(k, float(k), rgb, depth, pose) for k in range(frames)])


def test_a_front_counts_as_seen_only_from_the_front_and_unoccluded():
    from stratamap.core.evaluation.front_visibility import seen_from_front

    truth = [drawer(0.5)]  # its front faces -y at y = 0
    assert seen_from_front(truth, _walk((0.0, -1.5, 0.5), (0, 1, 0), 1.5)) == [True]
    assert seen_from_front(truth, _walk((0.0, 1.5, 0.5), (0, -1, 0), 1.5)) == [False]  # from behind
    assert seen_from_front(truth, _walk((0.0, -1.5, 0.5), (0, 1, 0), 0.8)) == [False]  # something in between
    assert seen_from_front(truth, _walk((3.0, -0.3, 0.5), (-1, 0, 0), 3.0)) == [False]  # from the side, 80 degrees
    assert seen_from_front(truth, _walk((0.0, -1.5, 3.0), (0, 1, 0), 1.5)) == [False]  # out of the image
    assert seen_from_front(truth, None) is None
    unknown = moved(drawer(0.5))
    unknown.part_size = None
    assert seen_from_front([unknown], _walk((0.0, -1.5, 0.5), (0, 1, 0), 1.5)) == [None]


def test_recall_on_large_fronts_seen_counts_only_what_the_walk_saw():
    truth = [door(), drawer(0.3, height=0.25, name="deep")]
    scores = score_joints(truth, [door()], seen=[False, True])
    assert scores["large_joints"] == 2 and scores["recall_large"] == pytest.approx(0.5)
    assert scores["large_seen_joints"] == 1 and scores["recall_large_seen"] == pytest.approx(0.0)
    assert [row["seen_from_front"] for row in scores["per_joint"] if row["truth"]] == [False, True]
    assert "recall_large_seen" not in score_joints(truth, [door()])
