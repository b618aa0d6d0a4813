"""The viser viewer in-process (no browser): what its controls change in the scene it serves; and
`stratamap view` on bad input (a folder that is not a map, viser missing): one line, exit 2."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from stratamap.core.viewer.scene import COSTMAP_TEXTURE, build_scene, quaternion_wxyz


@pytest.fixture
def viewer(small_map):
    pytest.importorskip("viser")
    from stratamap.core.viewer.app import MapViewer

    running = MapViewer(build_scene(small_map), host="127.0.0.1", port=0)
    yield running
    running.stop()


def test_joint_slider_moves_the_part_where_forward_kinematics_puts_it(viewer, small_map):
    door = viewer._part_handles[(3, "door")]
    body = viewer._part_handles[(3, "body")]
    closed = np.array(door.wxyz), np.array(door.position)
    body_before = np.array(body.position)
    viewer.set_joint(3, "door_hinge", np.pi / 2)
    expected = viewer.scene.object(3).part_poses({"door_hinge": np.pi / 2})["door"]
    assert abs(abs(float(np.dot(door.wxyz, quaternion_wxyz(expected[:3, :3])))) - 1.0) < 1e-5
    np.testing.assert_allclose(door.position, expected[:3, 3], atol=1e-6)
    assert not np.allclose(door.wxyz, closed[0])
    np.testing.assert_allclose(body.position, body_before)  # the body does not move
    viewer.set_joint(3, "door_hinge", 0.0)
    np.testing.assert_allclose(door.wxyz, closed[0], atol=1e-9)
    np.testing.assert_allclose(door.position, closed[1], atol=1e-9)


def test_colour_mode_and_object_view_change_the_points_sent(viewer):
    scene = viewer.scene
    completed = scene.visible_points("completed")
    assert len(viewer.points.points) == completed.sum() < len(scene.points)
    viewer.set_color_mode("class")
    np.testing.assert_array_equal(viewer.points.colors, scene.colors["class"][completed])
    viewer.set_object_view("observed")
    assert len(viewer.points.points) == len(scene.points)
    assert not any(h.visible for h in viewer._part_handles.values())
    viewer.set_object_view("both")
    assert all(h.visible for h in viewer._part_handles.values()) and len(viewer.points.points) == len(scene.points)
    viewer.set_models_shown(False)
    assert not any(h.visible for h in viewer._part_handles.values())


def test_selecting_an_object_shows_its_details(viewer):
    viewer.select(3)
    assert viewer.selector.value == "cabinet 3"
    assert viewer.info.content == viewer.scene.info[3] and "door_hinge" in viewer.info.content
    viewer.select(None)
    assert "Click an object" in viewer.info.content


def test_one_ground_texture_at_a_time(viewer):
    viewer.set_texture(COSTMAP_TEXTURE)
    assert {name for name, h in viewer._texture_handles.items() if h.visible} == {COSTMAP_TEXTURE}
    viewer.set_texture("off")
    assert not any(h.visible for h in viewer._texture_handles.values())


def _view(*args: str, before: str = "") -> subprocess.CompletedProcess:
    argv = ["stratamap", "view", *args]
    code = f"import sys; {before}sys.argv = {argv!r}; from stratamap.core.cli import main; main()"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_view_of_a_folder_that_is_not_a_map_is_one_line_exit_2(tmp_path):
    result = _view(str(tmp_path))
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr and "not a stratamap map" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def test_view_without_viser_says_how_to_install_it(small_map, tmp_path):
    small_map.save(tmp_path / "map")
    result = _view(str(tmp_path), before="sys.modules['viser'] = None; ")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "pip install 'stratamap[viz]'" in result.stderr
