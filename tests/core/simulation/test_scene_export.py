"""Scenes for simulators on hand-made maps: convex collision parts, the room's slabs, the rest plan,
geometry-less helper links and segmented fronts."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh

from stratamap.core.map.layers import (
    Completion,
    Geometry,
    Joint,
    LayeredMap,
    ObjectInstance,
    ObjectInstances,
    OrientedBox,
    Part,
    Semantics,
)
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.simulation.kinematics import build_tree, front_joint
from stratamap.core.simulation.physics import MIN_PART_THICKNESS, collision_parts
from stratamap.core.simulation.rest import REST_GAP, rest_offsets
from stratamap.core.simulation.structure import SLAB_THICKNESS, room_structure
from stratamap.core.stages import PipelineData
from tests.core.simulation.test_physics import box_object, graph_of


def test_a_flat_piece_becomes_a_thin_box_and_a_solid_one_its_hull():
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    (part,) = collision_parts(flat)
    assert part.is_volume and min(part.extents) == pytest.approx(MIN_PART_THICKNESS)
    solid = trimesh.creation.icosphere(radius=0.2)
    (hull,) = collision_parts(solid)
    assert hull.is_volume and hull.volume == pytest.approx(solid.volume, rel=1e-6)


def room_map(width=4.0, depth=3.0, height=2.5) -> LayeredMap:
    """Floor, four walls and a ceiling as labelled points of a width x depth room at the origin."""
    rng = np.random.default_rng(0)
    n = 3000
    floor = np.c_[rng.uniform(0, width, n), rng.uniform(0, depth, n), np.zeros(n)]
    ceiling = floor + [0, 0, height]
    z = rng.uniform(0, height, n)
    walls = np.concatenate(
        [
            np.c_[rng.uniform(0, width, n), np.zeros(n), z],
            np.c_[rng.uniform(0, width, n), np.full(n, depth), z],
            np.c_[np.zeros(n), rng.uniform(0, depth, n), z],
            np.c_[np.full(n, width), rng.uniform(0, depth, n), z],
        ]
    )
    vocab = Vocabulary.default()
    points = np.concatenate([floor, ceiling, walls])
    classes = np.concatenate(
        [np.full(n, vocab.id("floor")), np.full(n, vocab.id("ceiling")), np.full(len(walls), vocab.id("wall"))]
    )
    layered = LayeredMap()
    layered.geometry = Geometry(points)
    layered.semantics = Semantics(classes, np.zeros(len(points)), vocab)
    layered.instances = ObjectInstances()
    return layered


def test_room_slabs_lie_outside_the_room():
    slabs = {s.name: s for s in room_structure(room_map())}
    assert {"floor", "ceiling"} <= set(slabs) and sum(n.startswith("wall_") for n in slabs) == 4
    assert slabs["floor"].pose[2, 3] + slabs["floor"].size[2] / 2 == pytest.approx(0.0, abs=1e-9)
    assert slabs["ceiling"].pose[2, 3] - SLAB_THICKNESS / 2 == pytest.approx(2.5, abs=1e-6)
    for slab in slabs.values():
        if slab.class_name != "wall":
            continue
        center = slab.pose[:3, 3]
        # Each wall's slab is just outside one side of the 4 x 3 room, spanning it.
        outside = min(abs(center[0] + SLAB_THICKNESS / 2), abs(center[0] - 4 - SLAB_THICKNESS / 2))
        outside = min(outside, abs(center[1] + SLAB_THICKNESS / 2), abs(center[1] - 3 - SLAB_THICKNESS / 2))
        assert outside < 0.01 and slab.size[0] > 2.5


def test_rest_plan_drops_floating_objects_and_keeps_overlapping_ones_static():
    table = box_object(1, "table", [1.0, 0.6, 0.7], [0.0, 0.0, 0.0])
    cup = box_object(2, "cup", [0.08, 0.08, 0.1], [0.1, 0.0, 0.75])  # 5 cm above the table
    box = box_object(3, "box", [0.3, 0.3, 0.3], [2.0, 0.0, 0.04])  # 4 cm above the floor
    stuck = box_object(4, "box", [0.3, 0.3, 0.3], [0.4, 0.1, 0.5])  # half inside the table top
    overhang = box_object(5, "book", [0.3, 0.2, 0.03], [0.58, -0.2, 0.7])  # mostly off the table's edge
    instances = ObjectInstances([table, cup, box, stuck, overhang])
    graph = graph_of(instances, {2: 1, 4: 1, 5: 1})
    layered = room_map()
    slabs = [s for s in room_structure(layered) if s.name == "floor"]
    plan = rest_offsets(instances, graph, ["cup", "box", "book"], slabs)
    assert plan.offsets[2][2] == pytest.approx(-0.05 + REST_GAP, abs=1e-6)
    assert plan.offsets[3][2] == pytest.approx(-0.04 + REST_GAP, abs=1e-6)
    assert "penetrate" in plan.static[4] and "centre of mass" in plan.static[5]
    assert plan.free_ids(instances, ["cup", "box", "book"]) == {2, 3}
    tree = build_tree(instances, graph, offsets=plan.offsets, floating_ids={2, 3})
    joints = {j.child: j for j in tree.joints}
    assert joints["cup_2"].type == "floating" and joints["cup_2"].parent == "world"
    assert joints["box_4"].type == "fixed" and joints["box_4"].parent == "table_1"
    assert joints["cup_2"].origin[2, 3] == pytest.approx(0.7 + REST_GAP)


def test_the_rest_plan_is_what_mujoco_keeps_at_rest(tmp_path):
    pytest.importorskip("mujoco")
    from stratamap.core.simulation.mjcf import write_mjcf
    from stratamap.core.simulation.physics import settle

    table = box_object(1, "table", [1.0, 0.6, 0.7], [1.5, 1.5, 0.0])
    cup = box_object(2, "cup", [0.08, 0.08, 0.1], [1.6, 1.5, 0.8])
    chair = box_object(3, "chair", [0.5, 0.5, 0.9], [3.0, 1.5, 0.1])
    instances = ObjectInstances([table, cup, chair])
    graph = graph_of(instances, {2: 1})
    path = write_mjcf(instances, tmp_path, graph=graph, statics=room_structure(room_map()), rest=True)[0]
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] == 2 and result["max_displacement_m"] < 0.005
    root = ET.parse(path).getroot()
    assert {g.get("name") for g in root.iter("geom")} >= {"floor", "wall_0", "ceiling"}


def tilted_chair(iid: int, at, degrees: float) -> ObjectInstance:
    """A chair-sized box turned by ``degrees`` about x: it stands on one bottom edge, as a noisy
    mapped or completed bottom does."""
    size = [0.5, 0.5, 0.9]
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_translation((0, 0, size[2] / 2))
    pose = trimesh.transformations.rotation_matrix(np.radians(degrees), [1, 0, 0])
    pose[:3, 3] = at
    box = OrientedBox(np.array(at) + [0, 0, size[2] / 2], 0.0, np.array(size))
    points = trimesh.transform_points(mesh.vertices, pose)
    return ObjectInstance(iid, "chair", points, box, completion=Completion(mesh, pose, "test"))


def test_a_body_on_a_tilted_bottom_is_turned_onto_it_and_rests_in_mujoco_and_pybullet(tmp_path):
    """Dropped on one edge, a 5-degree tilted chair box rocks flat: its centre of mass moves about
    4 cm. The rest plan turns it onto its bottom first, so it starts at rest (free, not static)."""
    from stratamap.core.simulation.mjcf import write_mjcf
    from stratamap.core.simulation.rest import resting_normal

    chair = tilted_chair(1, [2.0, 1.5, 0.05], 5.0)
    instances = ObjectInstances([chair])
    graph = graph_of(instances, {})
    layered = room_map()
    layered.instances, layered.contact_graph = instances, graph
    plan = rest_offsets(instances, graph, ["chair"], room_structure(layered))
    assert plan.static == {} and set(plan.rotations) == {1}
    assert plan.to_dict()["max_tilt_deg"] == pytest.approx(5.0, abs=0.01)
    tree = build_tree(instances, graph, offsets=plan.offsets, rotations=plan.rotations, floating_ids={1})
    (joint,) = [j for j in tree.joints if j.child == "chair_1"]
    corners = trimesh.transform_points(chair.completion.mesh.vertices, joint.origin)
    assert corners[:, 2].min() == pytest.approx(REST_GAP, abs=1e-6)  # its bottom flat, just above the floor
    assert np.ptp(np.sort(corners[:, 2])[:4]) < 1e-6
    normal = resting_normal(np.asarray(chair.points), chair.points.mean(axis=0))
    np.testing.assert_allclose(normal, [0.0, np.sin(np.radians(5.0)), -np.cos(np.radians(5.0))], atol=1e-9)
    mujoco = pytest.importorskip("mujoco")
    del mujoco
    from stratamap.core.simulation.physics import settle

    path = write_mjcf(instances, tmp_path / "mjcf", graph=graph, statics=room_structure(layered), rest=True)[0]
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] == 1 and result["max_displacement_m"] < 0.005, result
    pytest.importorskip("pybullet")
    from stratamap.core.simulation import bullet
    from stratamap.plugins.exporters.urdf import URDFExporter

    (urdf, *_) = URDFExporter(bodies={"movable_classes": ["chair"]}).run(PipelineData(map=layered), tmp_path / "urdf")
    moved = bullet.settle(urdf, seconds=2.0)
    assert set(moved["displacement_m"]) == {"chair_1"} and moved["max_displacement_m"] < 0.005, moved


def test_stability_is_judged_on_the_face_a_body_stands_on_not_on_vertices_near_its_bottom():
    """A light base on the floor and a heavy block beside it whose bottom hangs 8 mm above the floor:
    the centre of mass lies 2 mm inside the base's face (less than the margin), though well inside
    the hull of every vertex within a centimetre of the bottom. It cannot be free."""
    base = trimesh.creation.box(extents=[0.4, 0.4, 0.1])
    base.apply_translation((0.0, 0.0, 0.05))
    height = 0.008 + 0.66 / 0.34 * 0.016 / (0.2 * 0.4)  # x of the centre of mass: 0.3 * 0.66 = 0.198
    block = trimesh.creation.box(extents=[0.2, 0.4, height - 0.008])
    block.apply_translation((0.3, 0.0, 0.008 + (height - 0.008) / 2))
    mesh = trimesh.util.concatenate([base, block])
    pose = np.eye(4)
    pose[:3, 3] = [2.0, 1.5, 0.0]
    points = trimesh.transform_points(mesh.vertices, pose)
    box = OrientedBox(pose[:3, 3] + [0.1, 0.0, height / 2], 0.0, np.array([0.6, 0.4, height]))
    thing = ObjectInstance(1, "box", points, box, completion=Completion(mesh, pose, "test"))
    instances = ObjectInstances([thing])
    plan = rest_offsets(instances, graph_of(instances, {}), ["box"], room_structure(room_map()))
    assert plan.static == {1: "its centre of mass is not over what it stands on"}


def articulated_with_helper() -> ObjectInstance:
    """A completed object whose seat slides on a geometry-less helper link and turns on it."""
    body = trimesh.creation.box(extents=[0.5, 0.5, 0.4])
    body.apply_translation((0, 0, 0.2))
    seat = trimesh.creation.box(extents=[0.4, 0.4, 0.05])
    lift = np.eye(4)
    lift[2, 3] = 0.45
    joints = [
        Joint("swivel", "continuous", "helper", "seat", np.eye(4), np.array([0.0, 0.0, 1.0])),
        Joint("lift", "prismatic", "body", "helper", lift, np.array([0.0, 0.0, 1.0]), 0.0, 0.1),
    ]
    parts = [Part("body", body), Part("seat", seat, lift)]
    mesh = trimesh.util.concatenate([body, seat.copy().apply_transform(lift)])
    box = OrientedBox([1.0, 1.0, 0.25], 0.0, [0.5, 0.5, 0.5])
    completion = Completion(mesh, np.eye(4), "test", parts=parts, joints=joints)
    return ObjectInstance(1, "chair", np.asarray(mesh.vertices), box, completion=completion)


def test_helper_links_without_geometry_keep_their_joints_in_the_urdf(tmp_path):
    pybullet = pytest.importorskip("pybullet")
    from stratamap.plugins.exporters.urdf import URDFExporter

    data = PipelineData()
    data.map.instances = ObjectInstances([articulated_with_helper()])
    path = URDFExporter(bodies={"structure": False}).run(data, tmp_path)[0]
    robot = ET.parse(path).getroot()
    links = {el.get("name") for el in robot.findall("link")}
    for joint in robot.findall("joint"):
        assert joint.find("parent").get("link") in links and joint.find("child").get("link") in links
    assert "chair_1__helper" in links
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
        count = pybullet.getNumJoints(body, physicsClientId=client)
        kinds = {pybullet.getJointInfo(body, k, physicsClientId=client)[2] for k in range(count)}
        assert count == 3  # the floating joint (PyBullet fixes it), the lift and the swivel
        assert {pybullet.JOINT_PRISMATIC, pybullet.JOINT_REVOLUTE} <= kinds
    finally:
        pybullet.disconnect(client)


@pytest.mark.parametrize(
    ("hinge", "edge"), [("left", (0, -1)), ("right", (0, 1)), ("top", (2, 1)), ("bottom", (2, -1))]
)
def test_a_door_opens_outwards_about_its_hinge_side(hinge, edge):
    # A 0.5 x 0.7 door facing -y (its normal), face at y = 0.
    box = OrientedBox([1.0, 0.01, 1.0], 0.0, [0.5, 0.02, 0.7])
    door = ObjectInstance(1, "cupboard", np.zeros((4, 3)), box, attributes={"joint": "revolute", "hinge": hinge})
    kind, frame, axis, lower, upper = front_joint(door)
    assert kind == "revolute" and lower == 0 and upper > 1.5
    local = frame[:3, 3] - box.center
    axis_index, sign = edge
    assert local[axis_index] == pytest.approx(sign * box.size[axis_index] / 2)
    assert local[1] == pytest.approx(-0.01)  # on the face
    # Opening a little swings the door's centre out of the furniture (towards -y).
    angle = 0.3
    k = axis / np.linalg.norm(axis)
    rotation = trimesh.transformations.rotation_matrix(angle, k)[:3, :3]
    center_in_hinge = box.center - frame[:3, 3]
    assert (rotation @ center_in_hinge)[1] < center_in_hinge[1] - 0.01
    drawer = ObjectInstance(2, "drawer", np.zeros((4, 3)), box, attributes={"joint": "prismatic", "hinge": None})
    kind, frame, axis, lower, upper = front_joint(drawer)
    assert kind == "prismatic" and np.allclose(frame[:3, :3] @ axis, [0, -1, 0]) and upper > 0


def slab_points(lo, hi, step: float = 0.01) -> np.ndarray:
    """Points filling the axis-aligned box ``lo``..``hi`` on a grid (a scanned board a step or more thick)."""
    axes = [np.arange(a, b + 1e-9, step) if b - a > step else np.array([a, b]) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def observed(iid: int, cls: str, points: np.ndarray) -> ObjectInstance:
    """An object known only by its observed points (no completion, or a rejected one)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    box = OrientedBox((lo + hi) / 2, 0.0, hi - lo)
    return ObjectInstance(iid, cls, points, box)


