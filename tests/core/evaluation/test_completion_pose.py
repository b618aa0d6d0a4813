"""Pose errors of completions: the yaw error is symmetry-aware, as in Scan2CAD's evaluation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stratamap.core.evaluation.completion import evaluate_completion, symmetric_yaw_error_deg, yaw_symmetry
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.groundtruth import GroundTruthObject
from stratamap.core.map.layers import Completion, ObjectInstance, ObjectInstances
from stratamap.core.synthetic.models import make_model


def pose(yaw_deg: float, xy=(2.0, 1.0)) -> np.ndarray:
    return make_pose([xy[0], xy[1], 0.0], np.radians(yaw_deg))


def placed(family: str, gt_yaw: float, pred_yaw: float, index: int = 0) -> dict:
    """The model of ``family`` as ground truth at ``gt_yaw``, completed by the very same model at ``pred_yaw``."""
    model = make_model(family, 7, index)
    mesh = model.mesh()
    gt = GroundTruthObject(1, model.class_name, mesh, pose(gt_yaw), model_id=model.id, family=family)
    completion = Completion(mesh.copy(), pose(pred_yaw), "test", model_id=model.id)
    points = trimesh.sample.sample_surface(gt.world_mesh(), 500, seed=0)[0]
    inst = ObjectInstance(3, model.class_name, points, gt.box(), completion=completion)
    res = evaluate_completion(ObjectInstances([inst]), [gt])
    assert res["objects"] == 1
    return res


def test_symmetry_comes_from_the_ground_truth_geometry():
    assert yaw_symmetry(make_model("rectangular_table", 7).mesh()) == "180"
    assert yaw_symmetry(make_model("box", 7).mesh()) == "180"
    assert yaw_symmetry(make_model("round_table", 7).mesh()) == "round"
    assert yaw_symmetry(make_model("bottle", 7).mesh()) == "round"
    square_table = trimesh.util.concatenate(
        [trimesh.creation.box((1.0, 1.0, 0.04), make_pose([0, 0, 0.73]))]
        + [
            trimesh.creation.box((0.05, 0.05, 0.71), make_pose([sx * 0.45, sy * 0.45, 0.355]))
            for sx in (-1, 1)
            for sy in (-1, 1)
        ]
    )
    assert yaw_symmetry(square_table) == "90"
    # Fronts, backrests and handles orient a shape: no symmetry (a cup's handle included).
    for family in ("four_leg_chair", "desk", "cabinet", "fridge", "sofa", "cup"):
        assert yaw_symmetry(make_model(family, 7).mesh()) == "none", family
    # Off-centre mesh frames: the axis goes through the box centre, not the mesh origin.
    shifted = make_model("rectangular_table", 7).mesh()
    shifted.apply_translation((0.7, -0.3, 0.0))
    assert yaw_symmetry(shifted) == "180"


def test_symmetric_yaw_error_by_hand():
    a = np.radians(10.0)
    assert symmetric_yaw_error_deg(a + np.pi, a, "none") == pytest.approx(180.0)
    assert symmetric_yaw_error_deg(a + np.pi, a, "180") == pytest.approx(0.0, abs=1e-9)
    assert symmetric_yaw_error_deg(a + np.radians(170), a, "180") == pytest.approx(10.0)
    assert symmetric_yaw_error_deg(a + np.radians(95), a, "90") == pytest.approx(5.0)
    assert symmetric_yaw_error_deg(a - np.radians(95), a, "90") == pytest.approx(5.0)
    assert symmetric_yaw_error_deg(a + np.radians(95), a, "180") == pytest.approx(85.0)
    assert symmetric_yaw_error_deg(a + 1.234, a, "round") == 0.0


def test_correctly_placed_rectangular_table_turned_half_way_has_no_yaw_error():
    # The same table turned by 180 deg occupies exactly the same space: it is correctly placed.
    res = placed("rectangular_table", 30.0, 210.0)
    obj = res["per_object"][0]
    assert obj["yaw_symmetry"] == "180"
    assert obj["yaw_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert obj["scan2cad"] is True and res["scan2cad_accuracy"] == 1.0
    # A real yaw error is still measured, modulo the symmetry.
    assert placed("rectangular_table", 30.0, 195.0)["per_object"][0]["yaw_error_deg"] == pytest.approx(15.0)
    assert placed("rectangular_table", 30.0, 120.0)["yaw_error_deg"] == pytest.approx(90.0)
    # Round tables: any yaw is right.
    assert placed("round_table", 30.0, 107.0)["yaw_error_deg"] == pytest.approx(0.0)


def test_asymmetric_objects_keep_the_plain_yaw_error():
    res = placed("four_leg_chair", 30.0, 210.0)
    obj = res["per_object"][0]
    assert obj["yaw_symmetry"] == "none"
    assert obj["yaw_error_deg"] == pytest.approx(180.0)
    assert obj["scan2cad"] is False
