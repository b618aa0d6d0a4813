"""Semantic object maps of kitchens from a point cloud (the kitchen paper's pipeline).

1. Normals on a voxel-downsampled copy; multi-LoD MSAC planes; regions per plane (region
   growing with boundary points as stoppers); regions smaller than ``min_area`` are dropped.
2. Level 1: each horizontal or vertical region gets features (horizontal: height above the floor,
   distance to the ceiling, length and width along its principal axes, area; vertical: height,
   floor distance, ceiling distance, width) and a CRF over touching regions labels it floor,
   table (any horizontal work surface), ceiling, wall or furniture (face).
3. Fixtures: on every furniture face, points standing 1-7 cm off the face are clustered and fitted
   (handles: 3D lines, knobs: circles; RANSAC + Levenberg-Marquardt).
4. Fronts: a face is cut into fronts where the scan shows gaps between them (points recessed
   behind the face along a line) and between groups of fixtures (each front carries its own).
5. Level 2: each front gets features (height, width, floor distance, number of handles and knobs,
   where its nearest fixture sits relative to its centre, handle orientation) and a second CRF
   over neighbouring fronts labels it cupboard (door), drawer, appliance or panel.
6. Hinges: a door opens on the side opposite its handle (left/right when the handle sits off the
   vertical centre line, else top/bottom); a door without a handle is a flap hinged at the top
   when wider than tall, else hinged on the side where its face ends. (Thresholds chosen on
   procedural kitchens.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stratamap.core.furniture.crf import CRF, binned
from stratamap.core.furniture.faces import (
    FrontCandidate,
    face_coords,
    fixture_groups,
    front_graph,
    groups_inside,
    hinge_side,
    level2_features,
    plane_axes,
    split_face,
)
from stratamap.core.furniture.fixtures import find_fixtures
from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.lazy import lazy_module
from stratamap.core.simulation.virtual_scan import LEVEL1, LEVEL2
from stratamap.plugins.segmenters.plane_crf.planes import boundary_points, multilod_planes, region_grow

spatial = lazy_module("scipy.spatial")

HORIZONTAL_DEG = 20.0


@dataclass
class Region:
    id: int
    indices: np.ndarray  # into the downsampled cloud
    normal: np.ndarray  # facing the sensor (vertical regions) or +z
    d: float
    orientation: str  # horizontal | vertical (slanted regions are left out)
    center: np.ndarray
    zmin: float
    zmax: float
    length: float  # horizontal regions: principal extents; vertical: width along the face
    width: float
    area: float


@dataclass
class FurnitureParams:
    voxel_size: float = 0.015
    normal_radius: float = 0.05
    plane_threshold: float = 0.015
    min_area: float = 0.02
    region_radius: float = 0.04
    fixture_standoff: tuple[float, float] = (0.012, 0.07)
    gap_depth: tuple[float, float] = (0.008, 0.06)
    seed: int = 0


@dataclass
class FurnitureResult:
    points: np.ndarray  # downsampled cloud
    cell_of_point: np.ndarray  # input point -> downsampled point
    regions: list[Region]
    region_of: np.ndarray  # per downsampled point, -1 none
    level1: np.ndarray  # per region, index into LEVEL1 (-1 unlabelled)
    fronts: list[FrontCandidate]
    front_of: np.ndarray  # per downsampled point, -1 none
    floor_z: float
    ceiling_z: float


def point_labels(res: FurnitureResult) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per downsampled point: level-1 label, region id, level-2 label and front id (-1: none)."""
    level1 = np.full(len(res.points), -1, np.int64)
    region = np.full(len(res.points), -1, np.int64)
    for r in res.regions:
        level1[r.indices] = res.level1[r.id]
        region[r.indices] = r.id
    level2 = np.full(len(res.points), -1, np.int64)
    for f in res.fronts:
        if f.label:
            level2[f.indices] = LEVEL2.index(f.label)
    return level1, region, level2, res.front_of


# --------------------------------------------------------------------------------------------
# 1. Regions