def shelf_book_and_one_sided_box() -> tuple[LayeredMap, ObjectInstances]:
    """A shelf seen as boards (bottom board, sides, back), a book on its bottom board, and a box seen
    only from its front and top (an inverted L of points, its back and bottom unseen). The shelf's
    lowest band of points is one connected piece, so its hull fills the compartment the book lies
    in; the box's points stand on their front edge only."""
    shelf = observed(
        1,
        "shelf",
        np.concatenate(
            [
                slab_points([1.0, 1.0, 0.0], [1.9, 1.35, 0.02]),  # bottom board
                slab_points([1.0, 1.0, 0.02], [1.02, 1.35, 0.4]),  # sides
                slab_points([1.88, 1.0, 0.02], [1.9, 1.35, 0.4]),
                slab_points([1.0, 1.33, 0.02], [1.9, 1.35, 0.4]),  # back
                slab_points([1.0, 1.0, 0.38], [1.9, 1.35, 0.4]),  # top board
            ]
        ),
    )
    book = observed(2, "book", slab_points([1.3, 1.05, 0.02], [1.55, 1.25, 0.07]))
    one_sided = observed(
        3,
        "box",
        np.concatenate(
            [
                slab_points([2.6, 1.0, 0.0], [3.0, 1.02, 0.4]),  # front, 2 cm thick
                slab_points([2.6, 1.0, 0.38], [3.0, 1.4, 0.4]),  # top
            ]
        ),
    )
    instances = ObjectInstances([shelf, book, one_sided])
    layered = room_map()
    layered.instances, layered.contact_graph = instances, graph_of(instances, {2: 1})
    return layered, instances


