"""The ``usd`` exporter: read back with pxr's own UsdPhysics parser, the scene the URDF exporter
writes for the same map (bodies, colliders, masses, joints, limits, poses), stage metadata, and
the one-line error when usd-core is missing."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from stratamap.core.errors import PluginError
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.layers import Completion, Joint, ObjectInstance, ObjectInstances, OrientedBox, Part
from stratamap.core.stages import PipelineData
from stratamap.core.testing import example_data, parametrize_with_checks
from stratamap.plugins.exporters.urdf import URDFExporter
from stratamap.plugins.exporters.usd import USDConfig, USDExporter
from tests.core.simulation.test_physics import box_object, graph_of
from tests.core.simulation.test_scene_export import room_map


def articulated(iid: int, cls: str, pose: np.ndarray, body_size, part_size, part_origin, joint_type, axis, limits):
    """A completed object at ``pose``: a box body and one moving part on a joint to it."""
    body = trimesh.creation.box(extents=body_size)
    body.apply_translation((0, 0, body_size[2] / 2))
    part = trimesh.creation.box(extents=part_size)
    part.apply_translation(np.asarray(part_size) / 2 * [1, 0, 1])  # the part's frame on its hinge edge
    joints = [Joint("hinge", joint_type, "body", "part", part_origin, np.asarray(axis, float), *limits)]
    parts = [Part("body", body), Part("part", part, part_origin)]
    mesh = trimesh.util.concatenate([body, part.copy().apply_transform(part_origin)])
    world = trimesh.transform_points(mesh.vertices, pose)
    lo, hi = world.min(0), world.max(0)
    box = OrientedBox((lo + hi) / 2, 0.0, hi - lo)
    return ObjectInstance(iid, cls, world, box, completion=Completion(mesh, pose, "test", parts=parts, joints=joints))


def swivel_chair(iid: int, at) -> ObjectInstance:
    """A chair whose seat slides up on a geometry-less helper link and turns on it."""
    body = trimesh.creation.box(extents=[0.5, 0.5, 0.4])
    body.apply_translation((0, 0, 0.2))
    seat = trimesh.creation.box(extents=[0.4, 0.4, 0.05])
    lift = make_pose((0.0, 0.0, 0.425))
    joints = [
        Joint("swivel", "continuous", "helper", "seat", np.eye(4), np.array([0.0, 0.0, 1.0])),
        Joint("lift", "prismatic", "body", "helper", lift, np.array([0.0, 0.0, 1.0]), 0.0, 0.1),
    ]
    parts = [Part("body", body), Part("seat", seat, lift)]
    mesh = trimesh.util.concatenate([body, seat.copy().apply_transform(lift)])
    pose = make_pose(at, yaw=0.3)
    world = trimesh.transform_points(mesh.vertices, pose)
    lo, hi = world.min(0), world.max(0)
    box = OrientedBox((lo + hi) / 2, 0.3, [0.5, 0.5, 0.45])
    return ObjectInstance(
        iid, "chair", world, box, completion=Completion(mesh, pose, "test", parts=parts, joints=joints)
    )


def scene() -> PipelineData:
    """A 4 x 3 m room: a table with a cup (free) and a monitor (fixed to it) on it, a box on the
    floor (free), a cabinet whose door turns on a tilted-frame hinge, a swivel chair (free, with a
    prismatic lift and a continuous swivel through a helper link), and two fronts found on a scan
    (a flap hinged at its top and a drawer)."""
    table = box_object(1, "table", [1.0, 0.6, 0.7], [1.0, 1.0, 0.0])
    cup = box_object(2, "cup", [0.08, 0.08, 0.1], [1.2, 1.0, 0.7])
    monitor = box_object(3, "monitor", [0.4, 0.1, 0.3], [0.8, 1.1, 0.7])
    box = box_object(4, "box", [0.3, 0.3, 0.3], [3.0, 0.5, 0.0])
    door_origin = make_pose((-0.3, -0.2, 0.0), yaw=0.0)
    cabinet = articulated(
        5, "cabinet", make_pose((3.0, 2.2, 0.0), yaw=0.5), [0.6, 0.4, 0.8], [0.6, 0.02, 0.8], door_origin,
        "revolute", [0.0, 0.0, -1.0], (0.0, 1.5),
    )  # fmt: skip
    chair = swivel_chair(6, (2.0, 1.8, 0.0))
    flap = ObjectInstance(
        7, "cabinet", np.zeros((4, 3)), OrientedBox([0.5, 2.9, 1.5], 0.2, [0.6, 0.02, 0.4]),
        attributes={"joint": "revolute", "hinge": "top"},
    )  # fmt: skip
    drawer = ObjectInstance(
        8, "cabinet", np.zeros((4, 3)), OrientedBox([1.5, 2.9, 0.5], 0.0, [0.5, 0.02, 0.2]),
        attributes={"joint": "prismatic", "hinge": None},
    )  # fmt: skip
    data = PipelineData()
    data.map = room_map()
    instances = ObjectInstances([table, cup, monitor, box, cabinet, chair, flap, drawer])
    data.map.instances = instances
    data.map.contact_graph = graph_of(instances, {2: 1, 3: 1})
    return data


def urdf_scene(path) -> tuple[dict, dict, dict]:
    """The URDF's links (name -> element), joints (name -> element) and each link's world pose."""
    robot = ET.parse(path).getroot()
    links = {el.get("name"): el for el in robot.findall("link")}
    joints = {el.get("name"): el for el in robot.findall("joint")}
    by_child = {el.find("child").get("link"): el for el in joints.values()}

    def origin(el) -> np.ndarray:
        o = el.find("origin")
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in o.get("rpy").split()]).as_matrix()
        pose[:3, 3] = [float(v) for v in o.get("xyz").split()]
        return pose

    poses = {"world": np.eye(4)}

    def pose_of(name: str) -> np.ndarray:
        if name not in poses:
            joint = by_child[name]
            poses[name] = pose_of(joint.find("parent").get("link")) @ origin(joint)
        return poses[name]

    for name in links:
        pose_of(name)
    return links, joints, {"poses": poses, "origin": origin, "by_child": by_child}


def usd_pose(prim) -> np.ndarray:
    from pxr import Usd, UsdGeom

    # Gf matrices act on row vectors: transposed, a pose acting on column vectors.
    return np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())).T


def frame_pose(position, orientation) -> np.ndarray:
    pose = np.eye(4)
    q = orientation
    pose[:3, :3] = Rotation.from_quat([*q.GetImaginary(), q.GetReal()]).as_matrix()
    pose[:3, 3] = list(position)
    return pose


def physics(stage):
    from pxr import Sdf, UsdPhysics

    parsed = UsdPhysics.UsdPhysicsLoadStageFromPrimRange(stage, [Sdf.Path("/World")])
    return {kind: dict(zip([str(p) for p in paths], descs)) for kind, (paths, descs) in parsed.items()}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    pytest.importorskip("pxr")
    from pxr import Usd

    out = tmp_path_factory.mktemp("usd")
    data = scene()
    urdf = URDFExporter().run(data, out)[0]
    (usda,) = USDExporter().run(data, out)
    return urdf, usda, Usd.Stage.Open(str(usda))


def test_the_usd_stage_has_the_urdfs_bodies_colliders_masses_and_poses(exported):
    from pxr import UsdPhysics

    urdf, _, stage = exported
    links, joints, tree = urdf_scene(urdf)
    parsed = physics(stage)
    kinds = UsdPhysics.ObjectType
    slabs = {n for n, el in links.items() if el.find("visual/geometry/box") is not None}
    assert {"floor", "ceiling", "wall_0"} <= slabs
    objects = set(links) - slabs - {"world"}
    bodies = {stage.GetPrimAtPath(p).GetName(): (p, d) for p, d in parsed[kinds.RigidBody].items()}
    # Every URDF link but the world is a body: the objects' links and the room's (kinematic) slabs.
    assert set(bodies) == objects | slabs and len(parsed[kinds.RigidBody]) == len(set(links) - {"world"})
    assert all(bodies[n][1].kinematicBody for n in slabs)
    for name, (path, desc) in ((n, bodies[n]) for n in objects):
        prim = stage.GetPrimAtPath(path)
        np.testing.assert_allclose(usd_pose(prim), tree["poses"][name], atol=1e-5, err_msg=name)
        assert len(desc.collisions) == len(links[name].findall("collision")), name
        mass = float(links[name].find("inertial/mass").get("value"))
        assert UsdPhysics.MassAPI(prim).GetMassAttr().Get() == pytest.approx(mass, rel=1e-5), name
    # The room's slabs: boxes of the URDF's sizes at its poses, each the collider of its own body.
    cubes = parsed[kinds.CubeShape]
    assert {stage.GetPrimAtPath(p).GetName() for p in cubes} == slabs
    for path, desc in cubes.items():
        name = stage.GetPrimAtPath(path).GetName()
        assert str(desc.rigidBody) == str(path).rsplit("/", 1)[0]
        size = [float(v) for v in links[name].find("collision/geometry/box").get("size").split()]
        # A unit cube scaled to the slab's size, at the URDF slab's pose.
        np.testing.assert_allclose(
            usd_pose(stage.GetPrimAtPath(path)), tree["poses"][name] @ np.diag([*size, 1.0]), atol=1e-5
        )
        np.testing.assert_allclose(list(desc.localScale), size, atol=1e-6)
    assert len(parsed[kinds.MeshShape]) == sum(len(links[n].findall("collision")) for n in objects)
    # Free bodies are the URDF's floating joints' children: dynamic, held by no joint; bodies fixed
    # to the world outside an articulation are kinematic.
    floating = {el.find("child").get("link") for el in joints.values() if el.get("type") == "floating"}
    assert {"cup_2", "box_4", "chair_6"} <= floating
    held = {stage.GetPrimAtPath(str(d.body1)).GetName() for kind in parsed for d in parsed[kind].values()
            if hasattr(d, "body1")}  # fmt: skip
    free = {n for n, (_, d) in bodies.items() if not d.kinematicBody and n not in held}
    assert free == floating
    kinematic = {n for n, (_, d) in bodies.items() if d.kinematicBody}
    assert kinematic == {"table_1", "monitor_3"} | slabs


def test_the_usd_stage_has_the_urdfs_joints_limits_and_articulations(exported):
    from pxr import UsdPhysics

    urdf, _, stage = exported
    links, joints, tree = urdf_scene(urdf)
    parsed = physics(stage)
    kinds = UsdPhysics.ObjectType
    usd_joints = {
        stage.GetPrimAtPath(p).GetName(): d
        for kind in (kinds.RevoluteJoint, kinds.PrismaticJoint)
        for p, d in parsed[kind].items()
    }
    moving = {n: el for n, el in joints.items() if el.get("type") in ("revolute", "continuous", "prismatic")}
    assert len(moving) == 5 and set(usd_joints) == set(moving)
    for name, el in moving.items():
        desc = usd_joints[name]
        kind = el.get("type")
        assert desc.type == (kinds.PrismaticJoint if kind == "prismatic" else kinds.RevoluteJoint), name
        parent, child = el.find("parent").get("link"), el.find("child").get("link")
        body0 = stage.GetPrimAtPath(str(desc.body0)).GetName() if not desc.body0.isEmpty else "world"
        assert (body0, stage.GetPrimAtPath(str(desc.body1)).GetName()) == (parent, child), name
        # The joint frame from either body is the URDF's joint frame, its X the URDF's axis.
        expected = tree["poses"][parent] @ tree["origin"](el)
        world0 = tree["poses"][parent] @ frame_pose(desc.localPose0Position, desc.localPose0Orientation)
        world1 = tree["poses"][child] @ frame_pose(desc.localPose1Position, desc.localPose1Orientation)
        axis = expected[:3, :3] @ [float(v) for v in el.find("axis").get("xyz").split()]
        for frame in (world0, world1):
            np.testing.assert_allclose(frame[:3, 3], expected[:3, 3], atol=1e-5, err_msg=name)
            np.testing.assert_allclose(frame[:3, 0], axis / np.linalg.norm(axis), atol=1e-5, err_msg=name)
        lower, upper = float(el.find("limit").get("lower")), float(el.find("limit").get("upper"))
        if kind == "continuous":
            assert not desc.limit.enabled, name
        else:
            scale = 180.0 / np.pi if kind == "revolute" else 1.0
            assert desc.limit.enabled, name
            assert desc.limit.lower == pytest.approx(lower * scale, rel=1e-5, abs=1e-4), name
            assert desc.limit.upper == pytest.approx(upper * scale, rel=1e-5, abs=1e-4), name
        assert desc.drive.enabled and desc.drive.damping > 0 and desc.drive.stiffness == 0, name
    assert usd_joints["cabinet_5__part_hinge"].limit.upper == pytest.approx(np.degrees(1.5), abs=1e-4)
    # The articulated completions are articulations (the fronts, one body on a world joint, are not).
    articulations = {stage.GetPrimAtPath(p).GetName(): d for p, d in parsed[kinds.Articulation].items()}
    assert set(articulations) == {"cabinet_5", "chair_6"}
    named = {n: {stage.GetPrimAtPath(str(b)).GetName() for b in d.articulatedBodies if not b.isEmpty}
             for n, d in articulations.items()}  # fmt: skip
    assert named == {"cabinet_5": {"cabinet_5", "cabinet_5__part"},
                     "chair_6": {"chair_6", "chair_6__helper", "chair_6__seat"}}  # fmt: skip
    # The fixed-base cabinet is welded to the world; the chair is a floating-base articulation.
    (weld,) = parsed[kinds.FixedJoint].values()
    assert weld.body0.isEmpty and stage.GetPrimAtPath(str(weld.body1)).GetName() == "cabinet_5"


def test_stage_metadata_and_gravity(exported):
    from pxr import UsdGeom, UsdPhysics

    _, usda, stage = exported
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdPhysics.GetStageKilogramsPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath().pathString == "/World"
    (scene_desc,) = physics(stage)[UsdPhysics.ObjectType.Scene].values()
    np.testing.assert_allclose(list(scene_desc.gravityDirection), [0, 0, -1])
    assert scene_desc.gravityMagnitude == pytest.approx(9.81)
    assert usda.read_text().startswith("#usda 1.0")


def test_a_usdc_file_name_writes_a_binary_crate_with_the_same_scene(tmp_path, exported):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdPhysics

    (path,) = USDExporter(filename="scene.usdc").run(scene(), tmp_path)
    assert path == tmp_path / "scene.usdc" and path.read_bytes().startswith(b"PXR-USDC")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.usdc"]  # no temporary file left
    counts = {k: len(v) for k, v in physics(Usd.Stage.Open(str(path))).items()}
    assert counts == {k: len(v) for k, v in physics(exported[2]).items()}
    assert counts[UsdPhysics.ObjectType.RigidBody] == 17  # 11 objects' links and 6 room slabs


@pytest.mark.parametrize("filename", ["scene.obj", "scene", "sub/scene.usda"])
def test_a_file_name_usd_cannot_write_is_a_config_error(filename):
    with pytest.raises(ValueError, match="must be a file name ending in .usda, .usdc, .usd"):
        USDConfig(filename=filename)


def test_without_usd_core_the_stage_names_the_extra_and_writes_nothing(tmp_path, monkeypatch):
    # As if usd-core were not installed: every pxr module import fails.
    for name in [m for m in sys.modules if m == "pxr" or m.startswith("pxr.")] + ["pxr"]:
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(PluginError, match=r"^the usd exporter needs usd-core .*: pip install 'stratamap\[usd\]'$"):
        USDExporter().run(scene(), tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_importing_the_exporter_does_not_load_pxr():
    code = "import sys, stratamap.plugins.exporters.usd; print('pxr' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"


def test_on_a_mapped_synthetic_room_the_usd_stage_has_the_urdfs_bodies_and_colliders(tmp_path):
    """The conformance kit's small pipeline (synthetic room, oracle, TSDF, bbox, contact graph)."""
    pytest.importorskip("pxr")
    from pxr import Usd, UsdPhysics

    data = example_data(set(USDExporter.requires) | set(USDExporter.optional))
    links, joints, _ = urdf_scene(URDFExporter().run(data, tmp_path)[0])
    parsed = physics(Usd.Stage.Open(str(USDExporter().run(data, tmp_path)[0])))
    kinds = UsdPhysics.ObjectType
    slabs = {n for n, el in links.items() if el.find("visual/geometry/box") is not None}
    objects = set(links) - slabs - {"world"}
    assert len(objects) >= 4 and len(parsed[kinds.RigidBody]) == len(objects) + len(slabs)
    assert len(parsed[kinds.CubeShape]) == len(slabs) >= 1
    assert len(parsed[kinds.MeshShape]) == sum(len(links[n].findall("collision")) for n in objects)
    free = [b for b in parsed[kinds.RigidBody].values() if not b.kinematicBody]
    assert len(free) == sum(el.get("type") == "floating" for el in joints.values()) >= 1


@parametrize_with_checks([USDExporter])
def test_usd_exporter_conforms(stage_cls, check):
    pytest.importorskip("pxr")
    check(stage_cls)
