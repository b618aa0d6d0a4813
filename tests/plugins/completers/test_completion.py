"""Completers against ground truth: model matching beats boxes; robustness; articulation; augmented scene."""

from __future__ import annotations

import copy

import numpy as np
import open3d as o3d
import open3d.core as o3c
import pytest
import trimesh

from stratamap.core.evaluation.completion import evaluate_completion, shape_distances
from stratamap.core.library.index import ModelIndex
from stratamap.core.library.models import ModelLibrary, model_to_library
from stratamap.core.map.layers import LayeredMap, ObjectInstance, ObjectInstances, OrientedBox
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.models import make_model
from stratamap.plugins.completers._matching import register_library
from stratamap.plugins.completers.bbox import BBoxCompleter
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from stratamap.plugins.completers.plane_box_match import ORIENTATIONS, PlaneBoxMatchCompleter
from stratamap.plugins.mappers.contact_graph import ContactGraphMapper
from stratamap.plugins.mappers.tsdf import TSDFMapper
from stratamap.plugins.segmenters.oracle import OracleSegmenter


@pytest.fixture(scope="module")
def mapped():
    spec = SceneSpec.model_validate(
        {"type": "office", "seed": 11, "camera": {"width": 320, "height": 240}, "trajectory": {"frames": 60}}
    )
    world = SyntheticWorld(spec)
    data = PipelineData(stream=world.stream(), ground_truth=world.ground_truth())
    return run_stages([OracleSegmenter(), TSDFMapper(), ContactGraphMapper()], data)


