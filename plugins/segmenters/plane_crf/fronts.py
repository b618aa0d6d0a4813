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

from dataclasses import dataclass, field

import numpy as np

from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.lazy import lazy_module
from stratamap.core.simulation.virtual_scan import LEVEL1, LEVEL2
from stratamap.plugins.segmenters.plane_crf.crf import CRF, binned
from stratamap.plugins.segmenters.plane_crf.fixtures import Fixture, find_fixtures
from stratamap.plugins.segmenters.plane_crf.planes import boundary_points, multilod_planes, plane_axes, region_grow

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
class FrontCandidate:
    id: int
    region: int
    indices: np.ndarray  # into the downsampled cloud
    normal: np.ndarray
    d: float
    u_range: tuple[float, float]
    z_range: tuple[float, float]
    face_u_range: tuple[float, float]
    fixtures: list[Fixture] = field(default_factory=list)
    label: str = ""
    hinge: str | None = None

    @property
    def width(self) -> float:
        return self.u_range[1] - self.u_range[0]

    @property
    def height(self) -> float:
        return self.z_range[1] - self.z_range[0]

    def center(self) -> np.ndarray:
        """The front's centre on its (vertical) plane."""
        u, _ = plane_axes(self.normal)
        c = (self.u_range[0] + self.u_range[1]) / 2 * u - self.d * self.normal
        c[2] = (self.z_range[0] + self.z_range[1]) / 2
        return c


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


# --------------------------------------------------------------------------------------------
# 3-4. Fixtures and fronts


