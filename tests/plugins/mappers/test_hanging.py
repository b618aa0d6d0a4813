"""The contact graph hangs an object whose underside the frames saw empty (``hang_over_free_space``):
a wall cabinet seen only from the front lies 0.3 m from the wall's points, too far to count as on
the wall by distance, and its refined box reached down to the floor through space the frames saw
empty. Depth frames ray-cast from hand-made scenes (tests/plugins/mappers/test_refined_boxes.py)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import Geometry, ObjectInstance, ObjectInstances, Semantics
from stratamap.core.map.sensors import RGBDFrame, SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.contact_graph import ContactGraphMapper, seen_free_below
from tests.plugins.mappers.test_refined_boxes import (
    FLOOR,
    INTRINSICS,
    depth_of,
    free_space,
    look_at,
    slab,
    surface_points,
)

WALL = slab((-2.0, 0.3, 0.0), (2.0, 0.32, 2.4))
#: A wall cabinet 0.3 m deep, its back on the wall, 1.4-2.0 m up.
CABINET = slab((-0.4, 0.0, 1.4), (0.4, 0.3, 2.0))
#: A board standing in front of the wall up to just under the cabinet: it hides the space below it.
BOARD = slab((-0.5, -0.12, 0.0), (0.5, -0.1, 1.38))
#: Cameras in the room, eye high, looking at the wall under the cabinet.
POSES = [look_at((x, -2.5, 1.3), (0.0, 0.3, 1.0)) for x in (-1.0, 0.0, 1.0)]


def cabinet_scene(meshes: list) -> PipelineData:
    """The cabinet's front (all the frames saw of it) as an unnamed object, the wall, the floor and
    anything else in ``meshes``, with the frames that saw them."""
    vocab = Vocabulary.default()
    front = surface_points(CABINET)
    front = front[front[:, 1] < 0.01]
    wall, floor = surface_points(WALL, 8000), surface_points(FLOOR)
    points = np.vstack([front, wall, floor])
    classes = np.concatenate(
        [
            np.full(len(front), vocab.id("object")),
            np.full(len(wall), vocab.id("wall")),
            np.full(len(floor), vocab.id("floor")),
        ]
    )
    ids = np.concatenate([np.ones(len(front)), np.zeros(len(wall) + len(floor))])
    frames = [
        RGBDFrame(k, float(k), np.zeros((120, 160, 3), np.uint8), depth_of(meshes, pose), pose)
        for k, pose in enumerate(POSES)
    ]
    data = PipelineData(stream=SensorStream("wall cabinet", INTRINSICS, frames))
    data.map.instances = ObjectInstances([ObjectInstance(1, "object", front, gravity_aligned_box(front))])
    data.map.geometry = Geometry(points=points)
    data.map.semantics = Semantics(classes.astype(np.int32), ids.astype(np.int32), vocab)
    return data


def refined_bottom(graph) -> float:
    node = graph.support.nodes[1]
    box = node.get("box_refined", node["box"])
    return float(box["center"][2] - box["size"][2] / 2)


def test_the_space_under_a_wall_cabinet_seen_empty_says_it_hangs():
    front = surface_points(CABINET)
    box = gravity_aligned_box(front[front[:, 1] < 0.01])
    assert seen_free_below(box, free_space([FLOOR, WALL, CABINET], POSES))
    assert not seen_free_below(box, free_space([FLOOR, WALL, CABINET, BOARD], POSES))


def test_a_wall_cabinet_seen_from_the_front_hangs_on_the_wall_not_down_to_the_floor():
    data = cabinet_scene([FLOOR, WALL, CABINET])
    graph = ContactGraphMapper().run(data)["contact_graph"]
    assert graph.parent(1) == "wall"
    assert refined_bottom(graph) == pytest.approx(1.4, abs=0.03)
    # Judged by distance to the wall's points alone, as before, it stood on the floor.
    before = ContactGraphMapper(hang_over_free_space=False).run(data)["contact_graph"]
    assert before.parent(1) == "floor" and refined_bottom(before) == pytest.approx(0.0, abs=0.01)


def test_where_nothing_saw_under_it_an_object_still_reaches_down_to_the_floor():
    """The board hides the space under the cabinet: nothing says it does not go down there."""
    graph = ContactGraphMapper().run(cabinet_scene([FLOOR, WALL, CABINET, BOARD]))["contact_graph"]
    assert graph.parent(1) == "floor" and refined_bottom(graph) == pytest.approx(0.0, abs=0.01)