def completed_counter(library_name: str):
    """A kitchen counter (doors and drawers) observed whole and completed from a one-model library."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    counter = make_model("kitchen_counter", 0, 1)
    name = register_library(library_name, ModelLibrary([model_to_library(counter)]))
    pts = trimesh.sample.sample_surface(counter.mesh(), 4000, seed=0)[0] + [1.5, 1.0, 0.0]
    data = PipelineData()
    data.map.instances = ObjectInstances([ObjectInstance(1, "counter", pts, gravity_aligned_box(pts))])
    data.map.instances = ICPMatchCompleter(library=name).run(data)["instances"]
    return counter, data


def run(completer, data: PipelineData) -> tuple[PipelineData, dict]:
    data = copy.copy(data)
    data.map = copy.copy(data.map)
    data.warnings = []
    data.notes = {}
    out = completer.run(data)
    for layer, value in out.items():
        data.set(layer, value, completer.name)
    return data, out


def chair_chamfer(data: PipelineData) -> float:
    res = evaluate_completion(data.map.instances, data.ground_truth.objects)
    return res["chamfer_l1_by_class"]["chair"]


@pytest.fixture(scope="module")
def plane_box_matched(mapped):
    """plane_box_match on the mapped office, run once for the tests below."""
    return run(PlaneBoxMatchCompleter(), mapped)[0]


@pytest.fixture(scope="module")
def icp_matched(mapped):
    """icp_match on the mapped office, run once for the tests below: (data, the stage's output)."""
    return run(ICPMatchCompleter(), mapped)


@pytest.mark.slow
def test_model_matching_beats_boxes_on_chairs(mapped, plane_box_matched, icp_matched):
    boxes, _ = run(BBoxCompleter(), mapped)
    icp, _ = icp_matched
    pbm = plane_box_matched
    cd_box, cd_icp, cd_pbm = chair_chamfer(boxes), chair_chamfer(icp), chair_chamfer(pbm)
    assert cd_icp < cd_box and cd_pbm < cd_box
    assert min(cd_icp, cd_pbm) <= 0.03, (cd_icp, cd_pbm)
    res = evaluate_completion(icp.map.instances, icp.ground_truth.objects)
    chairs = [r for r in res["per_object"] if r["class"] == "chair"]
    assert np.mean([bool(r.get("same_family")) for r in chairs]) >= 0.75
    assert np.median([r["yaw_error_deg"] for r in chairs]) < 10


@pytest.mark.slow
def test_augmented_scene_replaces_observed_fragments(mapped, icp_matched):
    data, out = icp_matched
    aug = out["augmented"]
    completed = data.map.instances.completed()
    scene = o3d.t.geometry.RaycastingScene()
    for inst in completed:
        m = inst.completion.world_mesh()
        scene.add_triangles(o3c.Tensor(m.vertices.astype(np.float32)), o3c.Tensor(m.faces.astype(np.uint32)))
    observed = {tuple(p) for p in np.round(mapped.map.geometry.points, 9)}
    kept_observed = np.array([p for p in aug.points if tuple(np.round(p, 9)) in observed])
    dist = scene.compute_distance(o3c.Tensor(kept_observed.astype(np.float32))).numpy()
    assert dist.min() > 0.1  # no observed point within epsilon of a completed model
    assert len(aug.points) > len(kept_observed)  # the models' own points were added
    lm = LayeredMap(geometry=mapped.map.geometry, instances=data.map.instances, augmented=aug)
    assert lm.layer_counts()["augmented"]["points"] == len(aug.points)


def test_articulation_carries_over():
    cabinet = make_model("cabinet", 0, 3)
    assert cabinet.joints
    name = register_library("cabinets", ModelLibrary([model_to_library(cabinet)]))
    world_pose = np.eye(4)
    world_pose[:3, 3] = (2.0, 1.0, 0.0)
    pts = trimesh.sample.sample_surface(cabinet.mesh(), 3000, seed=0)[0]
    pts = pts[(pts[:, 1] < 0) | (pts[:, 0] < -0.2)]  # the front and one side are seen
    pts = pts + world_pose[:3, 3]
    from stratamap.core.geometry.boxes import gravity_aligned_box

    inst = ObjectInstance(1, "cabinet", pts, gravity_aligned_box(pts))
    data = PipelineData()
    data.map.instances = ObjectInstances([inst])
    out = ICPMatchCompleter(library=name).run(data)
    c = out["instances"][1].completion
    assert c.model_id == cabinet.id
    assert [j.type for j in c.joints] == [j.type for j in cabinet.joints]
    assert {p.name for p in c.parts} >= {j.child for j in c.joints}
    np.testing.assert_allclose(c.pose[:3, 3], world_pose[:3, 3], atol=0.05)


def test_robustness_warns_and_leaves_objects_uncompleted(tmp_path):
    trimesh.creation.box((0.5, 0.5, 0.8)).export(tmp_path / "cab.stl")
    (tmp_path / "broken.obj").write_text("garbage")
    (tmp_path / "classes.csv").write_text("file,class\ncab.stl,cabinet\nbroken.obj,cabinet\n")
    box = OrientedBox([1, 1, 0.4], 0, [0.5, 0.5, 0.8])
    rng = np.random.default_rng(0)
    insts = ObjectInstances(
        [
            ObjectInstance(1, "cabinet", rng.uniform([0.75, 0.75, 0], [1.25, 1.25, 0.8], (400, 3)), box),
            ObjectInstance(2, "cabinet", rng.uniform(0, 1, (5, 3)), box),  # too few points
            ObjectInstance(3, "sofa", rng.uniform(0, 1, (400, 3)), box),  # no sofa in the library
            ObjectInstance(4, "sofa", rng.uniform(0, 1, (400, 3)), box),
            ObjectInstance(5, "object", rng.uniform(0, 1, (400, 3)), box),  # no class: no models by design
            ObjectInstance(6, "object", rng.uniform(0, 1, (400, 3)), box),
        ]
    )
    data = PipelineData()
    data.map.instances = insts
    out = ICPMatchCompleter(library=str(tmp_path), reject_distance=None, recognize=[]).run(data)
    assert out["instances"][1].completion is not None
    assert all(out["instances"][i].completion is None for i in (2, 3, 4, 5, 6))
    text = "\n".join(data.warnings)
    assert "broken.obj" in text and "object 2" in text
    # One warning per class, naming its objects; the unnamed ones are a note, not a warning.
    assert [w for w in data.warnings if "'sofa'" in w] == [
        "completers.icp_match: objects 3, 4: no 'sofa' models in the library; left uncompleted"
    ]
    assert "'object'" not in text
    assert data.notes["icp_match"]["unnamed_left_uncompleted"] == [5, 6]


def test_index_cache_round_trip(tmp_path):
    library = ModelLibrary([model_to_library(make_model("stool", 0, i)) for i in range(3)])
    built = ModelIndex(library, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("index-*.npz"))) == 1
    loaded = ModelIndex(library, cache_dir=tmp_path)
    for mid, m in built.models.items():
        np.testing.assert_allclose(loaded.models[mid].samples, m.samples, atol=1e-6)
        np.testing.assert_allclose(loaded.models[mid].descriptor, m.descriptor)
    assert loaded.shortlist("chair", built.models[library.models[0].id].descriptor, 1) == [library.models[0].id]


