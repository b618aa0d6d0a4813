"""Navigation safety: plan a disc robot's path with A* on an occupancy grid, and check the path
against ground-truth obstacles (first paper, section V-C: a laser map lets a robot drive into
chair seats its laser passes under; the multimap does not).

Plans stay in the mapped free space: unknown cells (and everything beyond the grid) are not
traversable, and start and goal are cells free for the robot both on the map and in the truth. A
path that leaves the ground-truth grid counts as colliding: nothing there vouches for it (with
unknown space free, plans used to run around the outside of the room's walls, never seen by the
sensor and beyond the truth, and were counted as safe).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import OccupancyGrid

ndimage = lazy_module("scipy.ndimage")

NEIGHBOURS = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)]


@dataclass
class Plan:
    cells: np.ndarray  # (N, 2) row, col
    xy: np.ndarray  # (N, 2) world
    length_m: float


def traversable(grid: OccupancyGrid, robot_radius: float, unknown_is_free: bool = False) -> np.ndarray:
    """Cells where a disc of ``robot_radius`` centred on the cell touches no occupied (or unknown) cell.

    Unless ``unknown_is_free``, the space beyond the grid is unknown too: the disc may not reach
    past the grid's border."""
    blocked = grid.data >= 65
    if not unknown_is_free:
        blocked = np.pad(blocked | (grid.data < 0), 1, constant_values=True)
    if not blocked.any():
        return np.ones(grid.data.shape, bool)
    dist = ndimage.distance_transform_edt(~blocked) * grid.resolution
    if not unknown_is_free:
        dist = dist[1:-1, 1:-1]
    return dist > robot_radius


def clearance(grid: OccupancyGrid) -> np.ndarray:
    """Distance (m) from every cell to the nearest occupied cell of ``grid`` (inf when none is)."""
    occupied = grid.data >= 65
    if not occupied.any():
        return np.full(grid.data.shape, np.inf)
    return ndimage.distance_transform_edt(~occupied) * grid.resolution


def astar(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    """8-connected A* on a boolean grid (octile heuristic); None when the goal is unreachable."""
    if not (free[start] and free[goal]):
        return None
    h, w = free.shape

    def heuristic(rc: tuple[int, int]) -> float:
        dr, dc = abs(rc[0] - goal[0]), abs(rc[1] - goal[1])
        return max(dr, dc) + (np.sqrt(2) - 1) * min(dr, dc)

    open_heap = [(heuristic(start), 0.0, start)]
    came: dict[tuple[int, int], tuple[int, int]] = {}
    cost = {start: 0.0}
    while open_heap:
        _, g, cur = heapq.heappop(open_heap)
        if cur == goal:
            path = [cur]
            while cur in came:
                cur = came[cur]
                path.append(cur)
            return path[::-1]
        if g > cost.get(cur, np.inf):
            continue
        for dr, dc in NEIGHBOURS:
            nxt = (cur[0] + dr, cur[1] + dc)
            if not (0 <= nxt[0] < h and 0 <= nxt[1] < w) or not free[nxt]:
                continue
            if dr and dc and not (free[cur[0] + dr, cur[1]] and free[cur[0], cur[1] + dc]):
                continue  # no corner cutting
            ng = g + (np.sqrt(2) if dr and dc else 1.0)
            if ng < cost.get(nxt, np.inf):
                cost[nxt] = ng
                came[nxt] = cur
                heapq.heappush(open_heap, (ng + heuristic(nxt), ng, nxt))
    return None


def plan_path(
    grid: OccupancyGrid, start_xy: np.ndarray, goal_xy: np.ndarray, robot_radius: float, unknown_is_free: bool = False
) -> Plan | None:
    free = traversable(grid, robot_radius, unknown_is_free)
    s = tuple(int(v) for v in grid.world_to_cell(np.asarray(start_xy)[None])[0])
    g = tuple(int(v) for v in grid.world_to_cell(np.asarray(goal_xy)[None])[0])
    inside = grid.in_bounds(np.array([s, g]))
    if not inside.all():
        return None
    cells = astar(free, s, g)  # type: ignore[arg-type]
    if cells is None:
        return None
    arr = np.array(cells)
    xy = grid.cell_to_world(arr)
    return Plan(arr, xy, float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()))


def collides(plan: Plan, obstacles: OccupancyGrid, robot_radius: float) -> bool:
    """Whether a disc of ``robot_radius`` moving along the plan touches an occupied cell of
    ``obstacles`` (e.g. the ground-truth projection of everything in [0.1 m, robot height]), or
    leaves the grid of ``obstacles`` (where nothing is known, nothing is certified free)."""
    rc = obstacles.world_to_cell(plan.xy)
    if not obstacles.in_bounds(rc).all():
        return True
    # A small tolerance for discretization: the robot may graze an obstacle's cell boundary.
    return bool(np.any(clearance(obstacles)[rc[:, 0], rc[:, 1]] < robot_radius - obstacles.resolution))


def evaluate_navigation(
    slam: OccupancyGrid,
    multimap: OccupancyGrid,
    truth: OccupancyGrid,
    robot_radius: float = 0.4,
    pairs: int = 12,
    seed: int = 0,
) -> dict:
    """Plan between start/goal pairs on both maps and count paths that touch ground-truth obstacles.

    Start and goal are cells where the robot fits on the multimap (known free space: never unknown
    space, so never outside the walls) and in the truth; plans keep to known free space. On the
    laser-only map (the multimap without its object band) every such pair is free as well."""
    import itertools

    free = traversable(multimap, robot_radius)
    cells = np.argwhere(free)
    # ... and free for the robot in the truth too (a start inside a true obstacle makes every path collide).
    rc = truth.world_to_cell(multimap.cell_to_world(cells))
    inside = truth.in_bounds(rc)
    clear = np.zeros(len(cells), bool)
    clear[inside] = clearance(truth)[rc[inside, 0], rc[inside, 1]] >= robot_radius - truth.resolution
    cells = cells[clear]
    if len(cells) < 2:
        return {
            "paths": 0,
            "colliding_laser_only": 0,
            "colliding_multimap": 0,
            "robot_radius": robot_radius,
            "records": [],
        }
    rng = np.random.default_rng(seed)
    picks = cells[rng.choice(len(cells), min(len(cells), 2 * pairs), replace=False)]
    n = laser_hits = multi_hits = 0
    records = []
    for a, b in itertools.islice(itertools.combinations(range(len(picks)), 2), 4 * pairs):
        if n >= pairs:
            break
        s, g = multimap.cell_to_world(picks[[a, b]])
        if np.linalg.norm(s - g) < 1.0:
            continue
        p_laser = plan_path(slam, s, g, robot_radius)
        p_multi = plan_path(multimap, s, g, robot_radius)
        if p_laser is None or p_multi is None:
            continue
        n += 1
        hit_l, hit_m = collides(p_laser, truth, robot_radius), collides(p_multi, truth, robot_radius)
        laser_hits += hit_l
        multi_hits += hit_m
        records.append(
            {
                "start": s.tolist(),
                "goal": g.tolist(),
                "laser_only": p_laser.xy.tolist(),
                "multimap": p_multi.xy.tolist(),
                "laser_collides": hit_l,
                "multimap_collides": hit_m,
            }
        )
    return {
        "paths": n,
        "colliding_laser_only": int(laser_hits),
        "colliding_multimap": int(multi_hits),
        "robot_radius": robot_radius,
        "records": records,
    }
