"""What a table's instance holds beside its top (``clusters``' pass ``split_beside_tops``): a chair pushed in
at its edge, its seat under the top, is another object where the frames saw through the top's level over
it; a table's legs under the top stay the table's, and so does what lies where no frame looked."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters.clusters import ClustersConfig
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.sightlines import Sightlines
from stratamap.plugins.segmenters.clusters.tops import beside_top, parts_beside, seen_open
from tests.plugins.segmenters.test_layout_planes import solids

VOCAB = Vocabulary.default()
SPACING = 0.02
TOP = 0.75


def table_and_chair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 1.2 x 0.8 m table top at 0.72-0.75 m on four legs, and a chair pushed in at its +y edge: its
    seat (0.45 m high) reaches 0.15 m under the top, its back rises to 0.9 m 0.3 m beyond the edge.
    Returns the points, their part names and the support index per point (the top's points: 0)."""
    parts = [("top", (0.0, 0.0, 0.72), (1.2, 0.8, TOP))]
    parts += [("leg", (x, y, 0.0), (x + 0.05, y + 0.05, 0.7)) for x in (0.02, 1.13) for y in (0.02, 0.73)]
    parts += [
        ("seat", (0.4, 0.65, 0.42), (0.8, 1.1, 0.45)),
        ("back", (0.4, 1.08, 0.45), (0.8, 1.1, 0.9)),
    ]
    points, names = solids(parts, SPACING)
    support = np.where((names == "top") & (points[:, 2] >= TOP - 1e-6), 0, -1)
    return points, names, support


def test_what_stands_beside_the_top_is_beside_it_and_the_legs_under_it_are_not():
    points, names, support = table_and_chair()
    beside, below, level = beside_top(points, support, np.array([0.96]))
    assert level == pytest.approx(TOP)
    assert beside[names == "back"].all()
    assert not beside[(names == "top") | (names == "leg")].any()
    # The seat beyond the edge is beside; its part under the top is below it.
    seat = names == "seat"
    assert beside[seat & (points[:, 1] > 0.9)].all() and not beside[seat & (points[:, 1] < 0.75)].any()
    assert below[seat & (points[:, 1] < 0.75)].all()
    legs = names == "leg"
    assert below[legs & (points[:, 2] <= TOP - 0.1)].all() and not below[legs & (points[:, 2] > TOP - 0.1)].any()


def test_a_seat_is_no_top_to_split_beside():
    points, names, _ = table_and_chair()
    seat_only = np.where((names == "seat") & (points[:, 2] >= 0.45 - 1e-6), 0, -1)
    assert beside_top(points, seat_only, np.array([0.18])) is None


def test_the_chair_takes_its_seat_under_the_top_and_leaves_the_legs():
    points, names, support = table_and_chair()
    beside, below, _ = beside_top(points, support, np.array([0.96]))
    part = parts_beside(points, np.arange(len(points)), beside, below, 2.4 * SPACING)
    chair = (names == "seat") | (names == "back")
    assert len(np.unique(part[chair])) == 1 and (part[chair] >= 0).all()
    assert (part[(names == "top") | (names == "leg")] == -1).all()


def rays_over(xy: np.ndarray, end_height: float) -> Sightlines:
    """Rays from a camera 1.5 m up, down through the level TOP over the points ``xy``, each ending at
    ``end_height``."""
    origin = np.array([0.6, -1.0, 1.5])
    ends = []
    for x, y in xy:
        direction = np.array([x, y, TOP]) - origin
        ends.append(origin + direction * (origin[2] - end_height) / (origin[2] - TOP))
    return Sightlines(np.broadcast_to(origin, (len(ends), 3)), np.array(ends))


