"""The physical check on hand-made scenes: convex shells, overlap volumes, resting and separating."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stratamap.core.layers import Completion, ContactGraph, ObjectInstance, ObjectInstances, OrientedBox
from stratamap.core.physics import convex_shell, penetration_depths, penetration_volume, resolve_scene, world_mesh


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
    objs = ObjectInstances([box_object(1, "box", (1.0, 1.0, 1.0), (0, 0, 0)), box_object(2, "box", (1.0, 1.0, 1.0), (0.5, 0.5, 0))])
    assert penetration_volume(objs) == pytest.approx(0.25, rel=1e-6)
    apart = ObjectInstances([box_object(1, "box", (1.0, 1.0, 1.0), (0, 0, 0)), box_object(2, "box", (1.0, 1.0, 1.0), (1.01, 0, 0))])
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
    fresh = ObjectInstances([box_object(1, "desk", (1.4, 0.7, 0.75), (0, 0, 0)), box_object(2, "chair", (0.5, 0.5, 1.0), (0.0, 0.5, 0))])
    copy = fresh.copy()
    resolve_scene(copy, graph_of(copy, {}))
    assert fresh[2].completion.pose[1, 3] == 0.5 and copy[2].completion.pose[1, 3] > 0.59


def test_unresolvable_overlap_is_reported():
    big = box_object(1, "cabinet", (2.0, 2.0, 1.0), (0, 0, 0))
    inside = box_object(2, "box", (0.3, 0.3, 0.3), (0, 0, 0))
    objs = ObjectInstances([big, inside])
    result = resolve_scene(objs, graph_of(objs, {}), max_shift=0.2)
    assert result.to_dict()["unresolved"] == [2]
