"""Gravity-aware layout (plugins/segmenters/clusters/layout.py): floor, walls, ceiling and support surfaces of
synthetic rooms and partial maps built here from boxes sampled on a grid, as a fused map's surface."""

from __future__ import annotations

import numpy as np

from stratamap.plugins.segmenters.clusters.layout import CEILING, FLOOR, NONE, WALL, LayoutParams, find_layout

ROOM = (6.0, 5.0, 2.6)


def box_surface(lo, hi, spacing: float, faces: str = "xXyYzZ") -> np.ndarray:
    """Points on a grid of ``spacing`` over the named faces of the box ``lo``-``hi`` (x: the face at
    lo[0], X: at hi[0], and so on)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = []
    for face in faces:
        axis = "xyz".index(face.lower())
        u, v = [a for a in range(3) if a != axis]
        gu = np.arange(lo[u], hi[u] + 1e-9, spacing)
        gv = np.arange(lo[v], hi[v] + 1e-9, spacing)
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        pts = np.zeros((uu.size, 3))
        pts[:, u], pts[:, v] = uu.ravel(), vv.ravel()
        pts[:, axis] = hi[axis] if face.isupper() else lo[axis]
        out.append(pts)
    return np.concatenate(out)


def solids(parts: list[tuple[str, tuple, tuple]], spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Surfaces of solid boxes ``(name, lo, hi)``, without what lies inside another box (hidden)."""
    points, names = [], []
    for name, lo, hi in parts:
        pts = box_surface(lo, hi, spacing)
        hidden = np.zeros(len(pts), bool)
        for other, olo, ohi in parts:
            if (other, olo, ohi) != (name, lo, hi):
                hidden |= np.all((pts > np.add(olo, 1e-6)) & (pts < np.subtract(ohi, 1e-6)), axis=1)
        points.append(pts[~hidden])
        names += [name] * int((~hidden).sum())
    return np.concatenate(points), np.array(names)


def table(x: float, y: float, name: str = "table", size=(1.2, 0.8), height: float = 0.75) -> list:
    w, d = size
    legs = [(x + sx * (w / 2 - 0.05), y + sy * (d / 2 - 0.05)) for sx in (-1, 1) for sy in (-1, 1)]
    return [(name, (x - w / 2, y - d / 2, height - 0.03), (x + w / 2, y + d / 2, height))] + [
        (name, (lx - 0.025, ly - 0.025, 0.0), (lx + 0.025, ly + 0.025, height - 0.03)) for lx, ly in legs
    ]


def chair(x: float, y: float) -> list:
    """A seat at 0.45 m on four legs; the rear legs rise on into the back's posts, as most chairs'."""
    s = 0.22
    parts = [("chair", (x - s, y - s, 0.42), (x + s, y + s, 0.46))]
    for sx in (-1, 1):
        leg_x = x + sx * (s - 0.02)
        parts.append(("chair", (leg_x - 0.02, y - s, 0.0), (leg_x + 0.02, y - s + 0.04, 0.42)))
        parts.append(("chair", (leg_x - 0.02, y + s - 0.04, 0.0), (leg_x + 0.02, y + s, 0.95)))
    parts.append(("chair", (x - s + 0.04, y + s - 0.03, 0.62), (x + s - 0.04, y + s, 0.92)))  # the back rest
    return parts


def room_shell(spacing: float, around: np.ndarray | None = None, margin: float = 1.0) -> list[tuple[str, np.ndarray]]:
    """The empty ROOM's floor, ceiling and four walls as (name, points on a grid of ``spacing``).

    With ``around`` (objects' points), the walls stand ``margin`` beyond the objects' footprint
    instead of at the ROOM's far sides (never outside the ROOM, so a unit against a ROOM wall stays
    against it): the same scene in a smaller room, a third of the points or fewer to cluster."""
    lo, hi = np.zeros(2), np.array(ROOM[:2])
    if around is not None and len(around):
        lo = np.clip(around[:, :2].min(axis=0) - margin, lo, hi)
        hi = np.clip(around[:, :2].max(axis=0) + margin, lo, hi)
    (x0, y0), (x1, y1), lz = lo, hi, ROOM[2]
    return [
        ("floor", box_surface((x0, y0, 0), (x1, y1, 0), spacing, "z")),
        ("ceiling", box_surface((x0, y0, lz), (x1, y1, lz), spacing, "Z")),
        ("wall", box_surface((x0, y0, 0), (x0, y1, lz), spacing, "x")),
        ("wall", box_surface((x1, y0, 0), (x1, y1, lz), spacing, "X")),
        ("wall", box_surface((x0, y0, 0), (x1, y0, lz), spacing, "y")),
        ("wall", box_surface((x0, y1, 0), (x1, y1, lz), spacing, "Y")),
    ]


