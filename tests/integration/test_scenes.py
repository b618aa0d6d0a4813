"""The shipped full pipelines (configs/office.yaml, configs/kitchen.yaml) and what robot software
makes of their exports: yourdfpy and PyBullet read the URDF, MuJoCo simulates the MJCF; and the
contact graph against the ground truth over several seeds."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.evaluation.graph import evaluate_graph
from stratamap.core.io.nav2 import read_map
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO

EXPORTS = [
    "scene.urdf", "scene.xml", "scene.sdf", "scene.glb", "map.yaml", "map.pgm", "multimap.yaml", "multimap.pgm",
    "costmap.yaml", "costmap.pgm", "scene_graph.json",
]  # fmt: skip


def half_resolution(kind: str) -> dict:
    """The scene spec of configs/scenes/KIND.yaml with 320x240 images (keeps the suite short)."""
    scene = yaml.safe_load((REPO / "configs" / "scenes" / f"{kind}.yaml").read_text())
    scene["camera"] = {**scene.get("camera", {}), "width": 320, "height": 240}
    return scene


@pytest.fixture(scope="module", params=["office", "kitchen"])
def scene_run(request, tmp_path_factory):
    """configs/KIND.yaml as shipped, but for half-resolution images."""
    out = tmp_path_factory.mktemp(request.param)
    config = yaml.safe_load((REPO / "configs" / f"{request.param}.yaml").read_text())
    config["source"]["params"] = {
        "scene": half_resolution(request.param),
        "frames": config["source"]["params"]["frames"],
    }
    path = out / "pipeline.yaml"
    path.write_text(yaml.safe_dump(config))
    out = out / "run"  # a run's output folder holds nothing but the run
    report = Pipeline(load_pipeline(path)).run(out)
    return request.param, out, report


def test_full_pipeline_writes_every_export(scene_run):
    _, out, report = scene_run
    for name in EXPORTS:
        assert (out / "export" / name).is_file(), name
    assert any((out / "export" / "meshes").iterdir())
    laser, multimap = read_map(out / "export" / "map.yaml"), read_map(out / "export" / "multimap.yaml")
    assert laser.data.shape == multimap.data.shape and (multimap.data == 100).sum() > (laser.data == 100).sum()
    # A completion that contradicts the observed points is rejected and reported, by design; any
    # other warning is a fault.
    unexpected = [w for w in report["warnings"] if "completion rejected, kept as observed" not in w]
    assert not unexpected, unexpected


def test_urdf_is_a_tree_that_pybullet_loads_with_its_joints(scene_run):
    yourdfpy = pytest.importorskip("yourdfpy")
    pybullet = pytest.importorskip("pybullet")
    kind, out, _ = scene_run
    path = out / "export" / "scene.urdf"
    robot = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=True)
    assert robot.validate()
    graph = nx.DiGraph([(j.parent, j.child) for j in robot.robot.joints])
    assert nx.is_arborescence(graph)
    declared = {j.type for j in robot.robot.joints}
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
        types = [
            pybullet.getJointInfo(body, k, physicsClientId=client)[2]
            for k in range(pybullet.getNumJoints(body, physicsClientId=client))
        ]
    finally:
        pybullet.disconnect(client)
    loaded = {pybullet.JOINT_REVOLUTE: "revolute", pybullet.JOINT_PRISMATIC: "prismatic"}
    assert {loaded[t] for t in types if t in loaded} == declared & {"revolute", "prismatic"}
    if kind == "kitchen":  # doors, oven, fridge and drawers
        assert {"revolute", "prismatic"} <= declared


def test_mujoco_scene_rests_under_gravity(scene_run):
    mujoco = pytest.importorskip("mujoco")
    from stratamap.core.simulation.physics import settle

    _, out, report = scene_run
    path = out / "export" / "scene.xml"
    model = mujoco.MjModel.from_xml_path(str(path))
    free = {
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.jnt_bodyid[j]))
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
    }
    top_level = {
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
        for b in range(1, model.nbody)
        if model.body_parentid[b] == 0
    }
    movable = ("chair", "cup", "book", "bottle", "box")
    static = ("table", "desk", "cabinet", "shelf", "counter", "fridge", "oven", "sofa")
    # Free bodies the rest plan could not start at rest stay static, with the reason in the report.
    held = set(report["notes"]["mjcf"]["rest"]["static"])
    assert free == {b for b in top_level if b.rsplit("_", 1)[0] in movable and b.rsplit("_", 1)[1] not in held}
    assert not any(b.rsplit("_", 1)[0] in static for b in free)
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] == len(free) > 0
    assert result["max_displacement_m"] < 0.02, sorted(result["displacement_m"].items(), key=lambda kv: -kv[1])[:3]


def _graph_edit_distance(config: Path, seed: int, out: Path) -> float:
    """The graph family of the run's metrics, alone: the run's other families (completion, panoptic
    quality) would cost each seed a third more and are not looked at here."""
    pipeline = Pipeline(load_pipeline(config, [f"source.params.seed={seed}"]))
    pipeline.run(out)
    data = pipeline.data
    gt = data.ground_truth
    return evaluate_graph(data.map.contact_graph, data.map.instances, gt.contact_graph, gt.objects)["ged"]


def test_contact_graph_matches_ground_truth_on_most_seeds(tmp_path):
    """Graph edit distance 0 on at least 4 of 5 kitchens (oracle labels; missed or split objects count).

    Half-resolution images and 60 frames a walk keep this test short (all five kitchens reach 0 with
    60 frames as with 120); ``benchmarks/contact_graph_seeds.py`` runs offices and kitchens at full
    resolution."""
    kind = "kitchen"
    scene = half_resolution(kind)
    config = tmp_path / "graph.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "source": {"plugin": "synthetic", "params": {"scene": scene, "frames": 60}},
                "stages": [
                    {"plugin": "oracle"},
                    {"plugin": "tsdf", "params": {"voxel_size": 0.02}},
                    {"plugin": "contact_graph"},
                ],
                # The graph is scored below, from the run's map; no report, no files to write.
                "output": {"save_map": False, "report": False, "metrics": False},
            }
        )
    )
    # The five seeds are independent runs: two processes, one per core.
    with ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn")) as pool:
        geds = list(pool.map(_graph_edit_distance, [config] * 5, range(5), [tmp_path / f"s{k}" for k in range(5)]))
    assert sum(g == 0 for g in geds) >= 4, geds
    assert np.mean(geds) <= 1.0, geds
