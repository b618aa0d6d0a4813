"""Pass ``join_seating`` of ``clusters``: two seats side by side that a mapper cut apart become one
sofa; a seat and something beside it that reaches out past the seat's depth stay apart."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter
from tests.plugins.segmenters.test_layout_planes import room_shell, solids

VOCAB = Vocabulary.default()


def seat(x0: float, x1: float, y0: float, depth: float = 0.85) -> list:
    """A block seat 0.45 m high from ``x0`` to ``x1``, ``depth`` deep from ``y0``, its back rising
    to 0.9 m along its rear edge."""
    return [
        ("chair", (x0, y0, 0.0), (x1, y0 + depth, 0.45)),
        ("chair", (x0, y0 + depth - 0.2, 0.45), (x1, y0 + depth, 0.9)),
    ]


def seating_map(objects: list[list]) -> PipelineData:
    """A 2 cm map of the room with ``objects`` (each a list of boxes), each its own instance voted chair."""
    things = [solids(parts, 0.02)[0] for parts in objects]
    shell = room_shell(0.02, around=np.concatenate(things))
    points = np.concatenate([p for _, p in shell] + things)
    classes = np.concatenate(
        [np.full(len(p), VOCAB.id(n)) for n, p in shell] + [np.full(len(p), VOCAB.id("chair")) for p in things]
    ).astype(np.int32)
    instances = np.concatenate(
        [np.zeros(len(p)) for _, p in shell] + [np.full(len(p), k) for k, p in enumerate(things, start=1)]
    ).astype(np.int32)
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    return data


def run(objects: list[list]) -> tuple[list, list]:
    data = seating_map(objects)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    return out["instances"], data.notes.get("clusters", {}).get("seating_joined", [])


def test_two_halves_of_a_sofa_side_by_side_are_one_sofa():
    # One 1.8 m sofa that a mapper's size prior cut into two 0.9 m "chairs".
    instances, joined = run([seat(1.0, 1.9, 1.0), seat(1.9, 2.8, 1.0)])
    assert len(joined) == 1, joined
    sofas = [i for i in instances if i.class_name == "sofa"]
    assert len(sofas) == 1 and np.ptp(np.asarray(sofas[0].points)[:, 0]) > 1.7


def test_a_seat_and_what_reaches_out_beside_it_past_its_depth_are_not_one_sofa():
    # The same halves, the second pushed 0.5 m back: together 1.35 m deep, no row of seats.
    instances, joined = run([seat(1.0, 1.9, 1.0), seat(1.9, 2.8, 1.5)])
    assert joined == []
    assert not any(i.class_name == "sofa" for i in instances)