def synthetic_room(spacing: float = 0.02, tight: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A 6 x 5 x 2.6 m room (floor, four walls, ceiling; with ``tight``, walls 1 m around the
    furniture) with a table, a cup on it and a chair; points on a grid of ``spacing`` (as a TSDF map
    of that voxel size), and a name per point."""
    objects, names = solids(
        table(3.0, 2.5) + [("cup", (3.2, 2.4, 0.75), (3.28, 2.48, 0.85))] + chair(3.0, 3.35), spacing
    )
    layout = room_shell(spacing, around=objects if tight else None)
    points = np.concatenate([p for _, p in layout] + [objects])
    labels = np.concatenate([np.full(len(p), n) for n, p in layout] + [names])
    return points, labels


def test_room_floor_walls_ceiling_and_the_table_top():
    points, names = synthetic_room(0.02)
    layout = find_layout(points, 0.02)
    for name, label in (("floor", FLOOR), ("wall", WALL), ("ceiling", CEILING)):
        assert (layout.labels[names == name] == label).mean() > 0.95, name
    things = np.isin(names, ["table", "chair", "cup"])
    assert (layout.labels[things] != NONE).mean() < 0.02
    assert abs(layout.floor_height) < 0.02 and abs(layout.ceiling_height - ROOM[2]) < 0.02 and layout.walls == 4
    heights = sorted(round(s.height, 2) for s in layout.supports)
    assert any(0.71 <= h <= 0.76 for h in heights), heights  # the 3 cm top: its upper or lower face
    top = max(layout.supports, key=lambda s: s.area)
    assert (names[top.indices] == "table").mean() > 0.99 and abs(top.area - 0.96) < 0.1


def test_tabletop_scan_has_no_floor_and_one_support():
    """A partial map: a tabletop with boxes on it, no floor, no walls (a Kinect tabletop scan)."""
    spacing = 0.005
    top = box_surface((-0.6, -0.4, 0.0), (0.6, 0.4, 0.0), spacing, "z")
    boxes, _ = solids([("box", (-0.3, -0.1, 0.0), (-0.1, 0.1, 0.15)), ("box", (0.1, 0.0, 0.0), (0.2, 0.1, 0.1))], 0.005)
    points = np.concatenate([top, boxes[boxes[:, 2] > 0.001]])
    layout = find_layout(points, 0.015)
    assert layout.floor_height is None and layout.ceiling_height is None and layout.walls == 0
    assert (layout.labels == NONE).all()
    main = max(layout.supports, key=lambda s: s.area)
    assert abs(main.height) < 0.01 and len(main.indices) >= 0.95 * len(top)
    # Only the boxes' lowest row shares the table's cells.
    assert (main.indices >= len(top)).sum() < 0.1 * len(boxes)
    assert (points[main.indices, 2] < 0.02).all()


def bent_floor_room(spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The synthetic room seen as one real frame sees it: its floor bends down beyond y = 3 m, by 8 cm
    at the far wall (a single Kinect frame's depth at range)."""
    points, names = synthetic_room(spacing)
    points = points.copy()
    far = (names == "floor") & (points[:, 1] > 3.0)
    points[far, 2] -= 0.04 * (points[far, 1] - 3.0)
    return points, names


def test_a_floor_bent_at_range_is_the_floor_where_the_source_found_it():
    points, names = bent_floor_room(0.02)
    # Alone, the layout takes the bent far part, lowest, for the floor, and the near floor for none.
    alone = find_layout(points, 0.02)
    assert alone.floor_height < -0.05
    layout = find_layout(points, 0.02, floor_hint=0.0)
    assert abs(layout.floor_height) < 0.02 and layout.walls == 4
    near = (names == "floor") & (points[:, 1] < 3.0)
    assert (layout.labels[near] == FLOOR).mean() > 0.95
    # The support surfaces are the table's, measured from that floor.
    assert any(0.71 <= s.height <= 0.76 for s in layout.supports)


def test_a_floor_hint_makes_no_floor_of_a_tabletop():
    """The hint relaxes what may lie below a floor, not what makes one: a tabletop scan the source
    levelled with its table at z = 0 has no floor."""
    spacing = 0.005
    top = box_surface((-0.6, -0.4, 0.0), (0.6, 0.4, 0.0), spacing, "z")
    boxes, _ = solids([("box", (-0.3, -0.1, 0.0), (-0.1, 0.1, 0.15))], spacing)
    layout = find_layout(np.concatenate([top, boxes[boxes[:, 2] > 0.001]]), 0.015, floor_hint=0.0)
    assert layout.floor_height is None and (layout.labels == NONE).all()


def test_a_lone_wall_with_a_cabinet_in_front_and_no_floor():
    """A partial map: one wall and a tall cabinet standing before it; only the wall is layout (the
    sensor's side tells the room's: the cabinet's front has the wall beyond it)."""
    spacing = 0.02
    wall = box_surface((0, 0, 0.5), (4.0, 0, 2.6), spacing, "y")
    cabinet, _ = solids([("cabinet", (1.0, 0.0, 0.5), (2.0, 0.6, 2.5))], spacing)
    cabinet = cabinet[(cabinet[:, 1] > 0.01) & (cabinet[:, 2] > 0.51)]  # its back and bottom are unseen
    points = np.concatenate([wall, cabinet])
    layout = find_layout(points, spacing, viewpoints=np.array([[2.0, 3.0, 1.5]]))
    assert layout.floor_height is None and layout.walls == 1
    on_wall = (wall[:, 0] < 0.99) | (wall[:, 0] > 2.01)  # the part the cabinet does not hide
    assert (layout.labels[: len(wall)][on_wall] == WALL).mean() > 0.95
    assert (layout.labels[len(wall) :] == WALL).mean() < 0.02


def test_without_gravity_nothing_is_named():
    points, _ = synthetic_room(0.04)
    layout = find_layout(points, 0.04, gravity=False)
    assert (layout.labels == NONE).all() and layout.supports == [] and layout.floor_height is None


def test_given_normals_replace_the_estimate():
    points, names = synthetic_room(0.04)
    from stratamap.plugins.segmenters.clusters.grid import cell_normals

    normals = cell_normals(points, 0.12)
    a = find_layout(points, 0.04, normals=normals)
    b = find_layout(points, 0.04)
    assert (a.labels == b.labels).mean() > 0.99 and abs(a.floor_height - b.floor_height) < 1e-9
    assert LayoutParams().support_heights[0] < 0.75 < LayoutParams().support_heights[1]


def _seen_through(points: np.ndarray, view: np.ndarray, y: float, holes: list[tuple[float, float, float, float]]):
    """Which points beyond the plane y = ``y`` the ``view`` sees through one of the ``holes``
    (x0, x1, z0, z1) in it."""
    share = (view[1] - y) / (view[1] - points[:, 1])
    x = view + share[:, None] * (points - view)
    return np.any([(x[:, 0] > a) & (x[:, 0] < b) & (x[:, 2] > c) & (x[:, 2] < d) for a, b, c, d in holes], axis=0)


def test_a_wall_with_a_door_and_a_window_is_a_wall_though_the_sensor_saw_beyond_it():
    """A room scanned from one place (a 360-degree scan): its y = 0 wall has a door and a window,
    through which the scanner saw the corridor's floor and far wall. What lies beyond the wall was
    seen through its openings, under their lintels: it is still the room's wall."""
    spacing = 0.03
    view = np.array([3.0, 2.5, 1.2])
    holes = [(2.5, 3.5, 0.0, 2.0), (4.5, 5.5, 1.0, 2.0)]
    shell = dict(room_shell(spacing)[:2])
    walls = [p for name, p in room_shell(spacing)[2:]]
    door_wall = walls[2]
    opening = np.any(
        [
            (door_wall[:, 0] > a) & (door_wall[:, 0] < b) & (door_wall[:, 2] > c) & (door_wall[:, 2] < d)
            for a, b, c, d in holes
        ],
        axis=0,
    )
    walls[2] = door_wall[~opening]
    corridor = np.concatenate(
        [
            box_surface((0, -2.0, 0), (ROOM[0], -0.05, 0), spacing, "z"),
            box_surface((0, -2.0, 0), (ROOM[0], -2.0, ROOM[2]), spacing, "y"),
        ]
    )
    corridor = corridor[_seen_through(corridor, view, 0.0, holes)]
    assert len(corridor) > 200
    points = np.concatenate([shell["floor"], shell["ceiling"], *walls, corridor])
    layout = find_layout(points, spacing, viewpoints=view[None])
    start = len(shell["floor"]) + len(shell["ceiling"]) + sum(len(w) for w in walls[:2])
    assert (layout.labels[start : start + len(walls[2])] == WALL).mean() > 0.9  # its edges: floor, ceiling
    assert layout.walls >= 4


def test_a_partition_the_sensor_sees_over_is_no_wall():
    """A 1.4 m partition inside the room, the room's wall behind it seen over its top: no opening
    under a lintel lets the sensor see beyond the partition, so the partition is no wall."""
    spacing = 0.03
    view = np.array([3.0, 3.5, 1.6])
    partition = box_surface((1.5, 1.5, 0.0), (4.5, 1.5, 1.4), spacing, "Y")
    points = np.concatenate([p for _, p in room_shell(spacing)] + [partition])
    layout = find_layout(points, spacing, viewpoints=view[None])
    assert (layout.labels[-len(partition) :] == WALL).mean() < 0.05
    assert layout.walls == 4


def test_a_tall_cabinet_beside_a_counter_is_no_wall_though_their_plinth_lies_in_its_plane():
    """A tall cabinet in a room's corner and a counter run beside it, whose plinth lies in the
    cabinet front's plane (the counter's front stands 10 cm proud of it): one plane 1.6 m high, seen
    from the room. The sensor sees the counter's top and the wall behind it over the plinth, where
    that plane has no points below the cabinet's top; but those columns are the plinth's, and what
    is seen over a thing's top is no view through an opening: the cabinet is no wall (a rendered
    kitchen's 2.1 m cabinet was, before)."""
    spacing = 0.03
    lx, ly = ROOM[0], ROOM[1]
    top = 1.6  # what the sensor sees of the room reaches this high
    view = np.array([3.0, 3.5, 1.5])
    cabinet = box_surface((0.0, 0.6, 0.0), (0.6, 0.6, top), spacing, "y")
    plinth = box_surface((0.6, 0.6, 0.0), (lx, 0.6, 0.1), spacing, "y")
    counter = np.concatenate(
        [
            box_surface((0.6, 0.7, 0.1), (lx, 0.7, 0.9), spacing, "y"),
            box_surface((0.6, 0.0, 0.9), (lx, 0.7, 0.9), spacing, "Z"),
        ]
    )
    room = np.concatenate(
        [
            box_surface((0, 0.6, 0), (lx, ly, 0), spacing, "z"),
            box_surface((0.6, 0, 0.9), (lx, 0, top), spacing, "y"),
            box_surface((0, 0.6, 0), (0, ly, top), spacing, "x"),
            box_surface((lx, 0.7, 0), (lx, ly, top), spacing, "X"),
            box_surface((lx, 0.0, 0.9), (lx, 0.7, top), spacing, "X"),
            box_surface((0, ly, 0), (lx, ly, top), spacing, "Y"),
        ]
    )
    points = np.concatenate([room, counter, cabinet, plinth])
    layout = find_layout(points, spacing, viewpoints=view[None])
    fronts = layout.labels[-(len(cabinet) + len(plinth)) :]
    assert (fronts == WALL).mean() < 0.05
    far_wall = len(box_surface((0, ly, 0), (lx, ly, top), spacing, "Y"))
    assert (layout.labels[len(room) - far_wall : len(room)] == WALL).mean() > 0.9


def test_a_backsplash_between_a_worktop_and_wall_units_is_a_wall():
    """A kitchen wall seen only between a counter's worktop (0.9 m) and the wall units above it
    (from 1.5 m): a band 0.6 m high with nothing seen behind it is the room's wall, and the counter's
    front and the wall units' fronts in front of it are not."""
    spacing = 0.03
    lx, ly, lz = ROOM
    view = np.array([3.0, 3.5, 1.5])
    backsplash = box_surface((0.0, 0.0, 0.9), (lx, 0.0, 1.5), spacing, "y")
    fronts = np.concatenate(
        [
            box_surface((0.0, 0.6, 0.0), (lx, 0.6, 0.9), spacing, "y"),  # the counter's front
            box_surface((0.0, 0.35, 1.5), (lx, 0.35, 2.2), spacing, "y"),  # the wall units' fronts
        ]
    )
    tops = np.concatenate(
        [
            box_surface((0.0, 0.0, 0.9), (lx, 0.6, 0.9), spacing, "Z"),
            box_surface((0.0, 0.0, 1.5), (lx, 0.35, 1.5), spacing, "z"),
        ]
    )
    room = np.concatenate(
        [
            box_surface((0, 0.6, 0), (lx, ly, 0), spacing, "z"),
            box_surface((0, 0, lz), (lx, ly, lz), spacing, "Z"),
            box_surface((0, 0.6, 0), (0, ly, lz), spacing, "x"),
            box_surface((lx, 0.6, 0), (lx, ly, lz), spacing, "X"),
            box_surface((0, ly, 0), (lx, ly, lz), spacing, "Y"),
        ]
    )
    points = np.concatenate([room, tops, fronts, backsplash])
    layout = find_layout(points, spacing, viewpoints=view[None])
    assert (layout.labels[-len(backsplash) :] == WALL).mean() > 0.9
    assert (layout.labels[-(len(backsplash) + len(fronts)) : -len(backsplash)] == WALL).mean() < 0.05
    high = LayoutParams(wall_min_height=1.0, wall_min_area=0.8)  # the defaults before 2026-12-07
    assert (
        find_layout(points, spacing, viewpoints=view[None], params=high).labels[-len(backsplash) :] == WALL
    ).mean() < 0.1


def test_a_walls_distance_reaches_only_as_far_as_the_wall():
    """A partition 1 m long (x from 0 to 1, facing y): a point in front of it is its distance across,
    one in its plane 2 m past its end is 1 m away, not 0 (the naming features read this distance)."""
    from stratamap.plugins.segmenters.clusters.layout import LayoutPlane

    plane = LayoutPlane(WALL, np.array([0.0, 1.0, 0.0]), 0.0, (-1.0, 0.0))  # along = -x: x in [0, 1]
    points = np.array([[0.5, 0.3, 1.0], [2.0, 0.0, 1.0], [2.0, 0.4, 0.2]])
    assert np.allclose(plane.distance(points), [0.3, 1.0, np.hypot(1.0, 0.4)])


def _against_back_wall(spacing: float, unit: tuple[float, float, float, float], extra: list[np.ndarray] = ()):
    """The room with a unit (x0, x1, depth, height) standing against its y = 0 wall, whose part the
    unit hides is not seen; the unit's front and sides last in the points."""
    x0, x1, depth, height = unit
    shell = room_shell(spacing)
    back = shell[4][1]
    hidden = (back[:, 0] > x0) & (back[:, 0] < x1) & (back[:, 2] < height)
    room = np.concatenate([p for k, (_, p) in enumerate(shell) if k != 4] + [back[~hidden], *extra])
    front = box_surface((x0, 0.0, 0.0), (x1, depth, height), spacing, "xXY")
    return room, front


def test_a_fridge_side_in_one_plane_with_a_cabinet_across_the_room_is_no_wall():
    """A fridge against the back wall, its side (x = 2) in one plane with the side of a low cabinet
    2.6 m away across the room, seen from a walk passing close by the fridge (the room seen up to
    1.8 m): the plane fit joins the two sides into one candidate whose columns between them are empty.
    So wide a gap is no doorway; what the sensor sees across it (the fridge's own front, the floor and
    walls beyond) still counts, and the side is no wall."""
    spacing = 0.03
    view = np.array([1.9, 2.0, 1.5])
    far_side = box_surface((2.0, 3.25, 0.0), (2.0, 3.9, 1.0), spacing, "x")
    room, fridge = _against_back_wall(spacing, (2.0, 2.6, 0.65, 1.75), [far_side])
    room = room[room[:, 2] <= 1.8]
    side = np.isclose(fridge[:, 0], 2.0)
    points = np.concatenate([room, fridge])
    layout = find_layout(points, spacing, viewpoints=view[None])
    assert (layout.labels[-len(fridge) :][side] == WALL).mean() < 0.05
    assert layout.walls == 4
    # Every empty column an opening (as before 2026-12-08): the side was a wall with a 2.6 m "doorway".
    before = LayoutParams(doorway_max_width=10.0)
    labels = find_layout(points, spacing, viewpoints=view[None], params=before).labels
    assert (labels[-len(fridge) :][side] == WALL).mean() > 0.7  # its edges: floor, the back wall