@pytest.mark.slow
def test_matching_is_deterministic(mapped, plane_box_matched):
    a = plane_box_matched
    b, _ = run(PlaneBoxMatchCompleter(), mapped)
    for ia, ib in zip(a.map.instances, b.map.instances, strict=True):
        assert (ia.completion is None) == (ib.completion is None)
        if ia.completion is not None:
            assert ia.completion.model_id == ib.completion.model_id
            np.testing.assert_allclose(ia.completion.pose, ib.completion.pose)


def test_orientations_are_the_24_rotations():
    assert len(ORIENTATIONS) == 24
    assert len({tuple(np.round(r.reshape(-1))) for r in ORIENTATIONS}) == 24
    assert all(np.isclose(np.linalg.det(r), 1) for r in ORIENTATIONS)


def test_chamfer_and_fscore_on_hand_made_shapes():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (2000, 3))
    same = shape_distances(a, a)
    assert same["chamfer_l1"] == 0 and same["fscore_1cm"] == 1.0
    shifted = shape_distances(a + [0.03, 0, 0], a)
    assert 0.005 < shifted["chamfer_l1"] <= 0.03 and shifted["fscore_5cm"] == 1.0
    assert shifted["fscore_1cm"] < 0.5


def test_articulated_completion_exports_working_joints(tmp_path):
    pybullet = pytest.importorskip("pybullet")
    yourdfpy = pytest.importorskip("yourdfpy")
    from stratamap.plugins.exporters.urdf import URDFExporter

    cabinet, data = completed_counter("counters")
    kinds = sorted(j.type for j in cabinet.joints)
    paths = URDFExporter().run(data, tmp_path)
    robot = yourdfpy.URDF.load(str(paths[0]))
    assert robot.validate()
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(paths[0]), useFixedBase=True, physicsClientId=client)
        found = sorted(
            {0: "revolute", 1: "prismatic"}[info[2]]
            for info in (
                pybullet.getJointInfo(body, i, physicsClientId=client)
                for i in range(pybullet.getNumJoints(body, physicsClientId=client))
            )
            if info[2] in (0, 1)
        )
    finally:
        pybullet.disconnect(client)
    assert found == kinds and "revolute" in found


def test_mjcf_export_loads_in_mujoco_with_articulation(tmp_path):
    mujoco = pytest.importorskip("mujoco")
    from stratamap.plugins.exporters.mjcf import MJCFExporter

    counter, data = completed_counter("counters-mjcf")
    paths = MJCFExporter().run(data, tmp_path)
    model = mujoco.MjModel.from_xml_path(str(paths[0]))
    names = {
        int(mujoco.mjtJoint.mjJNT_HINGE): "revolute",
        int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic",
        int(mujoco.mjtJoint.mjJNT_FREE): "free",
    }
    kinds = sorted(names[int(t)] for t in model.jnt_type)
    assert kinds == sorted(j.type for j in counter.joints)  # no free joint: furniture is static
    sim = mujoco.MjData(model)
    for _ in range(200):
        mujoco.mj_step(model, sim)
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "counter_1")
    np.testing.assert_allclose(sim.xpos[body][:2], data.map.instances[1].completion.pose[:2, 3], atol=1e-6)


