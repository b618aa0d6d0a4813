"""The demo pipeline with the learned completer ``pcn`` in place of ``bbox``: it runs end to end and
the URDF it exports loads in pybullet with every completed object."""

from __future__ import annotations

import json

import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO

SMALL = ["source.params.frames=16", "source.params.scene.camera={width: 320, height: 240}"]


def test_demo_with_pcn_exports_a_urdf_that_loads(tmp_path):
    pybullet = pytest.importorskip("pybullet")
    stages = yaml.safe_load((REPO / "configs" / "demo.yaml").read_text())["stages"]
    index = [s["plugin"] for s in stages].index("bbox")  # the demo's completer
    pipeline = load_pipeline(REPO / "configs" / "demo.yaml", [*SMALL, f"stages[{index}].plugin=pcn"])
    Pipeline(pipeline).run(tmp_path)
    report = json.loads((tmp_path / "report.json").read_text())
    assert [s["plugin"] for s in report["stages"]].count("pcn") == 1
    notes = report["notes"]["pcn"]
    assert notes["objects"]["completed"] == notes["objects"]["attempted"] >= 4
    assert notes["seconds_per_object"] > 0
    urdf = tmp_path / "export" / "scene.urdf"
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf), physicsClientId=client)
        assert pybullet.getNumJoints(body, physicsClientId=client) >= notes["objects"]["completed"]
    finally:
        pybullet.disconnect(client)
