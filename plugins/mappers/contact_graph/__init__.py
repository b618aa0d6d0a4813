"""Mapper ``contact_graph``: who supports whom (functional-scenes paper, section 2, in part).

A parent can support a child when it has a horizontal surface at the child's bottom height
(eq. 1: parent points within ``contact_tolerance`` of that height) and that surface covers at
least ``min_overlap`` (b_th) of the child's footprint (eq. 2). The surface's extent is the convex
hull of those points, so a tabletop hidden under the child still counts (the paper's hidden
supporting plane). Among valid parents the largest contact ratio wins (eq. 3); objects without
one stand on the floor, unless they hang above it next to a wall (wall support). Every node
carries its surface planes (iterative RANSAC, inliers removed after each plane) and a refined box
extended down to its supporting plane (the paper's Table 4 "refined"). Layout nodes (floor, walls,
ceiling) hang off the ``scene`` root; proximal edges join objects whose boxes touch.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.geometry.boxes import footprint_overlap
from stratamap.core.map.layers import ContactGraph
from stratamap.core.map.priors import plausible_heights
from stratamap.plugins.mappers._floor import floor_height
from stratamap.plugins.mappers.contact_graph.unseen import grow_into_unseen, seen_free_below, usual_depth

__all__ = ["ContactGraphConfig", "ContactGraphMapper", "grow_into_unseen", "seen_free_below", "usual_depth"]


def support_ratio(child_box, surface_xy: np.ndarray) -> float:
    """Area (m^2) of the child's footprint covered by the convex hull of a parent's surface points."""
    from scipy.spatial import ConvexHull, QhullError

    from stratamap.core.geometry.boxes import clip_polygon, polygon_area

    try:
        hull = surface_xy[ConvexHull(surface_xy).vertices]
    except (QhullError, ValueError):
        return 0.0
    return polygon_area(clip_polygon(child_box.corners_2d(), hull))


def footprint_neighbours(lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """For each of a set of x-y rectangles (corners ``lo``, ``hi``), the sorted indices of those
    it overlaps (itself included), found with a k-d tree of their centres: near-linear in their
    number where the all-pairs test is quadratic."""
    if len(lo) == 0:
        return []
    from scipy.spatial import cKDTree

    centers, radii = (lo + hi) / 2, np.linalg.norm(hi - lo, axis=1) / 2
    tree = cKDTree(centers)
    out = []
    for i in range(len(lo)):
        near = np.asarray(sorted(tree.query_ball_point(centers[i], radii[i] + radii.max() + 1e-9)), np.int64)
        keep = np.all((lo[near] <= hi[i]) & (hi[near] >= lo[i]), axis=1)
        out.append(near[keep])
    return out


def _extent(box: Any, points: np.ndarray | None = None, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The x-y rectangle holding a box's footprint (and ``points``), grown by ``margin``."""
    xy = box.corners_2d() if points is None or not len(points) else np.vstack([box.corners_2d(), points[:, :2]])
    return xy.min(0) - margin, xy.max(0) + margin


def floor_standing(inst: Any, floor_z: float) -> bool:
    """Whether an object of its class reaching up to where this one does stands on the floor (its
    base unseen: a chair's legs hidden under a table), not hanging from a wall (a wall cabinet's top
    is far above any cabinet standing on the floor)."""
    heights = plausible_heights(inst.class_name)
    return heights is not None and heights[0] <= inst.box.top_z - floor_z <= heights[1]


def surface_planes(
    points: np.ndarray, distance: float, max_planes: int, min_share: float, seed: int = 0
) -> list[dict[str, Any]]:
    """Iterative RANSAC: the object's largest planes, each fitted after the previous inliers are removed."""
    from stratamap.core.geometry.points import ransac_plane

    rest = np.asarray(points, dtype=np.float64)
    planes: list[dict[str, Any]] = []
    need = max(int(min_share * len(rest)), 10)
    for k in range(max_planes):
        if len(rest) < need:
            break
        normal, d, inliers = ransac_plane(rest, distance, iterations=200, seed=seed + k)
        if len(inliers) < need:
            break
        if normal[2] < 0:
            normal, d = -normal, -d
        kind = "horizontal" if abs(normal[2]) >= 0.9 else "vertical" if abs(normal[2]) <= 0.1 else "slanted"
        planes.append({"plane": [*map(float, normal), float(d)], "inliers": int(len(inliers)), "kind": kind})
        rest = np.delete(rest, inliers, axis=0)
    return planes