def test_glb_is_y_up_and_sdf_keeps_joints(tmp_path):
    import xml.etree.ElementTree as ET

    from stratamap.plugins.exporters.glb import GLBExporter
    from stratamap.plugins.exporters.sdf import SDFExporter

    counter, data = completed_counter("counters-sdf")
    glb = GLBExporter().run(data, tmp_path)[0]
    scene = trimesh.load(glb)
    assert scene.extents[1] == pytest.approx(counter.size[2], abs=0.02)  # height along glTF's +y
    sdf = ET.parse(SDFExporter().run(data, tmp_path)[0]).getroot()
    model = sdf.find("world").find("model[@name='counter_1']")
    assert model.find("static").text == "true"
    assert sorted(j.get("type") for j in model.findall("joint")) == sorted(j.type for j in counter.joints)
    for uri in sdf.iter("uri"):
        assert (tmp_path / uri.text).is_file()


def test_an_object_with_no_class_is_recognized_by_matching():
    from stratamap.core.geometry.boxes import gravity_aligned_box

    chair, table = make_model("four_leg_chair", 0, 2), make_model("round_table", 0, 2)
    name = register_library("recognition", ModelLibrary([model_to_library(chair), model_to_library(table)]))
    pts = trimesh.sample.sample_surface(chair.mesh(), 3000, seed=0)[0] + [2.0, 1.0, 0.0]
    blob = np.random.default_rng(0).uniform([4, 4, 0], [4.4, 4.4, 0.4], (600, 3))  # fits no model
    data = PipelineData()
    data.map.instances = ObjectInstances(
        [
            ObjectInstance(1, "object", pts, gravity_aligned_box(pts)),
            ObjectInstance(2, "object", blob, gravity_aligned_box(blob)),
        ]
    )
    out = ICPMatchCompleter(library=name).run(data)["instances"]
    assert out[1].class_name == "chair" and out[1].completion is not None
    record = out[1].attributes["recognition"]
    assert record["from"] == "object" and record["class"] == "chair" and record["fit_m"] <= 0.03
    naming = out[1].attributes["naming"]
    assert naming["by"] == "matching" and record["model"] in naming["why"] and "was object" in naming["why"]
    assert out[2].class_name == "object" and "class" not in out[2].attributes["recognition"]
    assert "naming" not in out[2].attributes  # it kept what it had
    assert data.notes["icp_match"]["recognition"] == {"attempted": 2, "recognized": 1}


def test_recognition_takes_no_class_the_shape_is_too_flat_for():
    """A flat sliver (the top of something, 1 cm high) lies on a table's top, but no table is 1 cm
    high: recognition by matching does not even try the class (no best class in its record)."""
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.map.instances import plausible

    table = make_model("round_table", 0, 2)
    name = register_library("recognition-flat", ModelLibrary([model_to_library(table)]))
    top = trimesh.sample.sample_surface(table.mesh(), 6000, seed=0)[0]
    sliver = top[top[:, 2] > top[:, 2].max() - 0.01] + [2.0, 1.0, 0.0]
    assert plausible("table", sliver) and not plausible("table", sliver, whole=True)
    data = PipelineData()
    data.map.instances = ObjectInstances([ObjectInstance(1, "object", sliver, gravity_aligned_box(sliver))])
    out = ICPMatchCompleter(library=name).run(data)["instances"]
    assert out[1].class_name == "object" and "best_class" not in out[1].attributes["recognition"]


def test_recognition_gives_no_class_that_stands_on_a_support_to_an_object_on_the_floor():
    """A microwave stands on a worktop or a shelf, never on a room's floor: a microwave's shape on the
    floor (a table's pedestal foot, a crate) is not recognized as one, the same shape on a worktop is."""
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.map.priors import ON_A_SUPPORT

    assert "microwave" in ON_A_SUPPORT
    microwave = make_model("microwave", 0, 2)
    name = register_library("recognition-footing", ModelLibrary([model_to_library(microwave)]))
    pts = trimesh.sample.sample_surface(microwave.mesh(), 3000, seed=0)[0]
    on_floor, on_worktop = pts + [2.0, 1.0, 0.0], pts + [4.0, 1.0, 0.9]
    data = PipelineData()
    data.map.instances = ObjectInstances(
        [
            ObjectInstance(1, "object", on_floor, gravity_aligned_box(on_floor)),
            ObjectInstance(2, "object", on_worktop, gravity_aligned_box(on_worktop)),
        ]
    )
    out = ICPMatchCompleter(library=name).run(data)["instances"]
    assert out[1].class_name == "object" and "best_class" not in out[1].attributes["recognition"]
    assert out[2].class_name == "microwave"


