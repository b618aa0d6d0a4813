"""Camera paths through a scene: a teleoperated-robot walk through free space, an orbit, a fixed view, and a tour
that sees every object of a scene of any size."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.geometry.transforms import look_at
from stratamap.core.lazy import lazy_module
from stratamap.core.synthetic.scene import Scene
from stratamap.core.synthetic.spec import TrajectorySpec

ndimage = lazy_module("scipy.ndimage")
spatial = lazy_module("scipy.spatial")
sparse = lazy_module("scipy.sparse")
csgraph = lazy_module("scipy.sparse.csgraph")

GRID = 0.05


def free_space(scene: Scene, clearance: float) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) from each cell to the nearest obstacle or wall, and the grid's origin."""
    lx, ly, _ = scene.room_size
    shape = (int(np.ceil(ly / GRID)), int(np.ceil(lx / GRID)))
    occupied = np.zeros(shape, bool)
    for obj in scene.objects:
        for _, mesh in obj.world_parts():
            lo, hi = mesh.bounds
            if lo[2] > 2.0:
                continue
            r0, c0 = int(np.floor(lo[1] / GRID)), int(np.floor(lo[0] / GRID))
            r1, c1 = int(np.ceil(hi[1] / GRID)), int(np.ceil(hi[0] / GRID))
            occupied[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = True
    occupied[0, :] = occupied[-1, :] = occupied[:, 0] = occupied[:, -1] = True
    dist = ndimage.distance_transform_edt(~occupied) * GRID
    return dist, np.zeros(2)


def _resample_loop(points: np.ndarray, n: int) -> np.ndarray:
    closed = np.vstack([points, points[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0], np.cumsum(seg)])
    t = np.linspace(0, s[-1], n, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, k]) for k in range(2)], 1)


def walk(scene: Scene, spec: TrajectorySpec, rng: np.random.Generator) -> list[np.ndarray]:
    """A loop around the room, kept ``clearance`` from obstacles, looking toward the room's middle."""
    lx, ly, _ = scene.room_size
    dist, _ = free_space(scene, spec.clearance)
    ok = dist >= spec.clearance
    inset = np.array([min(1.0, lx / 2 - 0.05), min(1.0, ly / 2 - 0.05)])
    corners = np.array(
        [[inset[0], inset[1]], [lx - inset[0], inset[1]], [lx - inset[0], ly - inset[1]], [inset[0], ly - inset[1]]]
    )
    loop = _resample_loop(corners, 400)
    if ok.any():
        # Move every waypoint to the nearest cell with enough clearance.
        _, (ri, ci) = ndimage.distance_transform_edt(~ok, return_indices=True)
        rc = np.clip(np.floor(loop[:, ::-1] / GRID).astype(int), 0, np.array(ok.shape) - 1)
        loop = np.stack([ci[rc[:, 0], rc[:, 1]], ri[rc[:, 0], rc[:, 1]]], 1) * GRID + GRID / 2
    # Smooth the loop (circular moving average) and resample at even spacing.
    k = 15
    padded = np.vstack([loop[-k:], loop, loop[:k]])
    kernel = np.ones(2 * k + 1) / (2 * k + 1)
    loop = np.stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(2)], 1)
    path = _resample_loop(loop, spec.frames)
    center = np.array([lx / 2, ly / 2])
    phase = rng.uniform(0, 2 * np.pi)
    poses = []
    for k, p in enumerate(path):
        # Look mostly toward the room's middle, with a slow sweep as a teleoperator would.
        to_center = center - p
        heading = np.arctan2(to_center[1], to_center[0]) + 0.35 * np.sin(
            2 * np.pi * 3 * k / max(spec.frames, 1) + phase
        )
        target = np.array([p[0] + 2.0 * np.cos(heading), p[1] + 2.0 * np.sin(heading), spec.look_height])
        eye = np.array([p[0], p[1], spec.height + 0.02 * np.sin(0.5 * k)])
        poses.append(look_at(eye, target))
    return poses


def orbit(scene: Scene, spec: TrajectorySpec) -> list[np.ndarray]:
    """An ellipse inside the room looking at its center."""
    lx, ly, _ = scene.room_size
    center = np.array([lx / 2, ly / 2])
    rx, ry = max(lx / 2 - 0.45, 0.5), max(ly / 2 - 0.45, 0.5)
    poses = []
    for k in range(spec.frames):
        a = 2 * np.pi * k / max(spec.frames, 1)
        eye = np.array([center[0] + rx * np.cos(a), center[1] + ry * np.sin(a), spec.height])
        poses.append(look_at(eye, [center[0], center[1], spec.look_height]))
    return poses


