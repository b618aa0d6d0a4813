"""The physical check on hand-made scenes: convex shells, overlap volumes, resting and separating."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stratamap.core.map.layers import Completion, ContactGraph, ObjectInstance, ObjectInstances, OrientedBox
from stratamap.core.simulation.physics import (
    convex_shell,
    penetration_depths,
    penetration_volume,
    resolve_scene,
    world_mesh,
)


def box_object(iid: int, cls: str, size, at) -> ObjectInstance:
    """An object completed by a box of ``size`` whose bottom center is at ``at``."""
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_translation((0, 0, size[2] / 2))
    pose = np.eye(4)
    pose[:3, 3] = at
    box = OrientedBox(np.array(at) + [0, 0, size[2] / 2], 0.0, size)
    points = np.asarray(mesh.vertices) + at
    return ObjectInstance(iid, cls, points, box, completion=Completion(mesh, pose, "test"))


def graph_of(instances, parents: dict[int, object]) -> ContactGraph:
    graph = ContactGraph()
    graph.support.add_node("floor", kind="layout")
    graph.support.add_edge("scene", "floor")
    for inst in instances:
        graph.support.add_node(inst.id, kind="object")
        graph.support.add_edge(parents.get(inst.id, "floor"), inst.id)
    return graph


def test_separating_axis_depth_of_two_cubes():
    a = convex_shell(trimesh.creation.box(extents=(1, 1, 1)).vertices)
    b = convex_shell(trimesh.creation.box(extents=(1, 1, 1)).vertices + [0.7, 0, 0])
    depths = penetration_depths(a, b, np.array([[0, 0, 0], [-0.3, 0, 0], [0, 0, 1.5]]))
    np.testing.assert_allclose(depths, [0.3, 0.0, 0.0], atol=1e-9)


def test_penetration_volume_is_the_exact_overlap():
    objs = ObjectInstances(
        [box_object(1, "box", (1.0, 1.0, 1.0), (0, 0, 0)), box_object(2, "box", (1.0, 1.0, 1.0), (0.5, 0.5, 0))]
    )
    assert penetration_volume(objs) == pytest.approx(0.25, rel=1e-6)
    apart = ObjectInstances(
        [box_object(1, "box", (1.0, 1.0, 1.0), (0, 0, 0)), box_object(2, "box", (1.0, 1.0, 1.0), (1.01, 0, 0))]
    )
    assert penetration_volume(apart) == 0.0


def test_sunk_and_floating_objects_come_to_rest_on_their_supporter():
    table = box_object(1, "table", (1.2, 0.8, 0.75), (0, 0, 0.02))  # floats 2 cm above the floor
    cup = box_object(2, "cup", (0.08, 0.08, 0.1), (0.1, 0.1, 0.72))  # sunk 5 cm into the table
    book = box_object(3, "book", (0.2, 0.15, 0.03), (-0.3, 0.1, 0.80))  # hovers 3 cm above it
    objs = ObjectInstances([table, cup, book])
    result = resolve_scene(objs, graph_of(objs, {2: 1, 3: 1}))
    bottoms = {i.id: world_mesh(i).bounds[0, 2] for i in objs}
    # Each object rests half the contact tolerance (1.5 mm) above its supporter, which adds up.
    assert bottoms[1] == pytest.approx(0.0, abs=0.002)
    assert bottoms[2] == pytest.approx(0.75, abs=0.0035)
    assert bottoms[3] == pytest.approx(0.75, abs=0.0035)
    assert not any(result.residual.values())
    assert penetration_volume(objs) < 1e-7


def test_overlapping_chair_moves_to_the_nearest_free_spot_and_carries_its_load():
    desk = box_object(1, "desk", (1.4, 0.7, 0.75), (0, 0, 0))
    chair = box_object(2, "chair", (0.5, 0.5, 1.0), (0.0, 0.5, 0))  # 10 cm into the desk's front
    cushion = box_object(3, "box", (0.3, 0.3, 0.05), (0.0, 0.5, 1.0))
    objs = ObjectInstances([desk, chair, cushion])
    resolve_scene(objs, graph_of(objs, {3: 2}), step=0.01)
    shift = objs[2].completion.pose[:3, 3] - [0.0, 0.5, 0]
    assert penetration_volume(objs) < 1e-6
    # The nearest way out is straight back from the desk, 10 cm (plus contact tolerance).
    assert shift[1] == pytest.approx(0.1, abs=0.011) and abs(shift[0]) < 0.011
    np.testing.assert_allclose((objs[3].completion.pose[:3, 3] - [0.0, 0.5, 1.0])[:2], shift[:2], atol=1e-9)
    # The input map's completions are untouched when the check runs on a copy.
    fresh = ObjectInstances(
        [box_object(1, "desk", (1.4, 0.7, 0.75), (0, 0, 0)), box_object(2, "chair", (0.5, 0.5, 1.0), (0.0, 0.5, 0))]
    )
    copy = fresh.copy()
    resolve_scene(copy, graph_of(copy, {}))
    assert fresh[2].completion.pose[1, 3] == 0.5 and copy[2].completion.pose[1, 3] > 0.59


def test_unresolvable_overlap_is_reported():
    big = box_object(1, "cabinet", (2.0, 2.0, 1.0), (0, 0, 0))
    inside = box_object(2, "box", (0.3, 0.3, 0.3), (0, 0, 0))
    objs = ObjectInstances([big, inside])
    result = resolve_scene(objs, graph_of(objs, {}), max_shift=0.2)
    assert result.to_dict()["unresolved"] == [2]


def sampled(mesh: trimesh.Trimesh, offset, n: int = 3000) -> np.ndarray:
    return trimesh.sample.sample_surface_even(mesh, n, seed=0)[0] + offset


def test_contact_graph_planes_hidden_tabletop_wall_support_and_refined_boxes():
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.map.layers import Geometry, Semantics
    from stratamap.core.map.vocabulary import Vocabulary
    from stratamap.core.stages import PipelineData
    from stratamap.plugins.mappers.contact_graph import ContactGraphMapper

    table_mesh = trimesh.creation.box(extents=(1.2, 0.8, 0.04))
    table = sampled(table_mesh, (0, 0, 0.73))
    box_pts = sampled(trimesh.creation.box(extents=(0.3, 0.3, 0.2)), (0.1, 0.0, 0.85))
    box_pts = box_pts[box_pts[:, 2] > 0.76]  # its bottom face is hidden by the tabletop
    table = table[
        ~((np.abs(table[:, 0] - 0.1) < 0.16) & (np.abs(table[:, 1]) < 0.16) & (table[:, 2] > 0.74))
    ]  # and hides it
    cabinet = sampled(trimesh.creation.box(extents=(0.6, 0.35, 0.6)), (3.0, 1.82, 1.6))
    cabinet = cabinet[cabinet[:, 2] > 1.35]  # seen from below only partly: its bottom is missing
    wall = np.stack(np.meshgrid(np.linspace(1, 5, 80), [2.0], np.linspace(0, 2.5, 50)), -1).reshape(-1, 3)
    instances = ObjectInstances(
        [
            ObjectInstance(i, c, p, gravity_aligned_box(p))
            for i, c, p in ((1, "table", table), (2, "box", box_pts), (3, "cabinet", cabinet))
        ]
    )
    vocab = Vocabulary.default()
    points = np.concatenate([table, box_pts, cabinet, wall])
    classes = np.concatenate(
        [
            np.full(len(table), vocab.id("table")),
            np.full(len(box_pts), vocab.id("box")),
            np.full(len(cabinet), vocab.id("cabinet")),
            np.full(len(wall), vocab.id("wall")),
        ]
    )
    data = PipelineData()
    data.map.instances = instances
    data.map.geometry = Geometry(points=points)
    data.map.semantics = Semantics(classes.astype(np.int32), np.zeros(len(points), np.int32), vocab)
    graph = ContactGraphMapper().run(data)["contact_graph"]
    assert graph.parent(2) == 1  # on the table, though the table shows no plane under it
    assert graph.parent(3) == "wall" and graph.parent(1) == "floor"
    assert graph.is_tree()
    planes = graph.support.nodes[1]["planes"]
    heights = sorted(-p["plane"][3] for p in planes if p["kind"] == "horizontal")
    assert len(heights) >= 2 and abs(heights[0] - 0.71) < 0.01 and abs(heights[-1] - 0.75) < 0.01  # underside and top
    refined = graph.support.nodes[2]["box_refined"]
    assert abs(refined["center"][2] - refined["size"][2] / 2 - 0.75) < 0.01  # reaches down to the tabletop


def test_settle_sees_a_body_tip_over_its_base_edge(tmp_path):
    """A tall post framed at the middle of its base, set down leaning 10 degrees: it falls flat. Its
    frame's origin, next to the edge it turns about, moves a few centimetres; its centre of mass
    falls some 40 cm. settle reports the latter."""
    pytest.importorskip("mujoco")
    from stratamap.core.simulation.physics import settle

    path = tmp_path / "post.xml"
    path.write_text(
        """<mujoco><option timestep="0.002"/><worldbody>
        <geom name="floor" type="plane" size="5 5 0.1"/>
        <body name="post" pos="0 0 0.001" euler="0 10 0"><freejoint/>
          <geom type="box" size="0.025 0.025 0.4" pos="0 0 0.4" density="500"/>
        </body></worldbody></mujoco>"""
    )
    result = settle(path, seconds=2.0)
    assert result["free_bodies"] == 1 and result["max_displacement_m"] > 0.3, result


def test_a_simulation_that_diverges_is_never_at_rest(tmp_path, capfd):
    """MuJoCo restarts a diverged simulation from the initial pose, so the end poses alone could
    show an exploded scene at rest: ``settle`` reports the divergence and an infinite displacement,
    and MuJoCo's printout of it stays out of the terminal."""
    mujoco = pytest.importorskip("mujoco")
    from stratamap.core.simulation.physics import settle

    path = tmp_path / "diverges.xml"
    path.write_text(
        """<mujoco><option timestep="0.002" gravity="0 0 -1e12"/><worldbody>
        <geom name="floor" type="plane" size="5 5 0.1"/>
        <body name="crate" pos="0 0 0.2"><freejoint/><geom type="box" size="0.1 0.1 0.1"/></body>
        </worldbody></mujoco>"""
    )
    result = settle(path, seconds=0.2)
    assert "mjWARN_BADQACC" in result["diverged"], result
    assert result["max_displacement_m"] == np.inf and not result["max_displacement_m"] < 0.02
    printed = capfd.readouterr()
    assert "QACC" not in printed.out + printed.err
    assert mujoco.get_mju_user_warning() is None  # MuJoCo's own printer is back


def test_near_is_depth_within_the_margin_face_by_face():
    """``Shell.near`` drops a point at the first face it lies beyond: the same points as testing
    every face's depth, for points inside, at the margin and far away, whatever the chunk."""
    from stratamap.core.simulation.physics import convex_shell

    rng = np.random.default_rng(5)
    shell = convex_shell(rng.normal(size=(60, 3)) * [1.0, 0.5, 0.2])
    points = np.vstack([rng.uniform(-3, 3, (20000, 3)), rng.normal(size=(500, 3)) * 0.3])
    for margin in (0.0, 0.05, 0.5):
        want = shell.depth(points) > -margin
        assert 0 < want.sum() < len(points)
        for chunk in (1, 8, 1000):
            assert np.array_equal(shell.near(points, margin, chunk), want)
    assert not shell.near(np.zeros((0, 3)), 0.1).any()