def orient_to_viewpoints(points: np.ndarray, normals: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    _, nearest = spatial.cKDTree(viewpoints).query(points)
    flip = np.einsum("ij,ij->i", normals, viewpoints[nearest] - points) < 0
    normals = normals.copy()
    normals[flip] *= -1
    return normals


def extract_regions(
    points: np.ndarray, normals: np.ndarray, viewpoints: np.ndarray, p: FurnitureParams
) -> tuple[list[Region], np.ndarray]:
    planes = multilod_planes(points, normals, threshold=p.plane_threshold, adjacency=p.region_radius, seed=p.seed)
    regions: list[Region] = []
    region_of = np.full(len(points), -1, np.int64)
    cos_h = np.cos(np.radians(HORIZONTAL_DEG))
    min_pts = max(10, int(p.min_area / (p.voxel_size**2)))
    for plane in planes:
        idx = plane.indices
        pts = points[idx]
        boundary = boundary_points(pts, plane.normal, radius=2.5 * p.voxel_size)
        labels = region_grow(pts, boundary, p.region_radius)
        for r in np.unique(labels):
            ridx = idx[labels == r]
            if len(ridx) < min_pts:
                continue
            n = plane.normal.copy()
            nz = abs(n[2])
            orientation = (
                "horizontal" if nz >= cos_h else "vertical" if nz <= np.sin(np.radians(HORIZONTAL_DEG)) else "other"
            )
            if orientation == "other":  # slanted or edge-on strips: neither level-1 kind, left out
                continue
            c = points[ridx].mean(0)
            d = plane.d
            if orientation == "vertical":
                _, nearest = spatial.cKDTree(viewpoints).query(c)
                if n @ (viewpoints[nearest] - c) < 0:
                    n, d = -n, -d
            u, v = plane_axes(n)
            uv = np.stack([points[ridx] @ u, points[ridx] @ v], 1)
            if orientation == "vertical":
                length = width = float(np.ptp(uv[:, 0]))
            else:
                cov = np.cov((uv - uv.mean(0)).T)
                w, vec = np.linalg.eigh(cov)
                proj = (uv - uv.mean(0)) @ vec
                length, width = float(np.ptp(proj[:, 1])), float(np.ptp(proj[:, 0]))
            region_of[ridx] = len(regions)
            regions.append(
                Region(
                    len(regions),
                    ridx,
                    n,
                    float(d),
                    orientation,
                    c,
                    float(points[ridx, 2].min()),
                    float(points[ridx, 2].max()),
                    length,
                    width,
                    len(ridx) * p.voxel_size**2,
                )
            )
    return regions, region_of


def floor_and_ceiling(regions: list[Region], points: np.ndarray) -> tuple[float, float]:
    horiz = [r for r in regions if r.orientation == "horizontal"]
    if not horiz:
        return float(np.percentile(points[:, 2], 1)), float(np.percentile(points[:, 2], 99))
    big = sorted(horiz, key=lambda r: -r.area)[:6]
    return float(min(r.center[2] for r in big)), float(max(r.center[2] for r in big))


# --------------------------------------------------------------------------------------------
# 2. Level 1

_H_Z = np.array([-0.3, 0.2, 0.5, 0.7, 0.9, 1.1, 1.5, 2.0, 2.5, 3.2])
_H_CEIL = np.array([-0.2, 0.15, 0.5, 1.0, 1.5, 2.0, 3.0])
_LOG_AREA = np.array([-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0])
_LEN = np.array([0.0, 0.3, 0.6, 1.0, 2.0, 4.0, 8.0])
_V_H = np.array([0.0, 0.2, 0.5, 0.9, 1.4, 2.0, 2.6, 3.2])
_V_FLOOR = np.array([-0.1, 0.05, 0.15, 0.4, 0.8, 1.2, 1.8, 2.5])
_V_CEIL = np.array([-0.1, 0.05, 0.2, 0.5, 0.9, 1.4, 2.0, 2.6])


def level1_features(regions: list[Region], floor_z: float, ceiling_z: float) -> np.ndarray:
    rows = []
    for r in regions:
        h = float(r.orientation == "horizontal")
        v = float(r.orientation == "vertical")
        z = r.center[2]
        f = [
            [h, v, 1.0],
            h * binned([z - floor_z], _H_Z)[0],
            h * binned([ceiling_z - z], _H_CEIL)[0],
            h * binned([np.log10(max(r.area, 1e-3))], _LOG_AREA)[0],
            h * binned([r.length], _LEN)[0],
            h * binned([r.width], _LEN)[0],
            v * binned([r.zmax - r.zmin], _V_H)[0],
            v * binned([r.zmin - floor_z], _V_FLOOR)[0],
            v * binned([ceiling_z - r.zmax], _V_CEIL)[0],
            v * binned([r.length], _LEN)[0],
            v * binned([np.log10(max(r.area, 1e-3))], _LOG_AREA)[0],
        ]
        rows.append(np.concatenate([np.asarray(x, float).ravel() for x in f]))
    return np.array(rows).reshape(len(regions), -1) if rows else np.zeros((0, level1_feature_count()))


def level1_feature_count() -> int:
    return (
        3
        + len(_H_Z)
        + len(_H_CEIL)
        + len(_LOG_AREA)
        + 2 * len(_LEN)
        + len(_V_H)
        + len(_V_FLOOR)
        + len(_V_CEIL)
        + len(_LEN)
        + len(_LOG_AREA)
    )


#: Relations of an ordered pair of touching regions (a, b).
L1_RELATIONS = ("hh", "vv", "h_above_v", "h_below_v", "v_below_h", "v_above_h")


def region_graph(points: np.ndarray, regions: list[Region], adjacency: float = 0.06) -> tuple[np.ndarray, np.ndarray]:
    """Touching regions (closest points within ``adjacency``) and the relation of each pair."""
    trees = [spatial.cKDTree(points[r.indices[:: max(1, len(r.indices) // 400)]]) for r in regions]
    lo = np.array([points[r.indices].min(0) for r in regions]).reshape(-1, 3)
    hi = np.array([points[r.indices].max(0) for r in regions]).reshape(-1, 3)
    edges, rels = [], []
    for a in range(len(regions)):
        for b in range(a + 1, len(regions)):
            if np.any(lo[a] > hi[b] + adjacency) or np.any(lo[b] > hi[a] + adjacency):
                continue
            if trees[a].count_neighbors(trees[b], adjacency) == 0:
                continue
            ra, rb = regions[a], regions[b]
            if ra.orientation == rb.orientation:
                rel = 0 if ra.orientation == "horizontal" else 1
            elif ra.orientation == "horizontal":
                rel = 2 if ra.center[2] >= rb.zmax - 0.05 else 3
            else:
                rel = 4 if rb.center[2] >= ra.zmax - 0.05 else 5
            edges.append((a, b))
            rels.append(rel)
    return np.array(edges, np.int64).reshape(-1, 2), np.array(rels, np.int64)


def find_fronts(
    points: np.ndarray,
    regions: list[Region],
    furniture: list[int],
    cloud: np.ndarray,
    tree: spatial.cKDTree,
    p: FurnitureParams,
) -> list[FrontCandidate]:
    fronts: list[FrontCandidate] = []
    for rid in furniture:
        r = regions[rid]
        pts = points[r.indices]
        fixtures = find_fixtures(pts, r.normal, r.d, cloud, tree, standoff=p.fixture_standoff)
        u_axis, _ = plane_axes(r.normal)
        uz = face_coords(pts, r.normal)
        # recessed points (gaps between fronts) from the full-resolution cloud behind the face
        reach = float(np.hypot(np.ptp(uz[:, 0]), np.ptp(uz[:, 1]))) / 2 + 0.05
        near = np.asarray(tree.query_ball_point(pts.mean(0), reach), dtype=np.int64)
        behind = cloud[near]
        depth = -(behind @ r.normal + r.d)
        recessed = behind[(depth > p.gap_depth[0]) & (depth < p.gap_depth[1])]
        ruz = face_coords(recessed, r.normal) if len(recessed) else np.zeros((0, 2))
        rect = (float(uz[:, 0].min()), float(uz[:, 0].max()), float(uz[:, 1].min()), float(uz[:, 1].max()))
        groups = fixture_groups(fixtures, u_axis)
        for part in split_face(rect, groups, ruz, uz):
            inside = (uz[:, 0] >= part[0]) & (uz[:, 0] <= part[1]) & (uz[:, 1] >= part[2]) & (uz[:, 1] <= part[3])
            if inside.sum() < 20:
                continue
            idx = r.indices[inside]
            fu, fz = uz[inside, 0], uz[inside, 1]
            mine = [g for g in groups_inside(groups, part) for g in g["fixtures"]]
            fronts.append(
                FrontCandidate(
                    len(fronts),
                    rid,
                    idx,
                    r.normal,
                    r.d,
                    (float(fu.min()), float(fu.max())),
                    (float(fz.min()), float(fz.max())),
                    (rect[0], rect[1]),
                    mine,
                )
            )
    return fronts


# --------------------------------------------------------------------------------------------
# The whole pipeline


def find_regions(cloud: np.ndarray, viewpoints: np.ndarray, p: FurnitureParams | None = None) -> FurnitureResult:
    """Steps 1: the downsampled cloud, its regions and the floor and ceiling heights (unlabelled)."""
    import open3d as o3d

    p = p or FurnitureParams()
    viewpoints = np.asarray(viewpoints, float).reshape(-1, 3)
    points, cell_of_point = voxel_downsample(np.asarray(cloud, float), p.voxel_size)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=p.normal_radius, max_nn=30))
    normals = orient_to_viewpoints(points, np.asarray(pcd.normals), viewpoints)
    regions, region_of = extract_regions(points, normals, viewpoints, p)
    floor_z, ceiling_z = floor_and_ceiling(regions, points)
    return FurnitureResult(
        points,
        cell_of_point,
        regions,
        region_of,
        np.full(len(regions), -1, np.int64),
        [],
        np.full(len(points), -1, np.int64),
        floor_z,
        ceiling_z,
    )


def label_regions(
    res: FurnitureResult,
    cloud: np.ndarray,
    level1_crf: CRF | None,
    level2_crf: CRF | None,
    p: FurnitureParams | None = None,
    level1_override: np.ndarray | None = None,
) -> FurnitureResult:
    """Steps 2-6 on the regions of ``res`` (in place). Without CRFs (training) fronts are found
    but not labelled; ``level1_override`` gives level-1 labels per region (ground truth, when
    training the second CRF)."""
    p = p or FurnitureParams()
    regions, points = res.regions, res.points
    if level1_override is not None:
        res.level1 = np.asarray(level1_override, np.int64).copy()
    elif level1_crf is not None and regions:
        X = level1_features(regions, res.floor_z, res.ceiling_z)
        E, rel = region_graph(points, regions)
        res.level1 = level1_crf.predict(X, E, rel).astype(np.int64)
    furniture = [
        i
        for i in range(len(regions))
        if res.level1[i] == LEVEL1.index("furniture") and regions[i].orientation == "vertical"
    ]
    cloud = np.asarray(cloud, float)
    res.fronts = find_fronts(points, regions, furniture, cloud, spatial.cKDTree(cloud), p)
    res.front_of[:] = -1
    for f in res.fronts:
        res.front_of[f.indices] = f.id
    if level2_crf is not None and res.fronts:
        X2 = level2_features(res.fronts, res.floor_z)
        E2, rel2 = front_graph(res.fronts)
        for f, lab in zip(res.fronts, level2_crf.predict(X2, E2, rel2)):
            f.label = LEVEL2[int(lab)]
    for f in res.fronts:
        f.hinge = hinge_side(f) if f.label in ("cupboard", "appliance", "") else None
    return res


def analyse(
    cloud: np.ndarray,
    viewpoints: np.ndarray,
    level1_crf: CRF | None,
    level2_crf: CRF | None,
    p: FurnitureParams | None = None,
    level1_override: np.ndarray | None = None,
) -> FurnitureResult:
    """Steps 1-6 on ``cloud`` (N, 3) scanned from ``viewpoints``."""
    return label_regions(find_regions(cloud, viewpoints, p), cloud, level1_crf, level2_crf, p, level1_override)


def majority_labels(cell_of_point: np.ndarray, labels: np.ndarray, n_cells: int) -> np.ndarray:
    """Per downsampled point, the most frequent label (>= 0) of the input points it holds, else -1."""
    labels = np.asarray(labels, np.int64)
    ok = labels >= 0
    if not ok.any():
        return np.full(n_cells, -1, np.int64)
    n_labels = int(labels.max()) + 1
    flat = np.asarray(cell_of_point[ok], np.int64) * n_labels + labels[ok]
    counts = np.bincount(flat, minlength=n_cells * n_labels).reshape(n_cells, n_labels)
    out = counts.argmax(1)
    out[counts.sum(1) == 0] = -1
    return out


def mode_per_group(groups: list[np.ndarray], labels: np.ndarray) -> np.ndarray:
    """The most frequent label (>= 0) within each index group, else -1."""
    out = np.full(len(groups), -1, np.int64)
    for k, idx in enumerate(groups):
        lab = labels[idx]
        lab = lab[lab >= 0]
        if len(lab):
            out[k] = int(np.bincount(lab).argmax())
    return out
