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