def fixed(scene: Scene, spec: TrajectorySpec) -> list[np.ndarray]:
    """One viewpoint from a corner, looking across the room (repeated ``frames`` times)."""
    lx, ly, _ = scene.room_size
    eye = np.array([0.4, 0.4, spec.height])
    pose = look_at(eye, [lx / 2, ly / 2, spec.look_height])
    return [pose.copy() for _ in range(spec.frames)]


#: tour: candidate viewpoints lie on a lattice of this pitch (m) over the free space; paths between
#: them are planned on a grid of PATH_GRID.
VIEWPOINT_PITCH = 0.4
PATH_GRID = 0.1
#: tour: surface points per object that decide from where it is seen; a viewpoint sees an object
#: well enough when it sees this share of what the object's best viewpoint sees.
TOUR_SAMPLES = 24
GOOD_VIEW = 0.7
MIN_VIEW_DISTANCE = 0.6


def _largest_component(ok: np.ndarray) -> np.ndarray:
    labels, n = ndimage.label(ok)
    if n <= 1:
        return ok
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


def _viewpoint_visibility(scene: Scene, spec: TrajectorySpec, cast: Any, eyes: np.ndarray, seed: int) -> np.ndarray:
    """(viewpoints, objects): the share of each object's sample points each eye sees within range."""
    from stratamap.core.synthetic.coverage import scene_samples, visible

    samples = scene_samples(scene, TOUR_SAMPLES, seed)
    n_obj = len(scene.objects)
    score = np.zeros((len(eyes), n_obj))
    if n_obj == 0:
        return score
    tree = spatial.cKDTree(samples.points)
    for v, eye in enumerate(eyes):
        near = np.asarray(tree.query_ball_point(eye, spec.view_range), np.int64)
        if len(near) == 0:
            continue
        hit = visible(cast, eye, samples.points[near], samples.normals[near], MIN_VIEW_DISTANCE, spec.view_range)
        score[v] = np.bincount(samples.owner[near[hit]], minlength=n_obj) / TOUR_SAMPLES
    return score


def _cover(score: np.ndarray) -> list[tuple[int, list[int]]]:
    """Greedy set cover: viewpoints, each with the objects it is chosen for, until every object
    some viewpoint sees is seen from one that sees it nearly as well as its best."""
    best = score.max(0) if len(score) else np.zeros(score.shape[1])
    good = (score >= GOOD_VIEW * best) & (best > 0)
    todo = best > 0
    chosen: list[tuple[int, list[int]]] = []
    while todo.any():
        gain = (good & todo).sum(1)
        # Most objects first, then the better views of them (ties to the lowest index: deterministic).
        quality = (score * (good & todo)).sum(1)
        v = int(np.lexsort((-quality, -gain))[0])
        objs = [int(o) for o in np.flatnonzero(good[v] & todo)]
        chosen.append((v, objs))
        todo[objs] = False
    return chosen


def _order(dist: np.ndarray) -> list[int]:
    """An open path through every stop: nearest neighbour from stop 0, then 2-opt."""
    n = len(dist)
    if n <= 2:
        return list(range(n))
    order, left = [0], set(range(1, n))
    while left:
        last = order[-1]
        nxt = min(left, key=lambda j: (dist[last, j], j))
        order.append(nxt)
        left.remove(nxt)
    improved = True
    while improved:
        improved = False
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                a, b = order[i - 1], order[i]
                c = order[j]
                d = order[j + 1] if j + 1 < n else None
                before = dist[a, b] + (dist[c, d] if d is not None else 0.0)
                after = dist[a, c] + (dist[b, d] if d is not None else 0.0)
                if after < before - 1e-9:
                    order[i : j + 1] = order[i : j + 1][::-1]
                    improved = True
    return order