def test_seen_coverage_counts_what_a_sensor_could_have_seen_of_a_model():
    """A closed unit against a wall, seen from the room: its front, top and sides are what the sensor
    could see. Points on those cover nearly all of it, although its back and bottom (a third of its
    surface) hold none; a strip of its front covers little."""
    from stratamap.plugins.completers._matching import seen_coverage

    unit = trimesh.creation.box(extents=[1.0, 0.5, 0.9])
    unit.apply_translation([0.0, 0.0, 0.45])
    views = np.array([[x, -3.0, 1.3] for x in (-2.0, -1.0, 0.0, 1.0, 2.0)])
    surface, faces = trimesh.sample.sample_surface(unit, 20000, seed=1)
    normals = unit.face_normals[faces]
    seeable = (normals[:, 1] < 0.5) & (normals[:, 2] > -0.5)  # not the back (+y) nor the bottom
    seen = surface[seeable]
    assert 0.55 < len(seen) / len(surface) < 0.75
    assert seen_coverage(unit, seen, views, 0.03) > 0.95
    strip = surface[seeable & (normals[:, 1] < -0.5) & (np.abs(surface[:, 0]) < 0.05)]
    assert len(strip) > 100 and seen_coverage(unit, strip, views, 0.03) < 0.1
    # Nothing seeable from these viewpoints (all inside the model): the whole surface counts.
    assert 0.55 < seen_coverage(unit, seen, np.array([[0.0, 0.0, 0.45]]), 0.03) < 0.8


def test_recognition_takes_no_class_for_a_strip_of_a_models_surface():
    """A strip of a fridge's front (a sliver a map keeps of a tall unit) lies on the fridge model's
    surface: the one-sided fit passes, but the strip covers little of what could be seen of the model
    posed there, so it keeps no class; the whole fridge is recognized."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    fridge = make_model("fridge", 0, 2)
    name = register_library("recognition-strip", ModelLibrary([model_to_library(fridge)]))
    mesh = fridge.mesh()
    pts, faces = trimesh.sample.sample_surface(mesh, 20000, seed=0)
    front = pts[(mesh.face_normals[faces][:, 1] < -0.9)]
    centre = float(np.median(front[:, 0]))
    strip = front[np.abs(front[:, 0] - centre) < 0.06] + [2.0, 1.0, 0.0]
    whole = pts[mesh.face_normals[faces][:, 2] > -0.5] + [4.0, 1.0, 0.0]
    data = PipelineData()
    data.map.instances = ObjectInstances(
        [
            ObjectInstance(1, "object", strip, gravity_aligned_box(strip)),
            ObjectInstance(2, "object", whole, gravity_aligned_box(whole)),
        ]
    )
    out = ICPMatchCompleter(library=name).run(data)["instances"]
    record = out[1].attributes["recognition"]
    assert record["best_class"] == "fridge" and record["fit_m"] <= 0.03 and record["coverage"] < 0.3, record
    assert out[1].class_name == "object" and "class" not in record
    assert out[2].class_name == "fridge" and out[2].attributes["recognition"]["coverage"] >= 0.3
    assert "seeable surface" in out[2].attributes["naming"]["why"]


def _front_of(completion) -> np.ndarray:
    """The top-view direction of a completed model's front (-y of the model frame) in the world."""
    return completion.pose[:2, :2] @ np.array([0.0, -1.0])