def test_coarse_neighbours_and_partial_shapes_do_not_keep_movable_objects_static(tmp_path):
    """The book lies inside the hull of the shelf's lowest band and the one-sided box's centre of
    mass hangs behind the edge it stands on: both used to be exported static. The shelf's part is
    cut around what was seen of the book, the box's parts are completed down to the floor; both are
    free and stay within the issue's 2 cm over 2 s in MuJoCo and in PyBullet; visuals keep the
    observed shapes."""
    layered, instances = shelf_book_and_one_sided_box()
    plan = rest_offsets(instances, layered.contact_graph, ["book", "box"], room_structure(layered))
    assert plan.static == {}, plan.static
    assert set(plan.offsets) == {2, 3} and set(plan.collision) == {1, 2, 3}
    tree = build_tree(instances, layered.contact_graph, collision=plan.collision, floating_ids={2, 3})
    links = {link.name: link for link in tree.links}

    # The box's collision parts reach the floor under its centre of mass; its visual does not.
    def base_depth(vertices: np.ndarray) -> float:  # how far front to back its lowest vertices reach
        vertices = np.asarray(vertices)
        return float(np.ptp(vertices[vertices[:, 2] < vertices[:, 2].min() + 1e-6, 1]))

    assert base_depth(trimesh.util.concatenate(links["box_3"].collision).vertices) > 0.35
    assert base_depth(links["box_3"].mesh.vertices) < 0.05
    pytest.importorskip("mujoco")
    from stratamap.core.simulation.mjcf import write_mjcf
    from stratamap.core.simulation.physics import settle

    path = write_mjcf(
        instances, tmp_path / "mjcf", graph=layered.contact_graph, statics=room_structure(layered), rest=True
    )[0]
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] == 2 and result["max_displacement_m"] < 0.02, result
    pytest.importorskip("pybullet")
    from stratamap.core.simulation import bullet
    from stratamap.plugins.exporters.urdf import URDFExporter

    (urdf, *_) = URDFExporter(bodies={"movable_classes": ["book", "box"]}).run(
        PipelineData(map=layered), tmp_path / "urdf"
    )
    moved = bullet.settle(urdf, seconds=2.0)
    assert set(moved["displacement_m"]) == {"book_2", "box_3"} and moved["max_displacement_m"] < 0.02, moved