def _yaw_pitch(eye: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    d = target - eye
    return float(np.arctan2(d[1], d[0])), float(np.arctan2(d[2], np.hypot(d[0], d[1])))


def tour(scene: Scene, spec: TrajectorySpec, seed: int, cast: Any) -> list[np.ndarray]:
    """A path through the free space past viewpoints that together see every object, looking at
    them in turn; frames are spread along it (``dwell`` of them turning at the viewpoints).

    Viewpoints: a lattice over the free space kept ``clearance`` from obstacles; from each, the share
    of every object's surface samples it sees within ``view_range`` (ray cast). A greedy set cover
    picks viewpoints until each object has one that sees it nearly as well as its best; the stops
    are ordered by path length on the free grid (nearest neighbour and 2-opt) and joined by
    shortest paths. Cost grows with the floor area and the objects, not with their product."""
    lx, ly, _ = scene.room_size
    dist, _ = free_space(scene, spec.clearance)
    ok = _largest_component(dist >= spec.clearance)
    if not ok.any():
        return walk(scene, spec, np.random.default_rng([seed, 104729]))
    step = max(1, int(round(VIEWPOINT_PITCH / GRID)))
    rows, cols = np.nonzero(ok[step // 2 :: step, step // 2 :: step])
    rows, cols = rows * step + step // 2, cols * step + step // 2
    eyes = np.stack([cols * GRID + GRID / 2, rows * GRID + GRID / 2, np.full(len(rows), spec.height)], 1)
    score = _viewpoint_visibility(scene, spec, cast, eyes, seed)
    stops = _cover(score)
    if not stops:
        return walk(scene, spec, np.random.default_rng([seed, 104729]))

    # Shortest paths between stops on a coarser grid of the free space (8-connected).
    k = max(1, int(round(PATH_GRID / GRID)))
    coarse = ndimage.minimum_filter(ok.astype(np.uint8), size=k)[k // 2 :: k, k // 2 :: k].astype(bool)
    shape = coarse.shape
    node = -np.ones(shape, np.int64)
    node[coarse] = np.arange(int(coarse.sum()))
    rr, cc = np.nonzero(coarse)
    edges_a, edges_b, weights = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rr + dr, cc + dc
        inside = (r2 >= 0) & (r2 < shape[0]) & (c2 >= 0) & (c2 < shape[1])
        r2, c2, r1, c1 = r2[inside], c2[inside], rr[inside], cc[inside]
        both = coarse[r2, c2]
        edges_a.append(node[r1[both], c1[both]])
        edges_b.append(node[r2[both], c2[both]])
        weights.append(np.full(int(both.sum()), np.hypot(dr, dc) * k * GRID))
    n_nodes = int(coarse.sum())
    graph = sparse.coo_matrix(
        (np.concatenate(weights), (np.concatenate(edges_a), np.concatenate(edges_b))), shape=(n_nodes, n_nodes)
    ).tocsr()
    cell_xy = np.stack([cc * k * GRID + k * GRID / 2, rr * k * GRID + k * GRID / 2], 1)
    stop_xy = eyes[[v for v, _ in stops], :2]
    stop_node = spatial.cKDTree(cell_xy).query(stop_xy)[1].astype(np.int64)
    geo, pred = csgraph.dijkstra(graph, directed=False, indices=stop_node, return_predecessors=True)
    between = geo[:, stop_node]
    between = np.where(np.isfinite(between), between, 1e6)
    order = _order(between)

    # The path: the stops in order, joined by their shortest paths (cell centres), stop to stop.
    legs: list[np.ndarray] = []
    for a, b in zip(order[:-1], order[1:], strict=False):
        cells, cur = [], int(stop_node[b])
        while cur != stop_node[a] and cur >= 0:
            cells.append(cur)
            cur = int(pred[a, cur])
        inner = cell_xy[cells[::-1][:-1]] if len(cells) > 1 else np.zeros((0, 2))
        legs.append(np.vstack([stop_xy[a], inner, stop_xy[b]]))

    # Where to look at each stop: one heading per group of its objects that fits in the view.
    objects = scene.objects
    centers = np.array([obj.pose[:3, 3] for obj in objects]) if objects else np.zeros((0, 3))
    for i, obj in enumerate(objects):
        lo = np.min([mesh.bounds[0] for _, mesh in obj.world_parts()], axis=0)
        hi = np.max([mesh.bounds[1] for _, mesh in obj.world_parts()], axis=0)
        centers[i] = (lo + hi) / 2
    half_fov = np.radians(24.0)
    views: list[list[tuple[float, float]]] = []
    for idx in order:
        v, objs = stops[idx]
        eye = eyes[v]
        angles = sorted((_yaw_pitch(eye, centers[o]), o) for o in objs)
        groups: list[list[tuple[float, float]]] = []
        for (yaw, pitch), _ in angles:
            if groups and abs(np.angle(np.exp(1j * (yaw - groups[-1][0][0])))) <= half_fov:
                groups[-1].append((yaw, pitch))
            else:
                groups.append([(yaw, pitch)])
        views.append(
            [
                (float(np.angle(np.mean(np.exp(1j * np.array([y for y, _ in g]))))), float(np.mean([p for _, p in g])))
                for g in groups
            ]
        )

    # Frames: ``dwell`` of them shared out over the headings at stops, the rest over the path by length.
    n_views = sum(len(v) for v in views)
    dwell_frames = int(round(spec.frames * spec.dwell)) if len(order) > 1 else spec.frames
    dwell_frames = min(max(dwell_frames, min(n_views, spec.frames)), spec.frames)
    travel_frames = spec.frames - dwell_frames
    per_view = np.full(n_views, dwell_frames // max(n_views, 1))
    per_view[: dwell_frames - int(per_view.sum())] += 1
    lengths = np.array([np.linalg.norm(np.diff(leg, axis=0), axis=1).sum() for leg in legs])
    per_leg = np.zeros(len(legs), np.int64)
    if len(legs) and travel_frames > 0:
        share = lengths / max(lengths.sum(), 1e-9) * travel_frames
        per_leg = np.floor(share).astype(np.int64)
        per_leg[np.argsort(-(share - per_leg), kind="stable")[: travel_frames - int(per_leg.sum())]] += 1

    samples: list[tuple[np.ndarray, float, float]] = []  # (xy, yaw, pitch) per frame
    view_iter = iter(per_view)
    for i, idx in enumerate(order):
        xy = stop_xy[idx]
        for yaw, pitch in views[i]:
            samples.extend((xy, yaw, pitch) for _ in range(int(next(view_iter))))
        if i < len(legs) and per_leg[i] > 0:
            leg = legs[i]
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(leg, axis=0), axis=1))])
            (y0, p0), (y1, p1) = views[i][-1], views[i + 1][0]
            turn = float(np.angle(np.exp(1j * (y1 - y0))))
            for t in (np.arange(per_leg[i]) + 1) / (per_leg[i] + 1):
                pos = np.array([np.interp(t * s[-1], s, leg[:, 0]), np.interp(t * s[-1], s, leg[:, 1])])
                samples.append((pos, y0 + t * turn, p0 + t * (p1 - p0)))
    poses = []
    for xy, yaw, pitch in samples[: spec.frames]:
        eye = np.array([xy[0], xy[1], spec.height])
        direction = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
        poses.append(look_at(eye, eye + direction))
    while len(poses) < spec.frames:  # only when there are fewer headings than frames allow
        poses.append(poses[-1].copy())
    return poses


def make_trajectory(scene: Scene, spec: TrajectorySpec, seed: int, cast: Any = None) -> list[np.ndarray]:
    """The camera-to-world poses of ``spec``'s path; ``cast`` (distances along rays, as
    :meth:`SceneRenderer.cast`) is what a tour sees with, made from the scene when not given."""
    rng = np.random.default_rng([seed, 104729])
    if spec.type == "walk":
        return walk(scene, spec, rng)
    if spec.type == "orbit":
        return orbit(scene, spec)
    if spec.type == "tour":
        if cast is None:
            from stratamap.core.synthetic.render import SceneRenderer

            cast = SceneRenderer(scene).cast
        return tour(scene, spec, seed, cast)
    return fixed(scene, spec)


def drift(poses: list[np.ndarray], std: float, seed: int) -> list[np.ndarray]:
    """Reported poses that drift from the true ones (a random walk in translation and yaw)."""
    if std <= 0:
        return [p.copy() for p in poses]
    rng = np.random.default_rng([seed, 15485863])
    offset = np.zeros(3)
    yaw = 0.0
    out = []
    for p in poses:
        offset += rng.normal(0, std, 3) * np.array([1.0, 1.0, 0.2])
        yaw += rng.normal(0, std / 10)
        c, s = np.cos(yaw), np.sin(yaw)
        d = np.eye(4)
        d[:2, :2] = [[c, -s], [s, c]]
        d[:3, 3] = offset
        out.append(d @ p)
    return out
