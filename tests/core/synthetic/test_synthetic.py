"""Synthetic worlds: models, scenes, sensors and ground truth, deterministic and physically consistent."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import networkx as nx
import numpy as np
import open3d as o3d
import open3d.core as o3c
import pytest
from PIL import Image
from typer.testing import CliRunner

from stratamap.core.cli import app
from stratamap.core.geometry.transforms import look_at
from stratamap.core.io.nav2 import read_map
from stratamap.core.map.layers import ContactGraph
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.synthetic import SCENE_TYPES, SceneSpec, SyntheticWorld, generate_scene
from stratamap.core.synthetic.models import FAMILIES, make_model
from stratamap.core.synthetic.render import SceneRenderer, apply_kinect_noise
from stratamap.core.synthetic.scene import room_layout
from stratamap.core.synthetic.writer import write_sequence
from stratamap.core.testing import fingerprint
from tests.conftest import REPO

runner = CliRunner()
TINY = {"camera": {"width": 80, "height": 60}, "trajectory": {"frames": 3}}


def tiny(scene_type: str, seed: int = 0, **extra) -> SceneSpec:
    return SceneSpec.model_validate({"type": scene_type, "seed": seed, **TINY, **extra})


# ---------------------------------------------------------------- models


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_models_are_watertight_and_canonical(family):
    for index in range(3):
        model = make_model(family, seed=3, index=index)
        for part in model.parts:
            assert part.mesh.is_watertight, f"{family} {part.name}"
        lo, hi = model.bounds
        assert abs(lo[2]) < 1e-9, "origin at the bottom"
        np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0, atol=1e-9)
        assert 0.01 < hi[2] < 2.5


def test_families_span_variety():
    a, b = make_model("four_leg_chair", 0, 0), make_model("four_leg_chair", 0, 1)
    assert a.params != b.params
    assert make_model("four_leg_chair", 0, 0).params == a.params


def test_articulated_families_open_the_right_way():
    """Doors swing out to the front (-y) and drawers slide out to the front."""
    from scipy.spatial.transform import Rotation

    for family in ("cabinet", "kitchen_counter", "fridge", "desk", "microwave"):
        model = make_model(family, seed=1, index=2)
        for joint in model.joints:
            child = [p for p in model.parts if p.link == joint.child]
            center = np.mean([p.mesh.bounds.mean(0) for p in child], 0)
            if joint.type == "prismatic":
                moved = center + joint.origin[:3, :3] @ joint.axis * joint.upper
            else:
                local = center - joint.origin[:3, 3]
                rot = Rotation.from_rotvec(joint.origin[:3, :3] @ joint.axis * np.radians(60)).as_matrix()
                moved = joint.origin[:3, 3] + rot @ local
            assert moved[1] < center[1] - 0.01, f"{family} {joint.name} opens backwards"


def test_models_build_cli_contract(tmp_path):
    out = tmp_path / "lib"
    result = runner.invoke(app, ["models", "build", "--out", str(out), "--per-family", "2"])
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "models.json").read_text())
    families = {m["family"] for m in doc["models"]}
    chairs = {m["family"] for m in doc["models"] if m["class"] == "chair"}
    joints = [j["type"] for m in doc["models"] for j in m["joints"]]
    assert len(families) >= 15 and len(chairs) >= 3
    assert "revolute" in joints and "prismatic" in joints
    for m in doc["models"]:
        assert {"id", "class", "family", "params", "bounds", "feature_planes", "parts", "joints"} <= set(m)
    from stratamap.core.library.models import ModelLibrary

    lib = ModelLibrary.load(out)
    assert len(lib) == 2 * len(FAMILIES) and not lib.problems
    for model in lib.models[::7]:
        for part in model.parts:
            assert part.load().is_watertight, (model.id, part.name)


def test_user_mesh_folder_and_broken_files(tmp_path):
    import trimesh

    trimesh.creation.box((0.5, 0.4, 0.9)).export(tmp_path / "cab.stl")
    trimesh.creation.icosphere().export(tmp_path / "ball.ply")
    (tmp_path / "broken.obj").write_text("this is not an obj\n")
    (tmp_path / "classes.csv").write_text(
        "file,class\ncab.stl,cabinet\nball.ply,object\nbroken.obj,box\nmissing.glb,box\n"
    )
    from stratamap.core.library.models import ModelLibrary

    lib = ModelLibrary.load(tmp_path)
    assert sorted(m.id for m in lib) == ["ball", "cab"]
    assert lib.get("cab").bounds[0][2] == pytest.approx(0.0)
    assert any("missing.glb" in p for p in lib.problems) and any("broken.obj" in p for p in lib.problems)


@pytest.mark.slow
def test_partnet_mobility_folders_load():
    root = REPO.parent / "shared" / "data" / "partnet_mobility"
    if not root.exists():
        pytest.skip("real data not available")
    from stratamap.core.library.models import ModelLibrary

    lib = ModelLibrary.load(root)
    assert {m.class_name for m in lib} == {"chair", "cabinet"}
    cabinets = lib.by_class("cabinet")
    assert all(any(j.type == "revolute" for j in m.joints) for m in cabinets)
    assert any(any(j.type == "prismatic" for j in m.joints) for m in cabinets)
    for m in lib:
        size = m.size
        assert size[2] > 0.5 * max(size[0], size[1]), f"{m.id} is not upright: {size}"


# ---------------------------------------------------------------- scenes


def test_an_objects_world_parts_are_made_once_per_pose_and_follow_a_move():
    obj = generate_scene(SceneSpec(type="office", seed=4)).objects[0]
    first, again = obj.world_parts(), obj.world_parts()
    assert len(first) == len(again) > 0 and all(a is b for (_, a), (_, b) in zip(first, again))
    lo = np.min([m.bounds[0] for _, m in first], axis=0)
    obj.pose = obj.pose.copy()
    obj.pose[0, 3] += 0.5
    moved = np.min([m.bounds[0] for _, m in obj.world_parts()], axis=0)
    assert np.allclose(moved - lo, [0.5, 0.0, 0.0])
    assert np.allclose(np.min([m.bounds[0] for _, m in first], axis=0), lo)  # the first call's meshes stay put


@pytest.mark.parametrize("scene_type", SCENE_TYPES)
def test_scene_types_place_their_objects_without_interpenetration(scene_type):
    scene = generate_scene(SceneSpec(type=scene_type, seed=4))
    requested = sum(SceneSpec(type=scene_type).resolved_objects().values())
    assert len(scene.objects) >= 0.8 * requested, scene.skipped
    lx, ly, _ = scene.room_size
    for i, a in enumerate(scene.objects):
        sdf = o3d.t.geometry.RaycastingScene()
        for _, mesh in a.world_parts():
            sdf.add_triangles(o3c.Tensor(mesh.vertices.astype(np.float32)), o3c.Tensor(mesh.faces.astype(np.uint32)))
        lo = np.min([m.bounds[0] for _, m in a.world_parts()], 0)
        hi = np.max([m.bounds[1] for _, m in a.world_parts()], 0)
        assert lo[0] > -1e-6 and lo[1] > -1e-6 and hi[0] < lx + 1e-6 and hi[1] < ly + 1e-6, "inside the room"
        for b in scene.objects[i + 1 :]:
            pts = np.vstack([np.vstack([m.sample(300, seed=0), m.vertices]) for _, m in b.world_parts()])
            # Resting contact is allowed; penetration deeper than 1 mm is not.
            depth = -sdf.compute_signed_distance(o3c.Tensor(pts.astype(np.float32))).numpy().min()
            assert depth < 1e-3, f"{b.class_name} {b.id} penetrates {a.class_name} {a.id} by {depth:.4f} m"


def test_chairs_are_pushed_partly_under_tables_and_desks():
    under = 0
    for seed in range(3):
        scene = generate_scene(SceneSpec(type="office", seed=seed))
        hosts = [o for o in scene.objects if o.class_name in ("desk", "table")]
        for chair in (o for o in scene.objects if o.class_name == "chair"):
            seat = next(m for p, m in chair.world_parts() if p.semantic == "seat")
            for host in hosts:
                top = next(m for p, m in host.world_parts() if p.semantic == "top")
                if np.all(seat.bounds[1, :2] > top.bounds[0, :2]) and np.all(seat.bounds[0, :2] < top.bounds[1, :2]):
                    under += 1
    assert under >= 3


def test_support_tree_matches_placement():
    for scene_type in SCENE_TYPES:
        scene = generate_scene(SceneSpec(type=scene_type, seed=2))
        g = scene.contact_graph().support
        by_id = {o.id: o for o in scene.objects}
        for obj in scene.objects:
            assert g.in_degree(obj.id) == 1
            parent = next(iter(g.predecessors(obj.id)))
            if parent == "floor":
                assert obj.pose[2, 3] == 0.0
            else:
                host = by_id[parent]
                tops = [s[4] + host.pose[2, 3] for s in host.model.support_surfaces]
                assert min(abs(t - obj.pose[2, 3]) for t in tops) < 1e-9


# ---------------------------------------------------------------- sensors


def test_rendered_depth_matches_geometry():
    """Looking straight down from 2 m at the empty floor gives depth 2 m everywhere."""
    spec = SceneSpec(type="room", objects={}, room_size=(4, 4, 2.6))
    renderer = SceneRenderer(generate_scene(spec))
    intr = CameraIntrinsics(64, 48, 40.0, 40.0, 31.5, 23.5)
    view = renderer.render(intr, look_at([2.0, 2.0, 2.0], [2.0, 2.0, 0.0], up=(0, 1, 0)))
    np.testing.assert_allclose(view.depth, 2.0, atol=1e-4)
    assert (view.class_ids == 1).all() and (view.instance_ids == 0).all()


def test_kinect_noise_grows_with_depth_squared():
    spec = SceneSpec(type="room", objects={}, room_size=(8, 8, 3.0))
    renderer = SceneRenderer(generate_scene(spec))
    intr = CameraIntrinsics(160, 120, 120.0, 120.0, 79.5, 59.5)
    stds = []
    for dist in (1.0, 3.0):
        view = renderer.render(intr, look_at([4.0, 8.0 - dist, 1.5], [4.0, 8.0, 1.5]))
        noisy = apply_kinect_noise(view, np.random.default_rng(0), 0.4, 8.0, 84.0, 0.0)
        ok = (noisy > 0) & (view.depth > 0)
        stds.append(np.std(noisy[ok] - view.depth[ok]))
    expected = [0.0012 + 0.0019 * (d - 0.4) ** 2 for d in (1.0, 3.0)]
    assert stds[1] > 3 * stds[0]
    assert expected[1] * 0.7 < stds[1] < expected[1] * 1.5


def test_laser_sees_chair_legs_but_not_seats():
    world = SyntheticWorld(tiny("room", seed=3))
    gt = world.ground_truth()
    laser, band = gt.occupancy["laser"].data, gt.occupancy["objects"].data
    assert ((band == 100) & (laser == 0)).sum() > 50  # seats and tabletops: above the laser
    assert ((laser == 100) & (band == 0)).sum() == 0
    scan = world.laser_scans[0]
    assert np.isfinite(scan.ranges).mean() > 0.95 and len(scan.ranges) == 720


def test_lidar_points_lie_on_the_scene():
    world = SyntheticWorld(tiny("corridor", lidar={"enabled": True, "rings": 8, "points_per_ring": 180}))
    scan = world.lidar_scans[0]
    assert len(scan.points) > 0.9 * 8 * 180
    from stratamap.core.geometry.transforms import apply

    pts = apply(scan.pose, scan.points)
    lx, ly, lz = world.scene.room_size
    assert pts[:, 0].min() > -0.1 and pts[:, 0].max() < lx + 0.1 and pts[:, 2].max() < lz + 0.1


# ---------------------------------------------------------------- on disk


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.mark.slow
@pytest.mark.parametrize("scene_type", ["office", "kitchen"])
def test_synth_writes_the_tum_layout_deterministically(tmp_path, scene_type):
    spec_file = REPO / "configs" / "scenes" / f"{scene_type}.yaml"
    args = ["synth", str(spec_file), "--seed", "3", "--frames", "4"]
    for name in ("a", "b"):
        result = runner.invoke(app, [*args, "--out", str(tmp_path / name)])
        assert result.exit_code == 0, result.output
    a = tmp_path / "a"
    assert _digest(a) == _digest(tmp_path / "b"), "same spec and seed must give identical files"
    for rel in (
        "rgb.txt",
        "depth.txt",
        "groundtruth.txt",
        "camera.json",
        "laser.txt",
        "gt/scene.json",
        "gt/contact_graph.json",
    ):
        assert (a / rel).is_file(), rel
    depth_files = sorted((a / "depth").glob("*.png"))
    assert len(depth_files) == 4
    depth = np.asarray(Image.open(depth_files[0]))
    assert depth.dtype == np.uint16 and depth.max() > 5000
    poses = [ln for ln in (a / "groundtruth.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(poses) == 4 and all(len(ln.split()) == 8 for ln in poses)
    graph = ContactGraph.from_dict(
        {
            "support": json.loads((a / "gt" / "contact_graph.json").read_text()),
            "proximal": nx.node_link_data(nx.Graph(), edges="links"),
        }
    )
    scene = json.loads((a / "gt" / "scene.json").read_text())
    for obj in scene["objects"]:
        assert graph.support.in_degree(obj["id"]) == 1
        assert graph.parent(obj["id"]) == obj["parent"]
        assert (a / "gt" / obj["mesh"]).is_file()
    grid = read_map(a / "gt" / "occupancy_objects.yaml")
    assert (grid.data == 100).any() and (grid.data == 0).any()


def test_in_memory_sequence_is_lazy_deterministic_and_picklable():
    import pickle

    world = SyntheticWorld(tiny("meeting_room", seed=5))
    stream = world.stream()
    again = pickle.loads(pickle.dumps(stream.frames))
    assert fingerprint([stream.frames[2].depth, stream.frames[2].rgb]) == fingerprint([again[2].depth, again[2].rgb])
    other = SyntheticWorld(tiny("meeting_room", seed=6)).stream()
    assert fingerprint(stream.frames[0].rgb) != fingerprint(other.frames[0].rgb)


def test_pose_drift_changes_reported_not_true_poses():
    world = SyntheticWorld(tiny("room", noise={"pose_drift": 0.01}, trajectory={"frames": 20}))
    assert np.allclose(world.true_poses[0][:3, 3], world.true_poses[0][:3, 3])
    err = np.linalg.norm(world.reported_poses[-1][:3, 3] - world.true_poses[-1][:3, 3])
    assert 0.005 < err < 0.5
    np.testing.assert_allclose(world.stream().frames[19].pose, world.reported_poses[19])


def test_write_sequence_with_lidar(tmp_path):
    world = SyntheticWorld(tiny("corridor", lidar={"enabled": True, "rings": 4, "points_per_ring": 64}))
    write_sequence(world, tmp_path / "seq")
    bins = sorted((tmp_path / "seq" / "lidar").glob("*.bin"))
    assert len(bins) == 3
    cloud = np.fromfile(bins[0], dtype=np.float32).reshape(-1, 4)
    assert len(cloud) == len(world.lidar_scans[0].points)


def test_room_layout_is_closed():
    layout = room_layout((4.0, 3.0, 2.5))
    assert [e.class_name for e in layout].count("wall") == 4
    assert all(e.mesh.is_watertight for e in layout)


def test_real_apartment_urdf_loads_into_the_library():
    root = REPO.parent / "shared" / "data" / "iai_apartment" / "urdf" / "apartment.urdf"
    if not root.exists():
        pytest.skip("real data not available")
    from stratamap.core.library.models import ModelLibrary

    lib = ModelLibrary.load(root)
    [model] = lib.models
    kinds = [j.type for j in model.joints]
    assert kinds.count("prismatic") == 27 and kinds.count("revolute") == 15
    assert any("walls.dae" in p for p in lib.problems)  # absent visual meshes are reported
    assert any("using its collision geometry" in p for p in lib.problems)
    assert len(model.parts) > 50 and abs(model.bounds[0][2]) < 1e-9


def test_varied_fixtures_change_only_the_handles_and_knobs():
    """``make_model(..., varied_fixtures=True)`` gives a counter's handles and knobs a style of their
    own (the fixture classifier's training data) and leaves every other part as it was (up to the
    model's centring); the default is the style every benchmark scene was made with."""
    from stratamap.core.synthetic.models import make_model

    plain, again = make_model("kitchen_counter", 5, 1), make_model("kitchen_counter", 5, 1)
    varied = [make_model("kitchen_counter", 5, 1, varied_fixtures=True) for _ in range(2)]
    fixture = {"handle", "knob"}

    def parts(model, keep):
        # Relative to the first part: a model is centred on its box, which handles standing out widen.
        origin = model.parts[0].mesh.bounds[0]
        return [
            (p.name, np.round(p.mesh.bounds - origin, 6).tolist(), p.albedo) for p in model.parts if keep(p.semantic)
        ]

    assert parts(plain, lambda s: True) == parts(again, lambda s: True)
    assert parts(varied[0], lambda s: True) == parts(varied[1], lambda s: True)  # deterministic
    assert parts(varied[0], lambda s: s not in fixture) == parts(plain, lambda s: s not in fixture)
    assert parts(plain, lambda s: s in fixture)
    assert parts(varied[0], lambda s: s in fixture) != parts(plain, lambda s: s in fixture)
    bars = [p.mesh.extents for p in plain.parts if p.name.endswith("_bar")]
    assert bars and all(np.isclose(sorted(e)[0], 0.012) for e in bars)  # the default 12 mm bar


def test_where_the_frames_were_taken_is_known_without_rendering_them(monkeypatch):
    """The sensor's positions (what completers and clusters turn things towards) come from the
    reported poses; rendering every frame of a walk for them cost seconds per stage."""
    from stratamap.core.map.sensors import sensor_viewpoints

    world = SyntheticWorld(SceneSpec.model_validate({"type": "office", "seed": 1, "trajectory": {"frames": 6}}))
    stream = world.stream()
    rendered = [np.asarray(stream.frames[k].pose) for k in range(len(stream.frames))]
    monkeypatch.setattr(world, "frame", lambda k: pytest.fail(f"frame {k} rendered"))
    np.testing.assert_array_equal(np.array(stream.frames.poses), np.array(rendered))
    views = sensor_viewpoints(stream, np.zeros((1, 3)))
    np.testing.assert_array_equal(views, np.array(rendered)[:, :3, 3])
    stream.frames.poses[0][:3, 3] = 99.0  # copies: the walk's own poses stay
    assert not np.any(stream.frames.poses[0][:3, 3] == 99.0)