def _face_coords(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    u, _ = plane_axes(normal)
    return np.stack([points @ u, points[:, 2]], 1)


def gap_cuts(
    uz: np.ndarray,
    recessed_uz: np.ndarray,
    axis: int,
    lo: float,
    hi: float,
    other_lo: float,
    other_hi: float,
    coverage: float = 0.5,
    bin_size: float = 0.01,
) -> list[float]:
    """Lines (constant coordinate ``axis``) along which recessed points run across most of the
    rectangle: the gaps between neighbouring fronts."""
    if len(recessed_uz) < 5 or hi - lo < 0.15:
        return []
    inside = (recessed_uz[:, axis] > lo + 0.05) & (recessed_uz[:, axis] < hi - 0.05)
    inside &= (recessed_uz[:, 1 - axis] >= other_lo) & (recessed_uz[:, 1 - axis] <= other_hi)
    pts = recessed_uz[inside]
    if len(pts) < 5:
        return []
    bins = np.floor((pts[:, axis] - lo) / bin_size).astype(int)
    along = np.floor((pts[:, 1 - axis] - other_lo) / 0.03).astype(int)
    n_along = max(1, int(np.ceil((other_hi - other_lo) / 0.03)))
    cover = np.zeros(int(np.ceil((hi - lo) / bin_size)) + 2)
    for b in np.unique(bins):
        cover[b] = len(np.unique(along[bins == b])) / n_along
    # a gap may straddle two bins
    pair = np.maximum(cover, np.r_[cover[1:], 0.0])
    cuts = []
    for b in np.argsort(-pair):
        if pair[b] < coverage:
            break
        c = lo + (b + 1.0) * bin_size
        if all(abs(c - x) > 0.08 for x in cuts):
            cuts.append(float(c))
    return sorted(cuts)


def _fixture_groups(fixtures: list[Fixture], u_axis: np.ndarray) -> list[dict]:
    """Fixture extents in face coordinates; knobs in a row just above a handle join its group."""
    items = []
    for f in fixtures:
        cu, cz = float(f.center @ u_axis), float(f.center[2])
        if f.kind == "handle" and f.direction is not None:
            du, dz = abs(float(f.direction @ u_axis)) * f.length / 2, abs(float(f.direction[2])) * f.length / 2
        else:
            du = dz = max(f.radius, 0.01)
        items.append({"u": (cu - du, cu + du), "z": (cz - dz, cz + dz), "fixtures": [f]})
    merged = True
    while merged:
        merged = False
        for i in range(len(items)):
            for j in range(i + 1, len(items)):
                a, b = items[i], items[j]
                knobs = any(f.kind == "knob" for f in a["fixtures"] + b["fixtures"])
                overlap_u = min(a["u"][1], b["u"][1]) - max(a["u"][0], b["u"][0]) > -0.05
                close_z = max(a["z"][0], b["z"][0]) - min(a["z"][1], b["z"][1]) < (0.15 if knobs else -1.0)
                if overlap_u and close_z:
                    items[i] = {
                        "u": (min(a["u"][0], b["u"][0]), max(a["u"][1], b["u"][1])),
                        "z": (min(a["z"][0], b["z"][0]), max(a["z"][1], b["z"][1])),
                        "fixtures": a["fixtures"] + b["fixtures"],
                    }
                    items.pop(j)
                    merged = True
                    break
            if merged:
                break
    return items


#: Fixture groups side by side closer than this (metres) may belong to one front (a door's handle
#: sits a few centimetres beside the drawer handles below it): no vertical cut between them.
MIN_BAND = 0.08


def split_face(
    rect: tuple[float, float, float, float], groups: list[dict], recessed_uz: np.ndarray, uz: np.ndarray, depth: int = 0
) -> list[tuple[float, float, float, float]]:
    """Guillotine cuts of the face rectangle (u0, u1, z0, z1): at gap lines first, then between
    fixture groups (a vertical cut where the groups leave a free band across u, else a
    horizontal one just above the lower group, as a drawer's handle sits in its upper part)."""
    u0, u1, z0, z1 = rect
    if depth > 12:
        return [rect]
    for axis, (lo, hi, olo, ohi) in ((0, (u0, u1, z0, z1)), (1, (z0, z1, u0, u1))):
        cuts = gap_cuts(uz, recessed_uz, axis, lo, hi, olo, ohi)
        if cuts:
            c = cuts[0]
            parts = [(u0, c, z0, z1), (c, u1, z0, z1)] if axis == 0 else [(u0, u1, z0, c), (u0, u1, c, z1)]
            return [x for part in parts for x in split_face(part, _inside(groups, part), recessed_uz, uz, depth + 1)]
    if len(groups) < 2:
        return [rect]
    # vertical cut: a free band in u between groups
    spans = sorted((g["u"][0], g["u"][1]) for g in groups)
    reach, best = spans[0][1], None
    for a, b in spans[1:]:
        if a > reach + MIN_BAND and (best is None or a - reach > best[1] - best[0]):
            best = (reach, a)
        reach = max(reach, b)
    if best is not None:
        c = (best[0] + best[1]) / 2
        parts = [(u0, c, z0, z1), (c, u1, z0, z1)]
    else:
        zs = sorted((g["z"][0], g["z"][1]) for g in groups)
        reach, best = zs[0][1], None
        for a, b in zs[1:]:
            if a > reach + 0.02 and (best is None or a - reach > best[1] - best[0]):
                best = (reach, a)
            reach = max(reach, b)
        if best is None:
            return [rect]
        c = min(best[0] + 0.05, (best[0] + best[1]) / 2)
        parts = [(u0, u1, z0, c), (u0, u1, c, z1)]
    return [x for part in parts for x in split_face(part, _inside(groups, part), recessed_uz, uz, depth + 1)]


def _inside(groups: list[dict], rect: tuple[float, float, float, float]) -> list[dict]:
    u0, u1, z0, z1 = rect
    return [g for g in groups if u0 <= (g["u"][0] + g["u"][1]) / 2 <= u1 and z0 <= (g["z"][0] + g["z"][1]) / 2 <= z1]


def hinge_side(front: FrontCandidate) -> str:
    """Opposite the handle; without one, a flap (wider than tall) hinges at the top, a door on
    the side where its face ends (or left)."""
    u_axis, _ = plane_axes(front.normal)
    cu, cz = (front.u_range[0] + front.u_range[1]) / 2, (front.z_range[0] + front.z_range[1]) / 2
    hw, hh = max(front.width / 2, 1e-3), max(front.height / 2, 1e-3)
    handles = [f for f in front.fixtures if f.kind == "handle"] or front.fixtures
    if handles:
        f = max(handles, key=lambda f: abs(float(f.center @ u_axis) - cu) / hw)
        du, dz = (float(f.center @ u_axis) - cu) / hw, (float(f.center[2]) - cz) / hh
        # A tall door hinges on a side unless its handle is centred (an appliance's door, hinged
        # at the bottom); square and wide fronts need the handle well off the centre line.
        if abs(du) >= (0.1 if front.height > 1.3 * front.width else 0.3):
            return "left" if du > 0 else "right"
        return "bottom" if dz > 0 else "top"
    if front.width > 1.3 * front.height:
        return "top"
    at_left = front.u_range[0] - front.face_u_range[0] < 0.05
    at_right = front.face_u_range[1] - front.u_range[1] < 0.05
    if at_right and not at_left:
        return "right"
    return "left"


_F_H = np.array([0.0, 0.1, 0.2, 0.3, 0.5, 0.8, 1.2, 2.2])
_F_W = np.array([0.0, 0.2, 0.35, 0.5, 0.7, 1.0, 1.5, 3.0])
_F_FLOOR = np.array([-0.1, 0.05, 0.15, 0.4, 0.7, 1.0, 1.4, 2.0])
_F_REL = np.array([-1.2, -0.6, -0.3, 0.0, 0.3, 0.6, 1.2])
_F_ASPECT = np.array([-1.5, -0.75, 0.0, 0.75, 1.5])


def level2_features(fronts: list[FrontCandidate], floor_z: float) -> np.ndarray:
    rows = []
    for fr in fronts:
        u_axis, _ = plane_axes(fr.normal)
        handles = [f for f in fr.fixtures if f.kind == "handle"]
        knobs = [f for f in fr.fixtures if f.kind == "knob"]
        nh, nk = len(handles), len(knobs)
        cu, cz = (fr.u_range[0] + fr.u_range[1]) / 2, (fr.z_range[0] + fr.z_range[1]) / 2
        hw, hh = max(fr.width / 2, 1e-3), max(fr.height / 2, 1e-3)
        if fr.fixtures:
            f = min(fr.fixtures, key=lambda f: np.hypot(float(f.center @ u_axis) - cu, float(f.center[2]) - cz))
            du, dz = (float(f.center @ u_axis) - cu) / hw, (float(f.center[2]) - cz) / hh
            dist = float(np.hypot(float(f.center @ u_axis) - cu, float(f.center[2]) - cz))
            vert = float(f.kind == "handle" and f.direction is not None and abs(f.direction[2]) > 0.7)
            has = 1.0
        else:
            du = dz = dist = vert = has = 0.0
        row = np.concatenate(
            [
                [
                    1.0,
                    has,
                    vert,
                    float(nh == 0),
                    float(nh == 1),
                    float(nh >= 2),
                    float(nk == 0),
                    float(1 <= nk <= 2),
                    float(nk >= 3),
                ],
                binned([fr.height], _F_H)[0],
                binned([fr.width], _F_W)[0],
                binned([fr.z_range[0] - floor_z], _F_FLOOR)[0],
                has * binned([abs(du)], _F_REL)[0],
                has * binned([dz], _F_REL)[0],
                has * binned([dist], _F_H)[0],
                binned([np.log(max(fr.height, 0.01) / max(fr.width, 0.01))], _F_ASPECT)[0],
            ]
        )
        rows.append(row)
    return np.array(rows).reshape(len(fronts), -1) if rows else np.zeros((0, level2_feature_count()))


def level2_feature_count() -> int:
    return 9 + len(_F_H) + len(_F_W) + len(_F_FLOOR) + 2 * len(_F_REL) + len(_F_H) + len(_F_ASPECT)


L2_RELATIONS = ("side_by_side", "a_above_b", "a_below_b")


def front_graph(fronts: list[FrontCandidate], touch: float = 0.06) -> tuple[np.ndarray, np.ndarray]:
    edges, rels = [], []
    for a in range(len(fronts)):
        for b in range(a + 1, len(fronts)):
            fa, fb = fronts[a], fronts[b]
            if abs(fa.normal @ fb.normal) < 0.9:
                continue
            ua, ub = fa.u_range, fb.u_range
            za, zb = fa.z_range, fb.z_range
            ov_u = min(ua[1], ub[1]) - max(ua[0], ub[0])
            ov_z = min(za[1], zb[1]) - max(za[0], zb[0])
            if (
                ov_z > 0.05
                and -touch < ov_u < 0.05
                and abs(fa.d - fb.d * (1 if fa.normal @ fb.normal > 0 else -1)) < 0.2
            ):
                rel = 0
            elif ov_u > 0.05 and -touch < ov_z < 0.05 and fa.region == fb.region:
                rel = 1 if za[0] >= zb[1] - 0.05 else 2
            else:
                continue
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
        uz = _face_coords(pts, r.normal)
        # recessed points (gaps between fronts) from the full-resolution cloud behind the face
        reach = float(np.hypot(np.ptp(uz[:, 0]), np.ptp(uz[:, 1]))) / 2 + 0.05
        near = np.asarray(tree.query_ball_point(pts.mean(0), reach), dtype=np.int64)
        behind = cloud[near]
        depth = -(behind @ r.normal + r.d)
        recessed = behind[(depth > p.gap_depth[0]) & (depth < p.gap_depth[1])]
        ruz = _face_coords(recessed, r.normal) if len(recessed) else np.zeros((0, 2))
        rect = (float(uz[:, 0].min()), float(uz[:, 0].max()), float(uz[:, 1].min()), float(uz[:, 1].max()))
        groups = _fixture_groups(fixtures, u_axis)
        for part in split_face(rect, groups, ruz, uz):
            inside = (uz[:, 0] >= part[0]) & (uz[:, 0] <= part[1]) & (uz[:, 1] >= part[2]) & (uz[:, 1] <= part[3])
            if inside.sum() < 20:
                continue
            idx = r.indices[inside]
            fu, fz = uz[inside, 0], uz[inside, 1]
            mine = [g for g in _inside(groups, part) for g in g["fixtures"]]
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
    counts = np.zeros((n_cells, int(labels.max()) + 1), np.int64)
    np.add.at(counts, (cell_of_point[ok], labels[ok]), 1)
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
