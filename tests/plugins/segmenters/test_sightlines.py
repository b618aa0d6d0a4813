"""What the frames' depth rays saw through an object (``clusters.sightlines``): the open space under a coffee
table's top, past its low shelf, against a unit's closed front, when their surface points alike fill
the middle heights."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from stratamap.core.map.sensors import CameraIntrinsics, RGBDFrame
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters.clusters.shapes import describe_shape, fits_class, prior_class
from stratamap.plugins.segmenters.clusters.sightlines import Sightlines
from tests.plugins.segmenters.test_layout_planes import solids

VOCAB = Vocabulary.default()


def coffee_table() -> np.ndarray:
    """A 1.0 x 0.5 m top at 0.45 m on four legs, with a shelf over its whole footprint at 0.12 m."""
    legs = [(x, y) for x in (0.03, 0.97) for y in (0.03, 0.47)]
    parts = [("table", (0.0, 0.0, 0.42), (1.0, 0.5, 0.45)), ("table", (0.0, 0.0, 0.10), (1.0, 0.5, 0.13))]
    parts += [("table", (x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.42)) for x, y in legs]
    return solids(parts, 0.02)[0]


def sideboard() -> np.ndarray:
    """A closed unit of the coffee table's size."""
    return solids([("cabinet", (0.0, 0.0, 0.0), (1.0, 0.5, 0.45))], 0.02)[0]


def rays_past(closed: bool) -> Sightlines:
    """Rays from cameras 2 m in front of the object (y = -2), 0.3 m high, to a wall at y = 1.5 behind it,
    across its middle heights: a closed front stops those that reach it at y = 0."""
    xs, zs = np.meshgrid(np.linspace(0.05, 0.95, 30), np.linspace(0.17, 0.34, 10))
    origins, ends = [], []
    for cx in (0.2, 0.5, 0.8):
        origin = np.array([cx, -2.0, 0.3])
        for x, z in zip(xs.ravel(), zs.ravel(), strict=True):
            at_front = np.array([x, 0.0, z])
            way = (at_front - origin) / np.linalg.norm(at_front - origin)
            length = (0.0 - origin[1]) / way[1] if closed else (1.5 - origin[1]) / way[1]
            origins.append(origin)
            ends.append(origin + length * way)
    return Sightlines(np.array(origins), np.array(ends))


def test_rays_tell_a_coffee_table_with_a_shelf_from_a_closed_unit():
    table, unit = coffee_table(), sideboard()
    # Their surface points alike fill the middle heights along their length: the map alone says solid.
    assert describe_shape(table, 0.0, []).solid and describe_shape(unit, 0.0, []).solid
    seen = rays_past(closed=False).seen_through(table)
    assert seen.through + seen.stopped > 200 and seen.share > 0.9
    stopped = rays_past(closed=True).seen_through(unit)
    assert stopped.through + stopped.stopped > 200 and stopped.share < 0.05
    # Seen through, the table's body is open: a table, no longer a cabinet.
    open_table = describe_shape(table, 0.0, [], rays_past(closed=False))
    assert not open_table.solid and open_table.flat_top
    assert prior_class(describe_shape(table, 0.0, []), VOCAB)[0] == "cabinet"
    assert prior_class(open_table, VOCAB)[0] == "table"
    assert fits_class("table", open_table)
    # The closed unit stays a unit.
    assert describe_shape(unit, 0.0, [], rays_past(closed=True)).solid
    # Rays that pass beside the object, over none of its footprint, say nothing of it.
    beside = Sightlines(rays_past(False).origins + [3.0, 0.0, 0.0], rays_past(False).ends + [3.0, 0.0, 0.0])
    assert beside.seen_through(table).through + beside.seen_through(table).stopped == 0


def test_too_few_rays_leave_the_surfaces_word():
    one_camera = rays_past(closed=False)
    few = Sightlines(one_camera.origins[:40], one_camera.ends[:40])
    assert describe_shape(coffee_table(), 0.0, [], few).solid


def test_rays_come_from_the_streams_posed_frames_with_depth():
    """A 40 x 30 frame 2 m from a wall, looking along +y from (1, 0, 1): its rays end on the wall;
    frames without a pose or depth, or of another size, give none."""
    intr = CameraIntrinsics(width=40, height=30, fx=30.0, fy=30.0, cx=19.5, cy=14.5)
    camera_to_world = np.array([[1.0, 0, 0, 1.0], [0, 0, 1.0, 0.0], [0, -1.0, 0, 1.0], [0, 0, 0, 1.0]])
    depth = np.full((30, 40), 2.0, np.float32)
    depth[0, 0] = np.nan
    rgb = np.zeros((30, 40, 3), np.uint8)
    frames = [
        RGBDFrame(0, 0.0, rgb, depth, camera_to_world),
        RGBDFrame(1, 0.1, rgb, depth, None),
        RGBDFrame(2, 0.2, rgb, np.zeros((10, 10), np.float32), camera_to_world),
    ]
    sight = Sightlines.from_stream(SimpleNamespace(intrinsics=intr, frames=frames))
    assert sight is not None and 0 < len(sight) < 40 * 30
    assert np.allclose(sight.ends[:, 1], 2.0) and np.allclose(sight.origins, [1.0, 0.0, 1.0])
    assert Sightlines.from_stream(SimpleNamespace(intrinsics=None, frames=frames)) is None
    assert Sightlines.from_stream(SimpleNamespace(intrinsics=intr, frames=frames[1:])) is None