def desk_and_chair_pushed_under_it() -> tuple[LayeredMap, ObjectInstances]:
    """A desk seen as its top, a front apron, four legs and a frame joining them at the floor, and a
    chair standing on the floor with
    its seat and the front of its legs under the desk top, its back outside. Both stand on the floor:
    the desk supports nothing."""
    desk = observed(
        1,
        "desk",
        np.concatenate(
            [
                slab_points([1.0, 1.0, 0.70], [2.2, 1.7, 0.72]),  # top
                slab_points([1.0, 1.0, 0.47], [2.2, 1.02, 0.70]),  # front apron (y = 1.0 faces the room)
                *(slab_points([x, y, 0.0], [x + 0.04, y + 0.04, 0.70]) for x in (1.0, 2.16) for y in (1.0, 1.66)),
                # a frame joining the legs at the floor: one piece with them, whose hull spans the footprint
                *(slab_points([1.0, y, 0.0], [2.2, y + 0.04, 0.02]) for y in (1.0, 1.66)),
                *(slab_points([x, 1.0, 0.0], [x + 0.04, 1.7, 0.02]) for x in (1.0, 2.16)),
            ]
        ),
    )
    chair = observed(
        2,
        "chair",
        np.concatenate(
            [
                slab_points([1.4, 0.75, 0.43], [1.85, 1.2, 0.45]),  # seat, its back half under the desk
                slab_points([1.4, 0.73, 0.45], [1.85, 0.75, 0.9]),  # back, outside the desk
                *(slab_points([x, y, 0.0], [x + 0.03, y + 0.03, 0.43]) for x in (1.4, 1.82) for y in (0.75, 1.17)),
            ]
        ),
    )
    instances = ObjectInstances([desk, chair])
    layered = room_map()
    layered.instances, layered.contact_graph = instances, graph_of(instances, {})
    return layered, instances


