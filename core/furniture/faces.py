"""Furniture faces and their fronts: the kitchen paper's analysis of one vertical face, shared by
the stages that find faces (``plane_crf`` on laser scans, ``fronts`` on fused maps).

A face is cut into fronts at gaps (points recessed behind it along a line) and between groups of
fixtures (each front carries its own handle); each front gets the level-2 features of the paper
(height, width, floor distance, handles and knobs, where its nearest fixture sits, handle
orientation) for a CRF over neighbouring fronts (cupboard, drawer, appliance, panel), and doors a
hinge side opposite their handle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stratamap.core.furniture.crf import binned
from stratamap.core.lazy import lazy_module

if TYPE_CHECKING:
    from stratamap.core.furniture.fixtures import Fixture

spatial = lazy_module("scipy.spatial")

#: The kitchen paper's front labels (``virtual_scan.LEVEL2``) of fronts that open, and of those
#: that open on a hinge.
OPENS = ("cupboard", "drawer", "appliance")
HINGED = ("cupboard", "appliance")
#: Labels of hinged fronts that hinge on a side wherever their handle is (a cupboard's door, its
#: handle centred near the top or not); the other hinged fronts with a centred handle hinge at the
#: bottom or the top (an oven's or a dishwasher's door, a flap).
SIDE_HINGED = ("cupboard",)

#: The CRF weights both stages ship (trained on virtual scans of procedural kitchens by
#: ``scripts/train_plane_crf.py``): level 1 labels planes, level 2 labels fronts.
SHIPPED_CRF = Path(__file__).resolve().parent / "models" / "plane_crf.json"


def plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two in-plane unit axes: for vertical planes, horizontal then +z; otherwise any pair."""
    n = normal / np.linalg.norm(normal)
    up = np.array([0.0, 0.0, 1.0])
    if abs(n[2]) < 0.9:
        u = np.cross(up, n)
        u /= np.linalg.norm(u)
        return u, np.cross(n, u)
    u = np.cross(n, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def radius_components(points: np.ndarray, radius: float) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = spatial.cKDTree(points).query_pairs(radius, output_type="ndarray")
    n = len(points)
    graph = (
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else coo_matrix((n, n))
    )
    return connected_components(graph, directed=False)[1]


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


def face_coords(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
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


def fixture_groups(fixtures: list[Fixture], u_axis: np.ndarray) -> list[dict]:
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
    rect: tuple[float, float, float, float],
    groups: list[dict],
    recessed_uz: np.ndarray,
    uz: np.ndarray,
    depth: int = 0,
    coverage: float = 0.5,
) -> list[tuple[float, float, float, float]]:
    """Guillotine cuts of the face rectangle (u0, u1, z0, z1): at gap lines first, then between
    fixture groups (a vertical cut where the groups leave a free band across u, else a
    horizontal one just above the lower group, as a drawer's handle sits in its upper part).
    ``coverage``: the share of a gap line's length that recessed points must cover (a dense view of
    a face, where every cell is measured and noise recesses some anywhere, needs more than a
    laser's sparse one)."""
    u0, u1, z0, z1 = rect
    if depth > 12:
        return [rect]
    for axis, (lo, hi, olo, ohi) in ((0, (u0, u1, z0, z1)), (1, (z0, z1, u0, u1))):
        cuts = gap_cuts(uz, recessed_uz, axis, lo, hi, olo, ohi, coverage)
        if cuts:
            c = cuts[0]
            parts = [(u0, c, z0, z1), (c, u1, z0, z1)] if axis == 0 else [(u0, u1, z0, c), (u0, u1, c, z1)]
            return [
                x
                for part in parts
                for x in split_face(part, groups_inside(groups, part), recessed_uz, uz, depth + 1, coverage)
            ]
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
    return [
        x for part in parts for x in split_face(part, groups_inside(groups, part), recessed_uz, uz, depth + 1, coverage)
    ]


def groups_inside(groups: list[dict], rect: tuple[float, float, float, float]) -> list[dict]:
    u0, u1, z0, z1 = rect
    return [g for g in groups if u0 <= (g["u"][0] + g["u"][1]) / 2 <= u1 and z0 <= (g["z"][0] + g["z"][1]) / 2 <= z1]


def hinge_side(front: FrontCandidate) -> str:
    """Opposite the handle; without one, a flap (wider than tall) hinges at the top, a door on
    the side where its face ends (or left). A centred handle says nothing about the side: on a
    tall front labelled an appliance (an oven's, a dishwasher's door) or not labelled, it hinges
    at the bottom; on a tall front labelled a cupboard door, on a side, as one without a handle."""
    u_axis, _ = plane_axes(front.normal)
    cu, cz = (front.u_range[0] + front.u_range[1]) / 2, (front.z_range[0] + front.z_range[1]) / 2
    hw, hh = max(front.width / 2, 1e-3), max(front.height / 2, 1e-3)
    handles = [f for f in front.fixtures if f.kind == "handle"] or front.fixtures
    tall = front.height > 1.3 * front.width
    if handles:
        f = max(handles, key=lambda f: abs(float(f.center @ u_axis) - cu) / hw)
        du, dz = (float(f.center @ u_axis) - cu) / hw, (float(f.center[2]) - cz) / hh
        # Square and wide fronts need the handle well off the centre line.
        if abs(du) >= (0.1 if tall else 0.3):
            return "left" if du > 0 else "right"
        if not (tall and front.label in SIDE_HINGED):
            return "bottom" if dz > 0 else "top"
    elif front.width > 1.3 * front.height:
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
