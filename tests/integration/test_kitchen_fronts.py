"""configs/kitchen_planes.yaml on the real IAI apartment: the fronts plane_crf finds become links
on joints (a revolute joint about the estimated hinge side for each door, a prismatic joint for
each drawer) that PyBullet loads and drives to their limits."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from stratamap.core.config import load_pipeline
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from stratamap.core.simulation.kinematics import link_name
from tests.conftest import REPO, shared_data


@pytest.fixture(scope="module")
def kitchen_planes(tmp_path_factory):
    shared_data("iai_apartment", "urdf", "apartment.urdf")
    out = tmp_path_factory.mktemp("kitchen_planes") / "run"
    Pipeline(load_pipeline(REPO / "configs" / "kitchen_planes.yaml")).run(out)
    return out, LayeredMap.load(out / "map")


def test_every_front_found_is_a_joint_with_its_hinge_side(kitchen_planes):
    out, layered = kitchen_planes
    fronts = [inst for inst in layered.instances if inst.attributes.get("joint") in ("revolute", "prismatic")]
    assert sum(f.attributes["joint"] == "revolute" for f in fronts) >= 5
    assert sum(f.attributes["joint"] == "prismatic" for f in fronts) >= 5
    robot = ET.parse(out / "export" / "scene.urdf").getroot()
    joints = {j.find("child").get("link"): j for j in robot.findall("joint")}
    for front in fronts:
        joint = joints[link_name(front)]
        kind = front.attributes["joint"]
        assert joint.get("type") == kind
        if kind == "prismatic":
            continue
        side = front.attributes["hinge"]
        assert joint.get("name").endswith(f"_hinge_{side}")
        # The hinge line lies on the estimated side of the front's face.
        origin = np.array([float(v) for v in joint.find("origin").get("xyz").split()])
        local = (origin - front.box.center) @ front.box.pose[:3, :3]
        half = np.asarray(front.box.size) / 2
        expected = {"left": (0, -half[0]), "right": (0, half[0]), "bottom": (2, -half[2]), "top": (2, half[2])}[side]
        assert local[expected[0]] == pytest.approx(expected[1], abs=1e-6)
    for name in ("scene.xml", "scene.sdf"):
        assert (out / "export" / name).is_file()


def test_pybullet_drives_each_front_to_its_limit(kitchen_planes):
    pybullet = pytest.importorskip("pybullet")
    out, layered = kitchen_planes
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(out / "export" / "scene.urdf"), useFixedBase=True, physicsClientId=client)
        pybullet.setGravity(0, 0, -9.81, physicsClientId=client)
        moving = {}
        for k in range(pybullet.getNumJoints(body, physicsClientId=client)):
            info = pybullet.getJointInfo(body, k, physicsClientId=client)
            if info[2] in (pybullet.JOINT_REVOLUTE, pybullet.JOINT_PRISMATIC):
                assert info[9] > info[8]  # a real range
                moving[k] = info[9]
                pybullet.setJointMotorControl2(
                    body, k, pybullet.POSITION_CONTROL, targetPosition=info[9], force=200, physicsClientId=client
                )
        fronts = [inst for inst in layered.instances if inst.attributes.get("joint") in ("revolute", "prismatic")]
        assert len(moving) == len(fronts)
        for _ in range(720):
            pybullet.stepSimulation(physicsClientId=client)
        for k, limit in moving.items():
            reached = pybullet.getJointState(body, k, physicsClientId=client)[0]
            assert reached == pytest.approx(limit, abs=0.02), pybullet.getJointInfo(body, k, physicsClientId=client)[1]
    finally:
        pybullet.disconnect(client)
