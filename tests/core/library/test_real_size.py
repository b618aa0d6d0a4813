"""Models at their real size from any library source, and PartNet-Mobility articulation kept whole
through matching and export (helper links included)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import trimesh

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.library.models import ModelLibrary
from stratamap.core.map.layers import ObjectInstance, ObjectInstances
from stratamap.core.map.priors import TYPICAL_HEIGHTS, plausible_heights
from stratamap.core.stages import PipelineData
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from tests.conftest import shared_data


def _box_mesh_folder(tmp_path, height_units: float, scale: str | None = None):
    mesh = trimesh.creation.box(extents=[0.5 * height_units, 0.5 * height_units, height_units])
    mesh.export(tmp_path / "chair.stl")
    with open(tmp_path / "classes.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["file", "class"] + (["scale"] if scale is not None else []))
        writer.writerow(["chair.stl", "chair"] + ([scale] if scale is not None else []))
    return ModelLibrary.load(tmp_path)


def test_mesh_folder_in_millimetres_is_read_in_metres(tmp_path):
    library = _box_mesh_folder(tmp_path, 950.0)
    (model,) = library.models
    assert model.size[2] == pytest.approx(0.95)
    assert "mm" in model.params["units"] and library.problems


def test_mesh_folder_scale_column_wins(tmp_path):
    library = _box_mesh_folder(tmp_path, 40.0, scale="0.025")
    assert library.models[0].size[2] == pytest.approx(1.0)
    assert not library.problems


def test_mesh_folder_with_no_plausible_unit_gets_the_class_height(tmp_path):
    (model,) = _box_mesh_folder(tmp_path, 7.0).models
    low, high = TYPICAL_HEIGHTS["chair"]
    assert model.size[2] == pytest.approx((low + high) / 2)


def test_plausible_heights_widen_the_typical_range():
    low, high = plausible_heights("chair")
    assert low < TYPICAL_HEIGHTS["chair"][0] and high > TYPICAL_HEIGHTS["chair"][1]
    assert plausible_heights("no such class") is None


@pytest.fixture(scope="module")
def partnet_library():
    return ModelLibrary.load(shared_data("partnet_mobility"))


@pytest.mark.slow
def test_partnet_models_load_at_their_class_height(partnet_library):
    for model in partnet_library:
        low, high = TYPICAL_HEIGHTS[model.class_name]
        assert low <= model.size[2] <= high, (model.id, model.size)
    chair = partnet_library.get("partnet_179")
    assert 1.5 < 1 / chair.params["scale_to_metres"] * chair.size[2] < 1.7  # shipped 1.61 units tall


def observed_chair(partnet_library, height: float) -> tuple[ObjectInstance, trimesh.Trimesh]:
    """The PartNet chair at ``height``, seen from one side (front and left), turned and placed."""
    chair = partnet_library.get("partnet_179")
    mesh = chair.mesh()
    mesh.apply_scale(height / chair.size[2])
    yaw = 0.6
    pose = np.eye(4)
    pose[:3, :3] = trimesh.transformations.rotation_matrix(yaw, [0, 0, 1])[:3, :3]
    pose[:3, 3] = (2.0, 1.5, 0.0)
    mesh.apply_transform(pose)
    points, faces = trimesh.sample.sample_surface(mesh, 6000, seed=0)
    view = np.array([np.cos(yaw + 2.2), np.sin(yaw + 2.2), 0.3])
    seen = mesh.face_normals[faces] @ view > 0.1
    pts = points[seen]
    return ObjectInstance(1, "chair", pts, gravity_aligned_box(pts)), mesh


@pytest.mark.slow
def test_a_true_height_chair_is_completed_at_its_height_and_exports(partnet_library, tmp_path):
    from stratamap.plugins.completers._matching import register_library

    name = register_library("partnet-real-size", partnet_library)
    inst, truth = observed_chair(partnet_library, 1.0)
    data = PipelineData()
    data.map.instances = ObjectInstances([inst])
    completer = ICPMatchCompleter(library=name)
    out = completer.run(data)
    completion = out["instances"][1].completion
    assert completion is not None and completion.model_id == "partnet_179"
    height = float(completion.world_mesh().bounds[1, 2] - completion.world_mesh().bounds[0, 2])
    assert height == pytest.approx(1.0, rel=0.05)
    assert out["instances"][1].attributes["match"]["scale"] == pytest.approx(list(completion.scale), abs=1e-3)
    # Every link and joint of the PartNet chair survives, the geometry-less helper link included.
    assert {j.name for j in completion.joints} >= {"joint_15", "joint_17"}
    data.map.instances = out["instances"]

    pybullet = pytest.importorskip("pybullet")
    mujoco = pytest.importorskip("mujoco")
    from stratamap.core.simulation.bullet import load_scene
    from stratamap.core.simulation.physics import settle
    from stratamap.plugins.exporters.mjcf import MJCFExporter
    from stratamap.plugins.exporters.urdf import URDFExporter

    urdf = URDFExporter().run(data, tmp_path / "urdf")[0]
    text = urdf.read_text()
    assert 'link name="chair_1__link_15_helper"' in text and "joint_17" in text
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), useFixedBase=True, physicsClientId=client)
        assert pybullet.getNumJoints(body, physicsClientId=client) > 18
    finally:
        pybullet.disconnect(client)
    scene = load_scene(urdf)
    try:
        assert set(scene.free) == {"chair_1"}
    finally:
        pybullet.disconnect(scene.client)
    mjcf = MJCFExporter().run(data, tmp_path / "mjcf")[0]
    model = mujoco.MjModel.from_xml_path(str(mjcf))
    free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert len(free) == 1 and model.njnt == 18  # the free joint and the chair's 17 moving joints
    assert settle(mjcf, seconds=2.0)["max_displacement_m"] < 0.02