class ContactGraphConfig(StageConfig):
    contact_tolerance: float = Field(
        default=0.04,
        gt=0.0,
        description="Max height difference between a child's bottom and its supporter's surface, metres (a_th).",
    )
    min_overlap: float = Field(
        default=0.5,
        gt=0.0,
        le=1.0,
        description="Min share of the child's footprint the supporter must cover (paper's b_th).",
    )
    feet_clearance: float = Field(
        default=0.015,
        ge=0.0,
        description=(
            "A supporting surface lies at least this far above the supporter's own bottom, metres (a table's feet do "
            "not carry the chair beside it)."
        ),
    )
    wall_distance: float = Field(
        default=0.1, ge=0.0, description="An unsupported object this close to wall points is wall-supported, metres."
    )
    hang_over_free_space: bool = Field(
        default=True,
        description=(
            "An unsupported object off the floor, of no class standing on the floor that high, whose underside the "
            "frames saw empty hangs (wall-supported: a wall shelf or cabinet seen from the front, its back on the wall "
            "unseen) rather than reaching down to the floor in its refined box; needs posed depth frames."
        ),
    )
    plane_distance: float = Field(
        default=0.015, gt=0.0, description="RANSAC inlier distance of the surface planes, metres."
    )
    max_planes: int = Field(default=4, ge=0, description="Surface planes kept per object (0: none).")
    min_plane_share: float = Field(
        default=0.1, gt=0.0, le=1.0, description="A surface plane holds at least this share of the object's points."
    )
    proximal_distance: float = Field(
        default=0.05, ge=0.0, description="Boxes closer than this (grown by it) are proximal, metres."
    )
    grow_unseen: bool = Field(
        default=True,
        description=(
            "Complete the refined box of an object seen from one side only (a chair pushed in under a table shows "
            "its backrest) front to back towards its class's usual depth (priors.ClassSize.usual_depth), on the side "
            "where the frames never saw the space beside it free and no other surface fills it; needs posed depth "
            "frames (an RGB-D stream)."
        ),
    )


