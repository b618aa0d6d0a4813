"""A side-hinged door hinges where it can swing open (plugins/completers/fronts/swing.py)."""

from __future__ import annotations

import numpy as np

from stratamap.core.geometry.boxes import OrientedBox
from stratamap.plugins.completers.fronts.swing import room_to_open, swing_blocked

# An object frame turned 30 degrees in the world: its face at y = -0.3, the room at lower y.
POSE = OrientedBox(np.array([1.0, 2.0, 0.0]), np.radians(30.0), np.ones(3)).pose
Y_FACE = -0.3
DOOR = (-0.5, 0.0, 0.1, 0.8)  # x0, x1, z0, z1 in the object frame: the left half of a 1 m face
OPENING = 1.6


def neighbour(x0: float, x1: float, y0: float, y1: float, z0: float = 0.0, z1: float = 0.9):
    """A box given by its extent in the object frame, as (pose, size) in the world."""
    centre = POSE @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2, 1.0])
    box = OrientedBox(centre[:3], np.radians(30.0), np.array([x1 - x0, y1 - y0, z1 - z0]))
    return box.pose, box.size


def test_a_door_beside_the_other_run_of_an_l_hinges_away_from_it():
    # The other run stands across the left end of the face, its front 0.6 m into the room, and its
    # box reaches 5 cm over the door's end (the corner of an L: the door's face was cut beyond it).
    side_run = neighbour(-1.2, -0.45, -0.9, 0.3)
    mine = swing_blocked(DOOR, "left", Y_FACE, OPENING, POSE, [side_run])
    other = swing_blocked(DOOR, "right", Y_FACE, OPENING, POSE, [side_run])
    assert mine > 0.05 and other < mine / 2, (mine, other)
    rects, turned = room_to_open([(DOOR, "cupboard", "left", [])], Y_FACE, OPENING, POSE, [side_run])
    assert rects[0][2] == "right" and turned[0]["from"] == "left" and turned[0]["to"] == "right"


def test_a_door_with_room_on_its_side_or_a_neighbour_above_keeps_its_hinge():
    far = neighbour(-2.5, -1.9, -0.9, 0.3)  # the other run, a step away
    wall_unit = neighbour(-1.2, -0.55, -0.9, 0.3, 1.4, 2.1)  # over the doors' height
    for neighbours in ([], [far], [wall_unit]):
        rects, turned = room_to_open([(DOOR, "cupboard", "left", [])], Y_FACE, OPENING, POSE, neighbours)
        assert rects[0][2] == "left" and turned == []


def test_a_door_blocked_both_ways_alike_and_a_drawer_are_left_as_they_are():
    # A table in front of the door, across its whole width: either swing runs into it.
    table = neighbour(-0.8, 0.3, -0.75, -0.45)
    mine = swing_blocked(DOOR, "left", Y_FACE, OPENING, POSE, [table])
    other = swing_blocked(DOOR, "right", Y_FACE, OPENING, POSE, [table])
    assert mine > 0 and other >= mine / 2
    rects, turned = room_to_open(
        [(DOOR, "cupboard", "left", []), ((0.0, 0.5, 0.5, 0.8), "drawer", None, [])], Y_FACE, OPENING, POSE, [table]
    )
    assert [r[2] for r in rects] == ["left", None] and turned == []
