"""Boxes, footprints and detection matching on hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.evaluation.detection import match_boxes, prf
from stratamap.core.geometry.boxes import box_iou_3d, footprint_overlap, gravity_aligned_box, min_area_rectangle
from stratamap.core.map.layers import OrientedBox


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2, 1.5])
def test_min_area_rectangle_recovers_a_rotated_rectangle(yaw):
    rng = np.random.default_rng(1)
    local = rng.uniform([-1.0, -0.25], [1.0, 0.25], size=(400, 2))
    local = np.vstack([local, [[-1, -0.25], [1, -0.25], [1, 0.25], [-1, 0.25]]])
    c, s = np.cos(yaw), np.sin(yaw)
    pts = local @ np.array([[c, s], [-s, c]]) + [3.0, -2.0]
    center, got_yaw, size = min_area_rectangle(pts)
    np.testing.assert_allclose(center, [3.0, -2.0], atol=1e-9)
    np.testing.assert_allclose(size, [2.0, 0.5], atol=1e-9)
    assert abs(np.sin(got_yaw - yaw)) < 1e-9  # same axis, up to a half-turn


def test_a_box_seen_from_its_corner_stands_square_to_the_walls():
    # What a sensor sees of a 0.7 x 0.6 m unit from its corner: two perpendicular faces, an L whose
    # smallest rectangle runs diagonally (a hair smaller than the upright one).
    rng = np.random.default_rng(0)
    seen = np.r_[
        np.c_[rng.uniform(0.0, 0.6, 200), rng.normal(0, 0.01, 200)],
        np.c_[rng.normal(0, 0.01, 200), rng.uniform(0.0, 0.7, 200)],
    ]  # 1 cm of depth noise
    wall = np.radians(3.0)
    turn = np.array([[np.cos(wall), -np.sin(wall)], [np.sin(wall), np.cos(wall)]])
    seen = seen @ turn.T
    _, tilted, _ = min_area_rectangle(seen, 0.03)
    assert min(abs(tilted - wall) % (np.pi / 2), np.pi / 2 - abs(tilted - wall) % (np.pi / 2)) > np.radians(20)
    _, yaw, size = min_area_rectangle(seen, 0.03, axes=[wall + np.pi / 2], axes_slack=0.1)
    assert np.isclose(np.mod(yaw - wall, np.pi / 2), 0, atol=1e-6) or np.isclose(
        np.mod(yaw - wall, np.pi / 2), np.pi / 2
    )
    np.testing.assert_allclose(size, [0.7, 0.6], atol=0.04)
    # A table turned 20 degrees from the walls stays turned: squaring it would cost far more footprint.
    rng2 = np.random.default_rng(1)
    table = (
        rng2.uniform([-1.0, -0.4], [1.0, 0.4], (500, 2))
        @ np.array([[np.cos(0.35), -np.sin(0.35)], [np.sin(0.35), np.cos(0.35)]]).T
    )
    _, yaw, size = min_area_rectangle(table, 0.03, axes=[0.0], axes_slack=0.1)
    assert abs(yaw - 0.35) < np.radians(2) and size[0] < 2.01
    # No axes, or no slack: the smallest rectangle, as before.
    assert min_area_rectangle(seen, 0.03, axes=[wall], axes_slack=0.0)[1] == tilted


def test_gravity_aligned_box_z_extent():
    pts = np.array([[0, 0, 0.2], [1, 0, 0.5], [1, 1, 0.9], [0, 1, 0.3]], float)
    box = gravity_aligned_box(pts)
    assert box.bottom_z == pytest.approx(0.2) and box.top_z == pytest.approx(0.9)


def test_overlap_and_iou():
    a = OrientedBox([0, 0, 0.5], 0.0, [2, 2, 1])
    b = OrientedBox([1, 1, 0.5], 0.0, [2, 2, 1])
    assert footprint_overlap(a, b) == pytest.approx(1.0)
    assert box_iou_3d(a, b) == pytest.approx(1.0 / 7.0)
    assert box_iou_3d(a, a) == pytest.approx(1.0)
    rotated = OrientedBox([0, 0, 0.5], np.pi / 4, [2, 2, 1])
    # A square and the same square turned 45 degrees overlap in a regular octagon.
    octagon = 8 * (np.sqrt(2) - 1)
    assert footprint_overlap(a, rotated) == pytest.approx(octagon, rel=1e-9)
    far = OrientedBox([10, 0, 0.5], 0.0, [1, 1, 1])
    assert box_iou_3d(a, far) == 0.0


def test_detection_matching_is_one_to_one_and_class_aware():
    gt = [("chair", OrientedBox([0, 0, 0.4], 0, [0.5, 0.5, 0.8])), ("table", OrientedBox([2, 0, 0.4], 0, [1, 1, 0.8]))]
    pred = [
        ("chair", OrientedBox([0.05, 0, 0.4], 0, [0.5, 0.5, 0.8])),
        ("chair", OrientedBox([0.1, 0, 0.4], 0, [0.5, 0.5, 0.8])),  # duplicate detection
        ("chair", OrientedBox([2, 0, 0.4], 0, [1, 1, 0.8])),  # right place, wrong class
    ]
    matches = match_boxes(pred, gt)
    assert matches == [(0, 0)]
    assert prf(len(matches), len(pred), len(gt)) == pytest.approx({"precision": 1 / 3, "recall": 0.5, "f1": 0.4})


def test_first_of_each_row_is_numpys_row_unique():
    from stratamap.core.geometry.points import first_of_each_row

    rng = np.random.default_rng(0)
    rows = np.round(rng.uniform(-1, 1, (5000, 3)), 1)  # many repeats
    rows[7] = [-0.0, 0.5, 0.0]
    rows[9] = [0.0, 0.5, -0.0]  # the same point as row 7
    expected = np.sort(np.unique(rows, axis=0, return_index=True)[1])
    assert np.array_equal(first_of_each_row(rows), expected)
    assert 9 not in first_of_each_row(rows)


def test_a_box_contains_points_within_its_turned_sides_and_margin():
    box = OrientedBox([1.0, 0.0, 0.5], np.pi / 4, [2.0, 0.2, 1.0])  # long side along x = y
    along, across, above = [1.7, 0.7, 0.5], [1.7, -0.7, 0.5], [1.0, 0.0, 1.04]
    assert box.contains(np.array([along, across, above])).tolist() == [True, False, False]
    assert box.contains(np.array([above]), margin=0.05).tolist() == [True]