class ContactGraphMapper(Mapper[ContactGraphConfig]):
    """Support relations (floor or the object below) and proximal relations between object boxes."""

    name = "contact_graph"
    Config = ContactGraphConfig
    requires = frozenset({"instances"})
    optional = frozenset({"semantics"})
    provides = frozenset({"contact_graph"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        insts = list(data.map.instances or [])
        graph = ContactGraph()
        g = graph.support
        floor_z = floor_height(data)
        g.add_node("floor", kind="layout", class_name="floor")
        g.add_edge("scene", "floor", relation="support")
        sem = data.map.semantics
        if sem is not None:
            present = set(np.unique(sem.class_ids).tolist())
            for layout in ("wall", "ceiling"):
                if layout in sem.vocabulary and sem.vocabulary.id(layout) in present:
                    g.add_node(layout, kind="layout", class_name=layout)
                    g.add_edge("scene", layout, relation="support")
        walls = None
        if (
            sem is not None
            and data.map.geometry is not None
            and "wall" in sem.vocabulary
            and len(sem) == len(data.map.geometry)
        ):
            wall_pts = data.map.geometry.points[sem.class_ids == sem.vocabulary.id("wall")]
            if len(wall_pts):
                from scipy.spatial import cKDTree

                walls = cKDTree(wall_pts)
        for inst in insts:
            planes = (
                surface_planes(inst.points, cfg.plane_distance, cfg.max_planes, cfg.min_plane_share, seed=inst.id)
                if cfg.max_planes
                else []
            )
            g.add_node(inst.id, kind="object", class_name=inst.class_name, box=inst.box.to_dict(), planes=planes)

        # Only objects whose footprints (or points) overlap in x-y can support one another or touch.
        support_extents = [_extent(inst.box, inst.points) for inst in insts]
        support_candidates = footprint_neighbours(
            np.array([e[0] for e in support_extents]).reshape(-1, 2),
            np.array([e[1] for e in support_extents]).reshape(-1, 2),
        )
        grown_by: dict[int, float] = {}
        can_grow = (
            cfg.grow_unseen
            and data.map.geometry is not None
            and sem is not None
            and len(sem.instance_ids) == len(data.map.geometry.points)
        )
        if can_grow:
            cloud = np.asarray(data.map.geometry.points, float)
            cloud_ids = np.asarray(sem.instance_ids)
        from stratamap.core.map.visibility import FreeSpace

        # The frames are read once, when an object first needs them (a map with nothing to judge reads none).
        frames_free = functools.cache(lambda: FreeSpace.from_stream(data.stream))

        def hangs(box: Any) -> bool:
            free = frames_free()
            return free is not None and seen_free_below(box, free)

        for child_index, child in enumerate(insts):
            bottom = float(np.percentile(child.points[:, 2], 1)) if len(child.points) else child.box.bottom_z
            # The floor is a candidate when the child's bottom is at floor height; an object is one
            # when it has a surface at that height (above its own feet) under enough of the child.
            floor_gap = abs(bottom - floor_z)
            best, best_gap, best_score, best_z = (
                None,
                floor_gap if floor_gap <= cfg.contact_tolerance else np.inf,
                0.0,
                0.0,
            )
            area = max(float(child.box.size[0] * child.box.size[1]), 1e-9)
            for parent in (insts[j] for j in support_candidates[child_index]):
                if parent.id == child.id or parent.box.bottom_z >= bottom - cfg.feet_clearance:
                    continue
                z = parent.points[:, 2]
                surface = parent.points[
                    (np.abs(z - bottom) <= cfg.contact_tolerance) & (z > parent.box.bottom_z + cfg.feet_clearance)
                ]
                ratio = support_ratio(child.box, surface[:, :2]) / area if len(surface) >= 10 else 0.0
                surface_z = float(np.percentile(surface[:, 2], 90)) if len(surface) else parent.box.top_z
                if ratio < cfg.min_overlap and abs(parent.box.top_z - bottom) <= cfg.contact_tolerance:
                    # Hidden supporting plane: the top of a parent whose surface the child hides.
                    ratio, surface_z = footprint_overlap(child.box, parent.box) / area, parent.box.top_z
                if ratio < cfg.min_overlap:
                    continue
                gap = abs(surface_z - bottom)
                # eq. 3: the best contact wins; a surface clearly nearer in height than the best so far wins too.
                if gap < best_gap - cfg.contact_tolerance / 2 or (
                    gap <= best_gap + cfg.contact_tolerance / 2 and ratio > best_score
                ):
                    best, best_gap, best_score, best_z = parent, gap, ratio, surface_z
            near_wall = (
                walls is not None
                and np.isfinite(
                    walls.query(
                        child.points[:: max(1, len(child.points) // 200)], distance_upper_bound=cfg.wall_distance
                    )[0]
                ).any()
            )
            if best is not None:
                g.add_edge(
                    best.id, child.id, relation="support", plane=[0.0, 0.0, 1.0, -best_z], contact_ratio=best_score
                )
                support_z = best_z
            elif (
                bottom - floor_z > cfg.contact_tolerance
                and not floor_standing(child, floor_z)
                and (near_wall or (cfg.hang_over_free_space and hangs(child.box)))
            ):
                g.add_edge("wall", child.id, relation="support")  # hangs on the wall (a wall cabinet, a picture)
                support_z = None
            else:
                g.add_edge("floor", child.id, relation="support", plane=[0.0, 0.0, 1.0, -float(floor_z)])
                support_z = float(floor_z)
            refined = None
            if support_z is not None and support_z < child.box.bottom_z:
                # Box refinement: the unseen bottom of an object reaches down to its support.
                refined = type(child.box)(
                    np.array([*child.box.center[:2], (support_z + child.box.top_z) / 2]),
                    child.box.yaw,
                    np.array([*child.box.size[:2], child.box.top_z - support_z]),
                )
            box = refined if refined is not None else child.box
            depth = usual_depth(child.class_name, box, floor_z, cfg.contact_tolerance)
            free = frames_free() if can_grow and depth is not None else None
            if free is not None and depth is not None:
                reach = depth + float(max(box.size[:2]))
                near = np.all(np.abs(cloud[:, :2] - box.center[:2]) <= reach, axis=1) & (cloud_ids != child.id)
                out = grow_into_unseen(box, depth, free, cloud[near])
                if out is not None:
                    refined = out[0]
                    grown_by[int(child.id)] = round(out[2], 3)
            if refined is not None:
                g.nodes[child.id]["box_refined"] = refined.to_dict()

        graph.proximal.add_nodes_from(g.nodes)
        proximal_extents = [_extent(inst.box, margin=cfg.proximal_distance) for inst in insts]
        proximal_candidates = footprint_neighbours(
            np.array([e[0] for e in proximal_extents]).reshape(-1, 2),
            np.array([e[1] for e in proximal_extents]).reshape(-1, 2),
        )
        for i, a in enumerate(insts):
            for b in (insts[j] for j in proximal_candidates[i] if j > i):
                za = min(a.box.top_z, b.box.top_z) - max(a.box.bottom_z, b.box.bottom_z)
                if za < -cfg.proximal_distance:
                    continue
                grown = type(a.box)(a.box.center, a.box.yaw, a.box.size + 2 * cfg.proximal_distance)
                if footprint_overlap(grown, b.box) > 0 and not (g.has_edge(a.id, b.id) or g.has_edge(b.id, a.id)):
                    graph.proximal.add_edge(a.id, b.id, relation="proximal")
        if grown_by:
            self.note("grown_into_unseen", grown_by)
        return {"contact_graph": graph}


@hookimpl
def stratamap_register_mappers():
    return [ContactGraphMapper]
