"""The contact graph's refined box grows an object seen from one side only into the space the frames
never saw free (core/map/visibility.py, contact_graph.grow_into_unseen), on depth frames ray-cast
from hand-made scenes."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
import trimesh

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import Geometry, ObjectInstance, ObjectInstances, Semantics
from stratamap.core.map.priors import least_usual_depth
from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame, SensorStream
from stratamap.core.map.visibility import FreeSpace
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.contact_graph import ContactGraphMapper, grow_into_unseen

INTRINSICS = CameraIntrinsics(160, 120, 120.0, 120.0, 80.0, 60.0)


def slab(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    mesh = trimesh.creation.box(extents=hi - lo)
    mesh.apply_translation((lo + hi) / 2)
    return mesh


def look_at(eye, target) -> np.ndarray:
    """Camera (optical: x right, y down, z forward) to world."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = eye
    return pose


def depth_of(meshes, pose) -> np.ndarray:
    """The depth image (z along the optical axis, 0 where nothing is hit) of ``meshes`` from ``pose``."""
    scene = o3d.t.geometry.RaycastingScene()
    for mesh in meshes:
        scene.add_triangles(
            o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)), o3d.core.Tensor(np.asarray(mesh.faces, np.uint32))
        )
    rays = scene.create_rays_pinhole(
        o3d.core.Tensor(INTRINSICS.matrix), o3d.core.Tensor(np.linalg.inv(pose)), INTRINSICS.width, INTRINSICS.height
    )
    t_hit = scene.cast_rays(rays)["t_hit"].numpy()
    directions = rays.numpy()[..., 3:]
    along = directions @ pose[:3, 2]
    depth = np.where(np.isfinite(t_hit), t_hit * along, 0.0)
    return depth.astype(np.float32)


def surface_points(mesh: trimesh.Trimesh, count: int = 4000) -> np.ndarray:
    return np.asarray(trimesh.sample.sample_surface_even(mesh, count, seed=0)[0])


FLOOR = slab((-3, -3, -0.02), (3, 3, 0.0))
TABLE_TOP = slab((-0.8, 0.0, 0.72), (0.8, 0.9, 0.75))
#: A chair pushed in under the table: its back at the table's edge, its seat under the top.
BACKREST = slab((-0.22, -0.06, 0.0), (0.22, -0.02, 0.9))
SEAT = slab((-0.22, -0.02, 0.42), (0.22, 0.42, 0.46))
#: Cameras behind the chair, eye high, looking over it at the table.
POSES = [look_at((x, -2.2, 1.5), (0.0, 0.4, 0.5)) for x in (-1.0, -0.5, 0.0, 0.5, 1.0)]


def free_space(meshes, poses=POSES) -> FreeSpace:
    return FreeSpace(INTRINSICS, [(depth_of(meshes, pose), pose) for pose in poses], stride=1)


def backrest_box():
    """What the map saw of the chair: its back, seen from behind."""
    back = surface_points(BACKREST)
    return gravity_aligned_box(back[back[:, 1] < -0.05])


def test_free_space_sees_past_what_lies_in_front_of_a_surface():
    free = free_space([FLOOR, TABLE_TOP, BACKREST, SEAT])
    behind_the_chair = np.array([[0.0, -0.5, 0.5], [0.0, -1.0, 0.3]])
    under_the_table = np.array([[0.0, 0.2, 0.3], [0.0, 0.4, 0.55]])
    beside = np.array([[3.5, -0.5, 0.5]])  # outside every view
    counts = free.seen_free(np.vstack([behind_the_chair, under_the_table, beside]))
    assert (counts[:2] >= 2).all() and (counts[2:] == 0).all(), counts


def test_a_pushed_in_chair_grows_under_the_table_not_behind_its_back():
    box = backrest_box()
    others = np.vstack([surface_points(TABLE_TOP), surface_points(FLOOR)])
    out = grow_into_unseen(box, 0.45, free_space([FLOOR, TABLE_TOP, BACKREST, SEAT]), others)
    assert out is not None
    grown, side, reach = out
    y = grown.corners_2d()[:, 1]
    assert y.min() == pytest.approx(box.corners_2d()[:, 1].min(), abs=1e-6)  # its back stays where it was seen
    assert 0.40 <= y.max() - y.min() <= 0.46 and y.max() > 0.3, (y.min(), y.max())


def test_a_free_standing_panel_grows_only_while_one_side_is_unseen():
    """A panel on its own seen from behind grows forward (the space in front was never seen); seen
    from the front too, it is as thin as it looks."""
    floor = surface_points(FLOOR)
    from_behind = grow_into_unseen(backrest_box(), 0.45, free_space([FLOOR, BACKREST]), floor)
    assert from_behind is not None and from_behind[1:] == (1, pytest.approx(0.45 - backrest_box().size[1], abs=1e-6))
    poses = POSES + [look_at((x, 2.5, 1.5), (0.0, 0.0, 0.5)) for x in (-1.0, 0.0, 1.0)]
    assert grow_into_unseen(backrest_box(), 0.45, free_space([FLOOR, BACKREST], poses), floor) is None


