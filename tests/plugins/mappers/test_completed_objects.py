"""Completed objects in the maps: a chair whose legs were never mapped stands on the floor, the
multimap gets the completed seat the observed points lack, and the physical check does not slide
a model away from what was observed of it."""

from __future__ import annotations

import numpy as np
import trimesh

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import (
    Completion,
    ContactGraph,
    Geometry,
    Joint,
    ObjectInstance,
    ObjectInstances,
    Semantics,
)
from stratamap.core.map.sensors import SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.contact_graph import ContactGraphMapper
from stratamap.plugins.mappers.occupancy import OccupancyMapper
from stratamap.plugins.mappers.physical_check import PhysicalCheckMapper


def chair_mesh() -> trimesh.Trimesh:
    legs = [((0.04, 0.04, 0.44), (x, y, 0.22)) for x in (-0.2, 0.2) for y in (-0.2, 0.2)]
    pieces = [((0.45, 0.45, 0.04), (0.0, 0.0, 0.46)), ((0.45, 0.04, 0.5), (0.0, 0.2, 0.73)), *legs]
    return trimesh.util.concatenate(
        [trimesh.creation.box(extents=e, transform=trimesh.transformations.translation_matrix(c)) for e, c in pieces]
    )


def room(objects: list[tuple[str, np.ndarray]]) -> PipelineData:
    """A 4 x 4 m room: floor and one wall (at y = 2) as labelled points, and the given objects."""
    vocab = Vocabulary.default()
    grid = np.linspace(-2, 2, 81)
    floor = np.stack(np.meshgrid(grid, grid, [0.0]), -1).reshape(-1, 3)
    wall = np.stack(np.meshgrid(grid, [2.0], np.linspace(0, 2.5, 51)), -1).reshape(-1, 3)
    pts = [floor, wall, *(p for _, p in objects)]
    classes = [np.full(len(floor), vocab.id("floor")), np.full(len(wall), vocab.id("wall"))]
    classes += [np.full(len(p), vocab.id(c)) for c, p in objects]
    data = PipelineData()
    data.stream = SensorStream("test")
    points = np.concatenate(pts)
    data.map.geometry = Geometry(points=points)
    data.map.semantics = Semantics(np.concatenate(classes).astype(np.int32), np.zeros(len(points), np.int32), vocab)
    data.map.instances = ObjectInstances(
        [ObjectInstance(i + 1, c, p, gravity_aligned_box(p)) for i, (c, p) in enumerate(objects)]
    )
    return data


def seen_from_above(mesh: trimesh.Trimesh, offset, below: float) -> np.ndarray:
    """Surface samples of ``mesh`` moved by ``offset``, all under ``below`` left out (never mapped)."""
    pts = trimesh.sample.sample_surface_even(mesh, 3000, seed=0)[0] + np.asarray(offset)
    return pts[pts[:, 2] > below]


def test_a_chair_by_the_wall_whose_legs_were_never_mapped_stands_on_the_floor():
    chair = seen_from_above(chair_mesh(), (0.0, 1.7, 0.0), below=0.42)  # seat and back only, 5 cm from the wall
    cabinet = seen_from_above(trimesh.creation.box(extents=(0.6, 0.35, 0.6)), (-1.2, 1.8, 1.6), below=1.35)
    data = room([("chair", chair), ("cabinet", cabinet)])
    graph = ContactGraphMapper().run(data)["contact_graph"]
    assert graph.parent(1) == "floor"  # a chair's height: it stands, its legs unseen
    assert graph.parent(2) == "wall"  # a cabinet's top at 1.9 m: it hangs


def test_the_multimap_has_the_completed_seat_the_observed_points_lack():
    back_only = seen_from_above(chair_mesh(), (0.0, 0.0, 0.0), below=0.5)
    back_only = back_only[back_only[:, 1] > 0.15]  # only the backrest was seen
    data = room([("chair", back_only)])
    seat_cell = np.array([[0.0, -0.1]])
    observed = OccupancyMapper().run(data)["occupancy"]["multimap"]
    rc = observed.world_to_cell(seat_cell)[0]
    assert observed.data[rc[0], rc[1]] != 100
    inst = data.map.instances[1]
    inst.completion = Completion(chair_mesh(), np.eye(4), "test", model_id="chair")
    completed = OccupancyMapper().run(data)["occupancy"]["multimap"]
    assert completed.data[rc[0], rc[1]] == 100
    assert (completed.data == 100).sum() > (observed.data == 100).sum()


