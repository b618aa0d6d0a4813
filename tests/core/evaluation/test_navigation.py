"""Navigation safety: plans keep to the mapped free space, and the figure draws them where they are."""

from __future__ import annotations

import numpy as np

from stratamap.core.evaluation.navigation import collides, evaluate_navigation, plan_path, traversable
from stratamap.core.map.layers import OccupancyGrid

RES = 0.05
ROOM = 4.0  # walls' outer side: a square room [0, 4] x [0, 4] m, walls 0.1 m thick


def room_grids(seen_margin: float = 1.5) -> tuple[OccupancyGrid, OccupancyGrid, OccupancyGrid]:
    """A mapped room as an occupancy mapper leaves it (walls occupied, the floor inside free, unknown
    all around: the sensor never saw past the walls), a chair the laser passes under (free on the
    laser map, occupied on the multimap) and the truth (the walls and the chair, over the room plus
    0.2 m, as synthetic ground truth is)."""
    n = int(round((ROOM + 2 * seen_margin) / RES))
    origin = (-seen_margin, -seen_margin, 0.0)
    xy = np.stack(np.meshgrid((np.arange(n) + 0.5) * RES, (np.arange(n) + 0.5) * RES, indexing="xy"), -1) - seen_margin
    x, y = xy[..., 0], xy[..., 1]
    inside = (x > 0.1) & (x < ROOM - 0.1) & (y > 0.1) & (y < ROOM - 0.1)
    wall = (x >= 0) & (x <= ROOM) & (y >= 0) & (y <= ROOM) & ~inside
    chair = (np.abs(x - 2.0) < 0.25) & (np.abs(y - 2.0) < 0.25)
    slam = np.full((n, n), -1, np.int8)
    slam[inside] = 0
    slam[wall] = 100
    multimap = slam.copy()
    multimap[chair] = 100
    m = int(round((ROOM + 0.4) / RES))
    txy = np.stack(np.meshgrid((np.arange(m) + 0.5) * RES, (np.arange(m) + 0.5) * RES, indexing="xy"), -1) - 0.2
    tx, ty = txy[..., 0], txy[..., 1]
    t_inside = (tx > 0.1) & (tx < ROOM - 0.1) & (ty > 0.1) & (ty < ROOM - 0.1)
    t_wall = (tx >= 0) & (tx <= ROOM) & (ty >= 0) & (ty <= ROOM) & ~t_inside
    t_chair = (np.abs(tx - 2.0) < 0.25) & (np.abs(ty - 2.0) < 0.25)
    truth = np.where(t_wall | t_chair, 100, 0).astype(np.int8)
    return (
        OccupancyGrid(slam, RES, origin),
        OccupancyGrid(multimap, RES, origin),
        OccupancyGrid(truth, RES, (-0.2, -0.2, 0.0)),
    )


def test_plans_stay_inside_the_walls():
    slam, multimap, truth = room_grids()
    nav = evaluate_navigation(slam, multimap, truth, robot_radius=0.3, pairs=12, seed=0)
    assert nav["paths"] >= 6
    for rec in nav["records"]:
        for key in ("laser_only", "multimap"):
            xy = np.asarray(rec[key])
            # Inside the room, the robot's disc clear of the walls' inner side (0.1 m thick walls).
            assert (xy > 0.1 + 0.3 - RES).all() and (xy < ROOM - 0.1 - 0.3 + RES).all(), (key, xy.min(0), xy.max(0))
            # Every cell of the plan free on its map.
            grid = slam if key == "laser_only" else multimap
            rc = grid.world_to_cell(xy)
            assert (grid.data[rc[:, 0], rc[:, 1]] == 0).all()
        assert not rec["multimap_collides"]
    # The laser-only map lets some paths through the chair; the multimap never does.
    assert nav["colliding_laser_only"] >= 1 and nav["colliding_multimap"] == 0


def test_unknown_space_and_the_space_beyond_the_grid_are_not_traversable():
    _, multimap, _ = room_grids()
    free = traversable(multimap, 0.3)
    assert not free[multimap.data < 0].any()
    # A goal outside the walls (in never-seen space) is unreachable.
    assert plan_path(multimap, np.array([1.0, 1.0]), np.array([-1.0, -1.0]), 0.3) is None
    # A free map with no border: the disc may not reach past the grid's edge either.
    open_grid = OccupancyGrid(np.zeros((40, 40), np.int8), RES)
    free = traversable(open_grid, 0.32)  # 6.4 cells: the outer 6 rings of cells are too close to the edge
    assert not free[:6].any() and not free[:, -6:].any() and free[6:-6, 6:-6].all()
    assert traversable(open_grid, 0.32, unknown_is_free=True).all()


def test_a_path_leaving_the_truth_counts_as_colliding():
    _, _, truth = room_grids()
    from stratamap.core.evaluation.navigation import Plan

    outside = np.array([[-0.6, 1.0], [-0.6, 2.0], [-0.6, 3.0]])  # beyond the wall and the truth's margin
    assert collides(Plan(np.zeros((3, 2), int), outside, 2.0), truth, 0.3)
    inside = np.array([[1.0, 1.0], [1.0, 2.0], [1.0, 3.0]])
    assert not collides(Plan(np.zeros((3, 2), int), inside, 2.0), truth, 0.3)


def test_navigation_figure_draws_each_grid_and_the_paths_in_world_coordinates(tmp_path, monkeypatch):
    from stratamap.core.evaluation import bench_report

    slam, multimap, truth = room_grids()
    # The laser map on a grid of its own (another origin and resolution than the multimap's).
    slam = OccupancyGrid(slam.data[::2, ::2], 2 * RES, (-1.5, -1.5, 0.0))
    nav = evaluate_navigation(room_grids()[0], multimap, truth, robot_radius=0.3, pairs=4, seed=0)
    run = tmp_path / "runs" / "s" / "v"
    run.mkdir(parents=True)
    np.savez(
        run / "navigation.npz",
        slam=slam.data,
        multimap=multimap.data,
        truth=truth.data,
        origin=np.asarray(multimap.origin),
        resolution=multimap.resolution,
        slam_origin=np.asarray(slam.origin),
        slam_resolution=slam.resolution,
        truth_origin=np.asarray(truth.origin),
        truth_resolution=truth.resolution,
    )
    rec = {
        "scene": "s",
        "variant": "v",
        "metrics": {"navigation": {"robot_radius": 0.3}},
        "details": {"navigation": nav["records"]},
    }
    figures = []

    def keep(fig, path):
        figures.append(fig)
        return path

    monkeypatch.setattr(bench_report, "_save", keep)
    assert bench_report.navigation_figure([rec], tmp_path) == tmp_path / "navigation.png"
    ax_laser, ax_multi = figures[0].axes[:2]
    for ax, grid, key in ((ax_laser, slam, "laser_only"), (ax_multi, multimap, "multimap")):
        ox, oy, _ = grid.origin
        extent = (ox, ox + grid.width * grid.resolution, oy, oy + grid.height * grid.resolution)
        assert np.allclose(ax.images[0].get_extent(), extent)
        lines = [np.asarray(line.get_xydata()) for line in ax.lines]
        assert len(lines) == len(nav["records"])
        for line, path in zip(lines, nav["records"], strict=True):
            assert np.allclose(line, path[key])
            assert (line > 0.1).all() and (line < ROOM - 0.1).all()