def test_growth_stops_at_another_surface():
    """A cabinet's front seen from the room, a wall 20 cm behind it: its box stops at the wall."""
    front = slab((-0.4, -0.02, 0.0), (0.4, 0.0, 0.8))
    wall = slab((-2.0, 0.2, 0.0), (2.0, 0.22, 2.4))
    poses = [look_at((x, -2.5, 1.4), (0.0, 0.0, 0.4)) for x in (-1.0, 0.0, 1.0)]
    free = free_space([FLOOR, front, wall], poses)
    seen = surface_points(front)
    box = gravity_aligned_box(seen[seen[:, 1] < -0.015])
    grown, _, _ = grow_into_unseen(box, 0.6, free, np.vstack([surface_points(wall, 8000), surface_points(FLOOR)]))
    y = grown.corners_2d()[:, 1]
    assert 0.15 <= y.max() <= 0.25, y.max()


def chair_scene(name: str) -> PipelineData:
    """The pushed-in chair's back as an instance named ``name``, the table top, the floor, and the
    frames that saw them."""
    vocab = Vocabulary.default()
    back = surface_points(BACKREST)
    back = back[back[:, 1] < -0.05]
    top, floor = surface_points(TABLE_TOP), surface_points(FLOOR)
    instances = ObjectInstances(
        [
            ObjectInstance(1, name, back, gravity_aligned_box(back)),
            ObjectInstance(2, "table", top, gravity_aligned_box(top)),
        ]
    )
    points = np.vstack([back, top, floor])
    classes = np.concatenate(
        [
            np.full(len(back), vocab.id(name)),
            np.full(len(top), vocab.id("table")),
            np.full(len(floor), vocab.id("floor")),
        ]
    )
    ids = np.concatenate([np.full(len(back), 1), np.full(len(top), 2), np.zeros(len(floor))])
    meshes = [FLOOR, TABLE_TOP, BACKREST, SEAT]
    frames = [
        RGBDFrame(k, float(k), np.zeros((120, 160, 3), np.uint8), depth_of(meshes, pose), pose)
        for k, pose in enumerate(POSES)
    ]
    data = PipelineData(stream=SensorStream("chair", INTRINSICS, frames))
    data.map.instances = instances
    data.map.geometry = Geometry(points=points)
    data.map.semantics = Semantics(classes.astype(np.int32), ids.astype(np.int32), vocab)
    return data


def test_the_contact_graph_refines_a_pushed_in_chair_and_says_so():
    data = chair_scene("chair")
    graph = ContactGraphMapper().run(data)["contact_graph"]
    refined = graph.support.nodes[1]["box_refined"]
    assert 0.40 <= min(refined["size"][:2]) <= 0.46
    assert "box_refined" not in graph.support.nodes[2] or min(graph.support.nodes[2]["box_refined"]["size"][:2]) >= 0.89
    assert set(data.notes["contact_graph"]["grown_into_unseen"]) == {1}
    off = ContactGraphMapper(grow_unseen=False).run(data)["contact_graph"]
    assert "box_refined" not in off.support.nodes[1] or min(off.support.nodes[1]["box_refined"]["size"][:2]) < 0.1


def test_an_unnamed_back_on_the_floor_grows_to_the_shallowest_furniture_of_its_height():
    """Named nothing, the chair's back (0.9 m high, on the floor) is taken to be as deep as the
    shallowest class standing that high (priors.least_usual_depth: cabinets and benches, 0.35 m)."""
    assert least_usual_depth(0.9) == pytest.approx(0.35)
    graph = ContactGraphMapper().run(chair_scene("object"))["contact_graph"]
    assert min(graph.support.nodes[1]["box_refined"]["size"][:2]) == pytest.approx(0.35, abs=0.01)


def test_a_back_hidden_on_both_sides_grows_both_ways_alike():
    """A chair's back between two table tops, seen from above only: the space beside it is hidden on
    both sides, so it grows both ways alike, its centre kept."""
    tops = [slab((-0.8, -0.6, 0.72), (0.8, -0.07, 0.75)), slab((-0.8, -0.01, 0.72), (0.8, 0.5, 0.75))]
    poses = [look_at((x, y, 2.8), (0.0, -0.04, 0.0)) for x, y in ((-0.6, -0.3), (0.6, 0.3), (0.0, 0.4), (0.0, -0.5))]
    free = free_space([FLOOR, BACKREST, *tops], poses)
    box = backrest_box()
    others = np.vstack([surface_points(t) for t in tops] + [surface_points(FLOOR)])
    grown, side, reach = grow_into_unseen(box, 0.45, free, others)
    assert side == 0 and reach == pytest.approx(0.45 - box.size[1], abs=1e-6)
    assert np.allclose(grown.center, box.center) and grown.size[1] == pytest.approx(0.45, abs=1e-6)