def test_the_physical_check_keeps_a_model_where_it_was_observed():
    """Two chairs completed into each other: sliding one 0.3 m away would leave its observed points
    far from its model, so the move is undone; the model that still penetrates its neighbour where it
    was seen is rejected and the object keeps its observed shape. What was seen of the two chairs
    interleaves, so the other model penetrates what was seen of the first, and is rejected in turn."""
    a = seen_from_above(chair_mesh(), (0.0, 0.0, 0.0), below=0.0)
    b = seen_from_above(chair_mesh(), (0.3, 0.0, 0.0), below=0.0)
    data = room([("chair", a), ("chair", b)])
    for inst, x in zip(data.map.instances, (0.0, 0.3), strict=True):
        pose = np.eye(4)
        pose[0, 3] = x
        inst.completion = Completion(chair_mesh(), pose, "test", model_id="chair")
    # The first one's completion is articulated (a swivel seat): the notes say its joint went with it.
    data.map.instances[1].completion.joints = [Joint("seat", "continuous", "base", "seat", np.eye(4), [0, 0, 1])]
    graph = ContactGraph()
    for i in (1, 2):
        graph.support.add_edge("floor", i, relation="support", plane=[0.0, 0.0, 1.0, 0.0])
    data.map.contact_graph = graph

    def slid(instances: ObjectInstances) -> list[int]:
        before = data.map.instances
        return [
            i.id
            for i in instances
            if i.completion is not None
            and np.linalg.norm(i.completion.pose[:2, 3] - before[i.id].completion.pose[:2, 3]) > 0.01
        ]

    checked = PhysicalCheckMapper().run(data)["instances"]
    assert slid(checked) == []
    assert data.notes["physical_check"]["undone"] and not data.notes["physical_check"]["unresolved"]
    reasons = sorted(i.attributes.get("completion_rejected", "") for i in checked)
    assert reasons == [
        "penetrates a neighbour where it was seen",
        "penetrates what was seen of a neighbour whose model was rejected",
    ]
    assert all(i.completion is None for i in checked)
    # One warning names both; the notes say why each.
    warnings = [w for w in data.warnings if "completion rejected" in w]
    assert len(warnings) == 1 and "objects 1 (chair), 2 (chair)" in warnings[0]
    assert "(1 joint with them)" in warnings[0]
    rejected = data.notes["physical_check"]["completions_rejected"]
    assert sorted(r["why"] for r in rejected) == reasons
    assert [r.get("joints") for r in rejected] == [1, None] and data.notes["physical_check"]["joints_rejected"] == 1
    assert slid(PhysicalCheckMapper(observed_distance=None).run(data)["instances"])  # what it did before: slide


def test_the_physical_check_updates_the_contact_graph_it_moved_objects_in():
    """A table completed 5 cm above the floor is rested on it: the tabletop its cup stands on is
    5 cm lower in the graph too, and every completed node has the box of its model as placed."""
    table = trimesh.creation.box(
        extents=(1.2, 0.8, 0.75), transform=trimesh.transformations.translation_matrix((0, 0, 0.375))
    )
    seen = seen_from_above(table, (0.0, 0.0, 0.05), below=0.06)
    data = room([("table", seen)])
    pose = np.eye(4)
    pose[2, 3] = 0.05
    data.map.instances[1].completion = Completion(table, pose, "test", model_id="table")
    graph = ContactGraph()
    graph.support.add_edge("floor", 1, relation="support", plane=[0.0, 0.0, 1.0, 0.0])
    graph.support.add_edge(1, 2, relation="support", plane=[0.0, 0.0, 1.0, -0.8])
    data.map.contact_graph = graph
    out = PhysicalCheckMapper().run(data)
    assert out["instances"][1].completion.pose[2, 3] < 0.01
    assert out["contact_graph"].support.edges[1, 2]["plane"][3] > -0.76  # the tabletop came down with the table
    assert graph.support.edges[1, 2]["plane"][3] == -0.8  # the input graph is left as it was
    box = out["contact_graph"].support.nodes[1]["box_completed"]
    assert np.allclose(box["size"], (1.2, 0.8, 0.75), atol=1e-6)


def test_a_room_in_millimetres_read_as_metres_is_a_one_line_error_naming_the_scale():
    """A scan stored in millimetres and read as metres spans kilometres: its occupancy grid would hold
    4 billion cells (65 GB of counts; the run died of memory). It is refused, saying what to set."""
    import pytest

    from stratamap.core.errors import DataError

    data = room([])
    data.map.geometry = Geometry(points=data.map.geometry.points * 1000.0)
    with pytest.raises(
        DataError, match=r"occupancy: the map spans 4,000 x 4,000 m.*source\.params\.scale=0\.001"
    ) as err:
        OccupancyMapper().run(data)
    assert "\n" not in str(err.value)
    assert OccupancyMapper(resolution=1.0).run(data)["occupancy"]["multimap"].data.size < 20_000_000
