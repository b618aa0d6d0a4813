"""Navigation safety: plan a disc robot's path with A* on an occupancy grid, and check the path
against ground-truth obstacles (first paper, section V-C: a laser map lets a robot drive into
chair seats its laser passes under; the multimap does not)."""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from stratamap.core.map.layers import OccupancyGrid

NEIGHBOURS = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)]


@dataclass
class Plan:
    cells: np.ndarray  # (N, 2) row, col
    xy: np.ndarray  # (N, 2) world
    length_m: float


def traversable(grid: OccupancyGrid, robot_radius: float, unknown_is_free: bool = False) -> np.ndarray:
    """Cells where a disc of ``robot_radius`` centred on the cell touches no occupied (or unknown) cell."""
    blocked = grid.data >= 65
    if not unknown_is_free:
        blocked |= grid.data < 0
    if not blocked.any():
        return np.ones(grid.data.shape, bool)
    dist = ndimage.distance_transform_edt(~blocked) * grid.resolution
    return dist > robot_radius


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
    ``obstacles`` (e.g. the ground-truth projection of everything in [0.1 m, robot height])."""
    occupied = obstacles.data >= 65
    if not occupied.any():
        return False
    dist = ndimage.distance_transform_edt(~occupied) * obstacles.resolution
    rc = obstacles.world_to_cell(plan.xy)
    ok = obstacles.in_bounds(rc)
    # A small tolerance for discretization: the robot may graze an obstacle's cell boundary.
    return bool(np.any(dist[rc[ok, 0], rc[ok, 1]] < robot_radius - obstacles.resolution))


def evaluate_navigation(
    slam: OccupancyGrid,
    multimap: OccupancyGrid,
    truth: OccupancyGrid,
    robot_radius: float = 0.4,
    pairs: int = 12,
    seed: int = 0,
) -> dict:
    """Plan between start/goal pairs (free for the robot on the multimap) on both maps and count
    paths that touch ground-truth obstacles."""
    import itertools

    free = traversable(multimap, robot_radius, True)
    cells = np.argwhere(free)
    if len(cells) < 2:
        return {"paths": 0, "colliding_laser_only": 0, "colliding_multimap": 0}
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
        p_laser = plan_path(slam, s, g, robot_radius, True)
        p_multi = plan_path(multimap, s, g, robot_radius, True)
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
