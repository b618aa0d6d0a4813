"""The viewer's scene, built from a small hand-made map: colour modes, subsampling, forward kinematics of
articulated models, floor textures, the contact graph and the text shown for a clicked object."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stratamap.core.errors import DataError
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.instances import set_naming
from stratamap.core.map.layers import Joint
from stratamap.core.viewer.scene import (
    COSTMAP_TEXTURE,
    UNLABELLED_GREY,
    build_scene,
    display_indices,
    find_map_dir,
    joint_motion,
    load_scene,
    object_info,
    part_poses,
    quaternion_wxyz,
    yaw_wxyz,
)
from tests.core.viewer.conftest import DOOR_WIDTH


def test_find_map_dir_accepts_a_run_folder_or_a_map_folder_and_names_anything_else(small_map, tmp_path):
    small_map.save(tmp_path / "run" / "map")
    assert find_map_dir(tmp_path / "run") == tmp_path / "run" / "map"
    assert find_map_dir(tmp_path / "run" / "map") == tmp_path / "run" / "map"
    (tmp_path / "other").mkdir()
    with pytest.raises(DataError, match=r"other: not a stratamap map \(no manifest.json here or in map/\)"):
        find_map_dir(tmp_path / "other")
    with pytest.raises(DataError, match="missing: no such file or folder"):
        find_map_dir(tmp_path / "missing")
    m, scene = load_scene(tmp_path / "run")
    assert len(m.instances) == 4 and scene.source == tmp_path / "run" / "map"


def test_colour_modes_follow_rgb_class_and_instance(small_map):
    scene = build_scene(small_map)
    sem = small_map.semantics
    assert len(scene.points) == len(small_map.geometry) == scene.total_points
    np.testing.assert_array_equal(scene.colors["rgb"], (small_map.geometry.colors * 255).round().astype(np.uint8))
    for mode, ids in (("class", sem.class_ids), ("instance", sem.instance_ids)):
        colors = scene.colors[mode]
        for value in np.unique(ids):  # one colour per class (instance), distinct between them
            assert len(np.unique(colors[ids == value], axis=0)) == 1
        assert len(np.unique(colors, axis=0)) == len(np.unique(ids))
    floor = sem.instance_ids == 0  # no instance: the unlabelled grey
    np.testing.assert_array_equal(scene.colors["instance"][floor][0], (UNLABELLED_GREY * 255).round())


def test_subsampling_is_even_deterministic_and_keeps_the_extent(small_map):
    keep = display_indices(100_000, 1000)
    assert len(keep) == 1000 and keep[0] == 0 and keep[-1] == 99_999
    assert np.array_equal(keep, display_indices(100_000, 1000)) and np.all(np.diff(keep) > 0)
    assert np.ptp(np.diff(keep)) <= 1  # evenly spaced
    scene = build_scene(small_map, max_points=500)
    assert len(scene.points) == 500 and scene.total_points == len(small_map.geometry)
    assert all(len(c) == 500 for c in scene.colors.values())
    assert np.allclose(scene.points.min(0), small_map.geometry.points.min(0), atol=0.2)
    with pytest.raises(DataError, match="max_points"):
        build_scene(small_map, max_points=0)


def test_completed_view_replaces_observed_points_by_models(small_map):
    scene = build_scene(small_map)
    completed = scene.visible_points("completed")
    hidden = set(np.unique(scene.point_instance_ids[~completed]))
    assert hidden == {1, 3}  # the table and the cabinet have models; the box and the plant keep their points
    assert scene.visible_points("observed").all() and scene.visible_points("both").all()
    views = {obj.id: obj for obj in scene.objects}
    assert [p.name for p in views[3].parts] == ["body", "door", "drawer"]
    assert [p.name for p in views[1].parts] == ["body"] and not views[1].joints
    assert not views[2].parts and views[2].pose is None
    assert [(j.name, j.lower, j.upper) for j in views[3].joints] == [
        ("door_hinge", 0.0, np.pi / 2),
        ("drawer_slide", 0.0, 0.3),
    ]


def test_joint_motion_follows_urdf_semantics():
    hinge = Joint("h", "revolute", "body", "door", np.eye(4), (0, 0, 1), 0, 2)
    np.testing.assert_allclose(joint_motion(hinge, np.pi / 2)[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    slide = Joint("s", "prismatic", "body", "drawer", np.eye(4), (0, -1, 0), 0, 0.3)
    np.testing.assert_allclose(joint_motion(slide, 0.25)[:3, 3], [0, -0.25, 0])
    fixed = Joint("f", "fixed", "body", "leg", np.eye(4), (0, 0, 1))
    np.testing.assert_array_equal(joint_motion(fixed, 1.0), np.eye(4))


def test_forward_kinematics_opens_the_door_about_its_hinge_and_pulls_the_drawer(small_map):
    completion = small_map.instances[3].completion
    rest = part_poses(completion)
    for part in completion.parts:  # joints at 0: every part where the map saved it
        np.testing.assert_allclose(rest[part.name], part.pose, atol=1e-12)
    opened = part_poses(completion, {"door_hinge": np.pi / 2, "drawer_slide": 0.3})
    np.testing.assert_allclose(opened["body"], rest["body"])
    door = next(p for p in completion.parts if p.name == "door").mesh.vertices
    moved = door @ opened["door"][:3, :3].T + opened["door"][:3, 3]
    before = door @ rest["door"][:3, :3].T + rest["door"][:3, 3]
    hinge = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.5, 1.0]])  # on the joint axis, in the door's frame
    np.testing.assert_allclose(hinge @ opened["door"].T, hinge @ rest["door"].T, atol=1e-12)  # the hinge stays put
    # Closed, the door spans x in the front plane; opened a quarter turn it sticks out in front (-y), its width intact.
    assert np.ptp(before[:, 0]) == pytest.approx(DOOR_WIDTH) and np.ptp(before[:, 1]) == pytest.approx(0.02)
    assert np.ptp(moved[:, 1]) == pytest.approx(DOOR_WIDTH) and np.ptp(moved[:, 0]) == pytest.approx(0.02)
    assert moved[:, 1].min() == pytest.approx(-0.21 - DOOR_WIDTH) and moved[:, 1].max() == pytest.approx(-0.21)
    shift = opened["drawer"][:3, 3] - rest["drawer"][:3, 3]
    np.testing.assert_allclose(shift, [0.0, -0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(opened["drawer"][:3, :3], np.eye(3), atol=1e-12)


def test_floor_textures_lay_cells_where_the_grid_says(small_map):
    scene = build_scene(small_map)
    assert set(scene.textures) == {"slam", "multimap", COSTMAP_TEXTURE}
    slam = scene.textures["slam"]
    assert (slam.width, slam.height) == pytest.approx((4.0, 3.0))
    np.testing.assert_allclose(slam.center, [2.0, 1.5, scene.floor_z - 0.01])
    assert scene.floor_z == pytest.approx(0.0)
    factor = slam.image.shape[0] // 60
    assert slam.image.shape[:2] == (60 * factor, 80 * factor)
    # Row 0 is the lowest y (viser lays an image's first row at -y): the unknown corner is in the last rows.
    assert slam.image[-1, -1, 0] == 150 and slam.image[0, -1, 0] == 235
    assert slam.image[0, 0, 0] < 60  # the occupied wall column is dark
    cost = scene.textures[COSTMAP_TEXTURE].image
    assert tuple(cost[0, 0]) == (220, 0, 220)  # lethal: magenta
    assert tuple(cost[0, -1]) == (240, 240, 240)  # free, far from the wall


def test_contact_graph_edges_join_object_centers(small_map):
    scene = build_scene(small_map)
    assert scene.support_edges.shape == (1, 2, 3)  # table -> box; layout supporters have no box to draw from
    np.testing.assert_allclose(scene.support_edges[0, 0], small_map.instances[1].box.center, atol=1e-6)
    np.testing.assert_allclose(scene.support_edges[0, 1], small_map.instances[2].box.center, atol=1e-6)
    assert scene.proximal_edges.shape == (1, 2, 3)


def test_object_info_tells_class_points_model_fit_scale_supporter_and_joints(small_map):
    text = object_info(small_map, small_map.instances[3])
    for expected in (
        "**cabinet 3**",
        "| points | 300 observed |",
        "cabinet_test (test)",
        "| fit score | 0.0123 |",
        "1.000 x 1.000 x 1.250",
        "| supporter | floor |",
        "door_hinge | revolute (body -> door, 0 .. 1.57)",
        "drawer_slide | prismatic (body -> drawer, 0 .. 0.3)",
    ):
        assert expected in text, (expected, text)
    box = object_info(small_map, small_map.instances[2])
    assert "| supporter | table 1 |" in box and "| model | not completed |" in box and "| joints | none |" in box
    assert "| named by | - |" in box  # no stage said
    named = dataclasses.replace(small_map.instances[2], attributes={})
    set_naming(named, "shape", "on a support, its size")
    assert "| named by | shape: on a support, its size |" in object_info(small_map, named)
    assert "| supports | box 2 |" in object_info(small_map, small_map.instances[1])


def test_quaternions_are_scalar_first():
    np.testing.assert_allclose(quaternion_wxyz(np.eye(3)), [1, 0, 0, 0])
    q = quaternion_wxyz(make_pose(yaw=0.7)[:3, :3])
    np.testing.assert_allclose(q, yaw_wxyz(0.7), atol=1e-12)
    np.testing.assert_allclose(q, [np.cos(0.35), 0, 0, np.sin(0.35)], atol=1e-12)


def test_a_map_without_geometry_shows_its_objects_points(small_map):
    small_map.geometry, small_map.semantics = None, None
    scene = build_scene(small_map)
    assert len(scene.points) == sum(len(i.points) for i in small_map.instances)
    assert set(np.unique(scene.point_instance_ids)) == {1, 2, 3, 4}
    assert len(np.unique(scene.colors["class"], axis=0)) == 4