def test_a_chair_pushed_under_a_desk_it_does_not_stand_on_is_free():
    """The desk's hull holds the chair's legs and seat. Cut around them, the desk used to keep the
    band of its points at the chair's feet (a supporter's band, where an object's underside and its
    support mix), which spans the desk's four legs: the chair's feet stood in it and the chair was
    exported static. And the chair's coarse hull reaches from its back's top to its seat's front,
    where none of its points are: the desk is cut around the chair's collision parts too."""
    layered, instances = desk_and_chair_pushed_under_it()
    plan = rest_offsets(instances, layered.contact_graph, ["chair"], room_structure(layered))
    assert plan.static == {}, plan.static
    assert set(plan.offsets) == {2} and 1 in plan.collision
    assert np.linalg.norm(plan.offsets[2]) < 0.01  # dropped onto the floor where it stands, not pushed out


def test_a_free_body_that_a_body_kept_static_penetrates_is_kept_static_too():
    """A chair's box pushed under a table pokes up through its top (the table's observed parts are
    cut around it, so the chair alone could be free), and a box on the table reaches into it: the
    box cannot rest and stays static where it was mapped, inside the free chair, which a simulator
    would then push out (the demo's chairs moved 5 cm in PyBullet). The chair is kept static too."""
    from tests.core.simulation.test_physics import box_object

    table = observed(
        1,
        "table",
        np.concatenate(
            [
                slab_points([1.0, 1.0, 0.72], [2.2, 1.8, 0.75]),
                *(slab_points([x, y, 0.0], [x + 0.04, y + 0.04, 0.72]) for x in (1.0, 2.16) for y in (1.0, 1.76)),
            ]
        ),
    )
    chair = box_object(2, "chair", (0.5, 0.5, 0.9), (1.6, 0.9, 0.0))  # its back half under the table
    box = box_object(3, "box", (0.3, 0.3, 0.2), (1.6, 1.25, 0.75))  # on the table, over the chair's box
    instances = ObjectInstances([table, chair, box])
    layered = room_map()
    graph = graph_of(instances, {3: 1})
    plan = rest_offsets(instances, graph, ["chair", "box"], room_structure(layered))
    assert set(plan.static) == {2, 3}, plan.static
    assert "kept static" in plan.static[2] and "box 3" in plan.static[2]
    assert plan.offsets == {}


def test_the_rest_plan_is_made_once_per_scene_whatever_the_meshes_have_cached():
    """The URDF exporter fills the completion meshes' caches (normals, areas); the MJCF and SDF
    exporters of the same run must find the plan it made (issue 68: exports that reuse work)."""
    from stratamap.core.simulation import rest

    table = box_object(1, "table", [1.0, 0.6, 0.7], [1.5, 1.5, 0.0])
    cup = box_object(2, "cup", [0.08, 0.08, 0.1], [1.6, 1.5, 0.75])
    instances = ObjectInstances([table, cup])
    graph = graph_of(instances, {2: 1})
    args = (instances, graph, ["cup"], [])
    before = rest.content_digest(args)
    first = rest_offsets(*args)
    kept = len(rest._PLANS)
    cached = [(inst.completion.mesh.face_normals, inst.completion.mesh.area) for inst in instances]
    assert all(len(normals) for normals, _ in cached)  # what an exporter computes, now in the caches
    assert rest.content_digest(args) == before
    again = rest_offsets(*args)
    assert len(rest._PLANS) == kept and again.to_dict() == first.to_dict()
    cup.completion.mesh.vertices = cup.completion.mesh.vertices + [0.0, 0.0, 0.01]
    assert rest.content_digest(args) != before