def _seen_from_above(model, heading: float, library: str, cameras: bool):
    """``model`` at ``heading``, only its top seen, matched against a library of it alone; with
    ``cameras``, posed frames 1.5-2.5 m in front of it. Returns (completion, the true front, the
    completer's notes)."""
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.geometry.transforms import make_pose
    from stratamap.core.map.sensors import RGBDFrame, SensorStream

    name = register_library(library, ModelLibrary([model_to_library(model)]))
    pts = trimesh.sample.sample_surface(model.mesh(), 4000, seed=1)[0]
    pts = pts[pts[:, 2] > pts[:, 2].max() - 0.01]
    pose = make_pose([2.0, 1.0, 0.0], heading)
    pts = pts @ pose[:3, :3].T + pose[:3, 3]
    front = pose[:2, :2] @ np.array([0.0, -1.0])
    data = PipelineData()
    if cameras:
        side = np.array([-front[1], front[0]])
        stops = [np.r_[[2.0, 1.0] + d * front + w * side, 1.4] for d in (1.5, 2.5) for w in (-0.8, 0.0, 0.8)]
        blank, colour = np.zeros((2, 2), np.float32), np.zeros((2, 2, 3), np.uint8)
        frames = [RGBDFrame(k, float(k), colour, blank, make_pose(at, 0.0)) for k, at in enumerate(stops)]
        data = PipelineData(stream=SensorStream("front", frames=frames))
    data.map.instances = ObjectInstances([ObjectInstance(1, model.class_name, pts, gravity_aligned_box(pts))])
    completion = ICPMatchCompleter(library=name).run(data)["instances"][1].completion
    return completion, front, data.notes["icp_match"]


@pytest.mark.parametrize("heading", [0.3, 2.0, 3.6, 5.2])
def test_a_model_seen_only_from_above_turns_its_front_to_where_it_was_seen_from(heading):
    """A drawer cabinet of which only the top was seen (between counters, from above): its library
    model fits as well turned half round, drawers to the wall; the match turns the front towards
    where the sensor stood."""
    cabinet = make_model("cabinet", 0, 3)
    assert any(j.type == "prismatic" for j in cabinet.joints)
    c, front, notes = _seen_from_above(cabinet, heading, "front-seen cabinet", cameras=True)
    assert c is not None
    assert float(_front_of(c) @ front) > 0.9, (heading, _front_of(c), front)
    np.testing.assert_allclose(c.pose[:2, 3], [2.0, 1.0], atol=0.08)
    # The notes name it where the best fit alone (no cameras) would have turned it the other way.
    blind, _, _ = _seen_from_above(cabinet, heading, "front-seen cabinet", cameras=False)
    assert notes["fronts_towards_sensor"] == ([1] if float(_front_of(blind) @ front) < 0.9 else [])


@pytest.mark.parametrize("family", ["box", "rectangular_table"])
def test_a_model_with_nothing_that_opens_keeps_its_best_fit(family):
    """Where the sensor stood says nothing of the front of a model with no door or drawer (a box's
    "front" may as well face away): the same pose with cameras or none."""
    model = make_model(family, 0, 0)
    assert not any(j.type in ("revolute", "prismatic") for j in model.joints)
    seen, _, notes = _seen_from_above(model, 2.0, f"front-seen {family}", cameras=True)
    unseen, _, _ = _seen_from_above(model, 2.0, f"front-seen {family}", cameras=False)
    np.testing.assert_array_equal(seen.pose, unseen.pose)
    assert notes["fronts_towards_sensor"] == []


def test_the_front_breaks_only_ties_of_the_fit():
    from stratamap.plugins.completers.icp_match import seen_front_yaw

    yaws = np.arange(4) * np.pi / 2  # fronts along -y, +x, +y, -x
    coarse = np.array([0.020, 0.050, 0.021, 0.060])
    towards = np.array([0.0, 1.0])  # seen from +y
    assert seen_front_yaw(coarse, yaws, towards, tie=0.005) == 2  # the tie goes to the front facing +y
    assert seen_front_yaw(coarse, yaws, towards, tie=0.0) == 0  # no tie allowed: the best fit
    assert seen_front_yaw(coarse, yaws, np.zeros(2), tie=0.005) == 0  # seen from all round: the best fit
    # Seen from +x, a little from +y: the front along +x fits 3 cm worse and is not taken.
    assert seen_front_yaw(coarse, yaws, np.array([1.0, 0.3]), tie=0.005) == 2
