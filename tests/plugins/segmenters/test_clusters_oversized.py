"""No instance larger than any class allows (issue 65, step 3): a mapper's mask over an L of two counter
runs is split at the L's inner corner, and noted; a long straight run, one counter, is kept whole."""

from __future__ import annotations

import numpy as np

from stratamap.core.geometry.boxes import gravity_aligned_box
from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter
from tests.plugins.segmenters.test_layout_planes import room_shell, solids

VOCAB = Vocabulary.default()
SPACING = 0.03
#: Two base-unit runs under one worktop height, meeting in a corner of the room (an L), and a long
#: straight run along the opposite wall.
BACK_RUN = ("counter", (0.0, 4.4, 0.0), (2.6, 5.0, 0.9))
SIDE_RUN = ("counter", (0.0, 2.7, 0.0), (0.6, 4.4, 0.9))
STRAIGHT_RUN = ("counter", (1.2, 0.0, 0.0), (5.6, 0.6, 0.9))


def scene() -> PipelineData:
    """The room's shell and the three runs; the L is one mask instance voted ``table`` (a detector
    without a counter label framed both runs), the straight run another."""
    layout = room_shell(SPACING)
    objects, names = solids([BACK_RUN, SIDE_RUN, STRAIGHT_RUN], SPACING)
    points = np.concatenate([p for _, p in layout] + [objects])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [names])
    classes = np.array([VOCAB.id(n) for n in names], np.int32)
    ids = np.zeros(len(points), np.int32)
    counter = names == "counter"
    classes[counter] = VOCAB.id("table")
    straight = counter & (points[:, 1] <= 0.6 + 1e-6)
    ids[counter & ~straight], ids[straight] = 1, 2
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=SPACING)
    data.map.semantics = Semantics(classes, ids, VOCAB)
    return data


def run(**params) -> tuple[PipelineData, dict]:
    data = scene()
    out = ClustersSegmenter(keep_instances=True, recognize=True, **params).run(data)
    return data, out


def boxes(data: PipelineData, out: dict) -> dict[int, np.ndarray]:
    ids = out["semantics"].instance_ids
    points = data.map.geometry.points
    return {int(i): gravity_aligned_box(points[ids == i]) for i in np.unique(ids[ids > 0])}


def covering(found: dict, part: tuple) -> list[int]:
    """The instances as narrow as one run (15 cm to spare) whose boxes hold the centre of ``part``."""
    _, lo, hi = part
    centre, depth = np.add(lo, hi) / 2, min(np.subtract(hi, lo)[:2])
    return [i for i, box in found.items() if box.contains(centre[None], 0.0)[0] and min(box.size[:2]) <= depth + 0.15]


def test_an_l_of_two_runs_in_one_mask_is_split_at_its_corner_and_noted():
    data, out = run()
    found = boxes(data, out)
    back, side = covering(found, BACK_RUN), covering(found, SIDE_RUN)
    assert len(back) == len(side) == 1 and back != side, {i: b.size for i, b in found.items()}
    notes = data.notes["clusters"]["oversized"]
    assert len(notes) == 1 and notes[0]["instance"] == 1 and len(notes[0]["into"]) >= 2, notes


def test_a_long_straight_run_is_one_object():
    data, out = run()
    found = boxes(data, out)
    assert len(covering(found, STRAIGHT_RUN)) == 1
    assert all(note["instance"] != 2 for note in data.notes["clusters"]["oversized"])


def test_without_the_pass_the_l_stays_one_instance():
    from stratamap.plugins.segmenters.clusters import DEFAULT_PASSES

    data, out = run(passes=[p for p in DEFAULT_PASSES if p != "split_oversized"])
    found = boxes(data, out)
    assert not covering(found, SIDE_RUN)
    assert "oversized" not in data.notes.get("clusters", {})