def test_a_part_splits_only_where_the_frames_saw_through_the_tops_level_over_it():
    seat = np.stack(np.meshgrid(np.linspace(0.42, 0.78, 6), np.linspace(0.9, 1.05, 4)), -1).reshape(-1, 2)
    past = rays_over(seat, end_height=0.45).across_level(TOP)
    assert seen_open(past, seat)  # open above the seat: 24 rays went on to it
    stopped = rays_over(seat, end_height=TOP).across_level(TOP)
    assert not seen_open(stopped, seat)  # something at the top's level there: perhaps the top
    assert not seen_open(past, seat + 2.0)  # no ray went over that place
    assert not seen_open(None, seat)  # a point cloud: no rays at all


def test_joins_of_what_a_pass_kept_apart_are_refused():
    points = np.random.default_rng(0).random((40, 3))
    lab = Labelling.of_labels(
        ClustersConfig(), points, VOCAB, np.ones(40, np.int32), np.ones(40, np.int32), 0.02, np.zeros(0)
    )
    lab.keep_apart(np.arange(10), np.arange(10, 30))
    assert lab.held_apart(np.arange(0, 12), np.arange(12, 40))
    assert lab.held_apart(np.arange(12, 40), np.arange(0, 12))
    assert not lab.held_apart(np.arange(0, 4), np.arange(10, 30))  # a scrap of the first is not it
    assert not lab.held_apart(np.arange(30, 40), np.arange(10, 30))


def test_the_pass_gives_the_chair_back_and_keeps_the_tops_rim_and_legs():
    """The whole pass on a table's instance holding a chair pushed in at it and a strip of its top's rim
    that the plane fit left out: the chair becomes an instance of its own, seen open from above; the
    rim (at the top's level) and the legs stay the table's, and no later join puts the chair back."""
    from types import SimpleNamespace

    from stratamap.plugins.segmenters.clusters.labelling import Supports
    from stratamap.plugins.segmenters.clusters.tops import split_beside_tops

    points, names, support = table_and_chair()
    rim = solids([("rim", (-0.12, 0.0, 0.72), (0.0, 0.8, TOP))], SPACING)[0]
    points = np.concatenate([points, rim])
    names = np.concatenate([names, np.full(len(rim), "rim")])
    support = np.concatenate([support, np.full(len(rim), -1)])
    n = len(points)
    table = VOCAB.id("table")
    lab = Labelling.of_labels(
        ClustersConfig(recognize=True),
        points,
        VOCAB,
        np.full(n, table, np.int32),
        np.ones(n, np.int32),
        SPACING,
        np.zeros(0),
    )
    lab.supports = Supports(support, np.array([TOP]), np.array([0.96]))
    lab.layout = SimpleNamespace(labels=np.zeros(n, np.int64))
    seat = np.stack(np.meshgrid(np.linspace(0.42, 0.78, 6), np.linspace(0.9, 1.05, 4)), -1).reshape(-1, 2)
    # Rays pass the top's level over the chair's seat and over the rim (a ray past the rim's outer
    # edge goes on down): only the rim's level says it is the top's.
    beyond_rim = np.stack(np.meshgrid(np.linspace(-0.11, -0.06, 3), np.linspace(0.1, 0.7, 8)), -1).reshape(-1, 2)
    lab.sight = rays_over(np.concatenate([seat, beyond_rim]), end_height=0.45)
    split_beside_tops(lab)
    chair = (names == "seat") | (names == "back")
    chair_ids = np.unique(lab.instance_ids[chair])
    assert len(chair_ids) == 1 and chair_ids[0] not in (0, 1)
    assert (lab.instance_ids[(names == "top") | (names == "leg") | (names == "rim")] == 1).all()
    assert lab.held_apart(np.flatnonzero(chair), np.flatnonzero(lab.instance_ids == 1))
    assert lab.notes["split_beside_tops"][0]["new_instances"] == [int(chair_ids[0])]
    # Without rays over the chair (a point cloud) nothing shows the top is not there: nothing splits.
    lab.instance_ids, lab.sight = np.ones(n, np.int32), None
    split_beside_tops(lab)
    assert (lab.instance_ids == 1).all()
