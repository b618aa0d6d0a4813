"""The fronts of a storage object's face: fixtures, cuts, labels and hinge sides.

Handles and knobs are the blobs of a face's height map (:mod:`.relief`) standing out of its local
level by three times its noise (flush handles: elongated blobs of contrast in the colour images);
the kitchen paper's front analysis then runs unchanged (:mod:`stratamap.core.furniture.faces`):
the face is cut at gaps (recessed or shadowed lines) and between groups of fixtures, each front
gets the paper's level-2 features and the CRF labels it, and a door hinges opposite its handle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stratamap.core.furniture.crf import CRF
from stratamap.core.furniture.faces import (
    HINGED,
    FrontCandidate,
    fixture_groups,
    front_graph,
    groups_inside,
    hinge_side,
    level2_features,
    split_face,
)
from stratamap.core.furniture.fixtures import Fixture
from stratamap.core.map.layers import OrientedBox
from stratamap.core.map.priors import FRONT_MAX_WIDTH
from stratamap.core.simulation.structure import StaticBox
from stratamap.core.simulation.virtual_scan import LEVEL2
from stratamap.plugins.completers.fronts.face import ON_FACE, Face, backed_by_wall, find_faces
from stratamap.plugins.completers.fronts.relief import (
    CELL_MIN,
    FACE_CELL,
    HeightMap,
    frame_points,
    height_map,
    lines_only,
    point_spacing,
)


@dataclass
class Front:
    """One front of a face, in face coordinates, with what the CRF made of it."""

    rect: tuple[float, float, float, float]
    label: str  # cupboard | drawer | appliance | panel
    hinge: str | None
    fixtures: list[Fixture]


#: Fixtures and gaps stand this many times the face's noise out of it (or the configured standoff
#: and gap depth, when higher).
NOISE_MARGIN = 3.0
#: Least luminance contrast (0-1) of a handle or a gap in the colour images.
CONTRAST_MIN = 0.06
#: Longest handle seen in colour only (m): a longer dark or light line is an edge between fronts.
MAX_SHADE_HANDLE = 0.45
#: Share of a front's rectangle on the face's plane.
MIN_FLAT = 0.6
#: The lowest a handle or a knob sits over the floor (m).
LOWEST_FIXTURE = 0.08
#: Share of a gap line's length the recessed (or shadowed) cells of a height map cover. A 3 mm gap
#: shows in 1 cm cells only in parts; at 0.8 the fronts leaned on false fixtures to be cut apart.
GAP_COVERAGE = 0.5
#: Fewest cells of a fixture.
MIN_FIXTURE_CELLS = 4


def blobs(labels: np.ndarray, count: int, hm: HeightMap):
    """Each labelled blob of at least MIN_FIXTURE_CELLS cells that does not touch the face's outline
    (what does is its edge or what stands beside it): (mask, centre (u, z), principal axis (u, z),
    length along it, width across it)."""
    for k in range(1, count + 1):
        blob = labels == k
        if blob.sum() < MIN_FIXTURE_CELLS or blob[[0, -1], :].any() or blob[:, [0, -1]].any():
            continue
        uz = hm.centres(blob)
        mean = uz.mean(0)
        _, _, vt = np.linalg.svd(uz - mean, full_matrices=False)
        along = (uz - mean) @ vt[0]
        across = (uz - mean) @ np.array([-vt[0][1], vt[0][0]])
        yield blob, mean, vt[0], float(np.ptp(along)) + hm.cell, float(np.ptp(across)) + hm.cell


def fixtures_of(hm: HeightMap, face: Face, standoff: tuple[float, float], max_handle: float = 0.6) -> list[Fixture]:
    """Handles and knobs: connected blobs of cells standing ``standoff`` above the face's local
    level; a blob at least 6 cm long and 2.5 times as long as wide is a handle (its axis the blob's
    principal axis), a compact one up to 7 cm a knob."""
    from scipy import ndimage

    # Hysteresis: a blob is the cells above half the threshold connected to one above it (a thin
    # bar's middle stands out less than its posts).
    threshold = max(standoff[0], NOISE_MARGIN * hm.noise)
    relief = np.nan_to_num(hm.relief, nan=0.0)
    below_max = np.nan_to_num(hm.heights, nan=0.0) < standoff[1]
    low = lines_only((relief > threshold / 2) & below_max, 3)
    labels, count = ndimage.label(low, structure=np.ones((3, 3)))
    strong = np.unique(labels[(relief > threshold) & low])
    labels[~np.isin(labels, strong[strong > 0])] = 0
    out: list[Fixture] = []
    for blob, mean, axis2, length, width in blobs(labels, count, hm):
        height = float(np.nanmedian(hm.heights[blob]))
        center = mean[0] * face.u_axis - (face.d - height) * face.normal
        center[2] = mean[1]
        if length > max_handle:
            continue
        if length >= 0.06 and length >= 2.5 * width:
            direction = axis2[0] * face.u_axis + np.array([0.0, 0.0, axis2[1]])
            out.append(Fixture("handle", center, direction / np.linalg.norm(direction), length, 0.0, int(blob.sum())))
        elif length <= 0.07:
            out.append(Fixture("knob", center, None, 0.0, max(length, width) / 2, int(blob.sum())))
    return out


def off_edges(
    hm: HeightMap, face: Face, fixtures: list[Fixture], standoff: tuple[float, float], longest_handle: float = 0.6
) -> list[Fixture]:
    """``fixtures`` less those lying along a proud edge of the face: a line of cells standing out
    of it as far as a fixture's cells do (:func:`fixtures_of`'s lower, hysteresis level) along
    GAP_COVERAGE of the face's width or height, and longer than ``longest_handle``: a worktop's
    lip over a run of doors, a rail along a plinth. In pieces such a line is a row of "handles"
    that keeps the fronts under it from being cut apart (the real kitchen's back counter run)."""
    if not fixtures:
        return fixtures
    level = max(standoff[0], NOISE_MARGIN * hm.noise) / 2
    proud = lines_only(np.nan_to_num(hm.relief, nan=0.0) > level, 5)
    edges = []
    for axis in (0, 1):  # 0: rows, horizontal edges at a height; 1: columns, vertical ones at a u
        cells = proud.sum(axis=1 - axis)
        lines = np.flatnonzero((cells >= GAP_COVERAGE * proud.shape[1 - axis]) & (cells * hm.cell > longest_handle))
        edges.append((hm.z0 if axis == 0 else hm.u0) + (lines + 0.5) * hm.cell)
    kept = []
    for f in fixtures:
        vertical = f.kind == "handle" and f.direction is not None and abs(float(f.direction[2])) >= 0.5
        lines, at = (edges[1], float(f.center @ face.u_axis)) if vertical else (edges[0], float(f.center[2]))
        if len(lines) and np.min(np.abs(lines - at)) <= 2 * hm.cell:
            continue
        kept.append(f)
    return kept


def contrast_handles(
    hm: HeightMap, face: Face, known: list[Fixture], max_handle: float = MAX_SHADE_HANDLE
) -> list[Fixture]:
    """Handles the colour images show and the depth does not (flush bars and channel handles, dark
    on a light front or light on a dark one): elongated blobs of cells whose luminance differs from
    their surroundings' by three times the face's spread (at least CONTRAST_MIN), at least 8 cm
    long and four times as long as wide, at most ``max_handle`` (a longer line is an edge between
    fronts), not touching the face's outline, and not where a fixture in ``known`` already is."""
    from scipy import ndimage

    if hm.contrast is None or not np.isfinite(hm.contrast).any():
        return []
    c = hm.contrast[np.isfinite(hm.contrast)]
    spread = float(1.4826 * np.median(np.abs(c - np.median(c))))
    threshold = max(CONTRAST_MIN, NOISE_MARGIN * spread)
    mask = lines_only(np.abs(np.nan_to_num(hm.contrast, nan=0.0)) > threshold, 3)
    labels, count = ndimage.label(mask, structure=np.ones((3, 3)))
    out: list[Fixture] = []
    for blob, mean, axis2, length, width in blobs(labels, count, hm):
        if not (0.08 <= length <= max_handle and length >= 4 * width):
            continue
        if _where_known(known, face, mean, length):
            continue
        center = mean[0] * face.u_axis - face.d * face.normal
        center[2] = mean[1]
        direction = axis2[0] * face.u_axis + np.array([0.0, 0.0, axis2[1]])
        out.append(Fixture("handle", center, direction / np.linalg.norm(direction), length, 0.0, int(blob.sum())))
    return out


def _where_known(known: list[Fixture], face: Face, mean: np.ndarray, length: float) -> bool:
    """Whether a blob centred at ``mean`` (face coordinates), ``length`` long, lies where one of
    the fixtures ``known`` already is."""
    return any(
        abs(float(f.center @ face.u_axis) - mean[0]) < length / 2 + 0.03 and abs(float(f.center[2]) - mean[1]) < 0.05
        for f in known
    )


#: A cell is on a thin line when at least this share of the frames' measurements of it were marked
#: light or dark by :func:`~.relief.thin_lines` (a steel bar on a red door shows in about one
#: frame in five on the real kitchen, light and shade coming and going with the viewpoint).
LINE_SHARE = 0.1
#: How far (m) beyond a bar's ends its line must be gone: a handle ends, an edge goes on.
LINE_END = 0.04
#: Bars of one row: centres at most this far apart (m) across the row, lengths within this ratio.
ROW_ALIGN = 0.03
ROW_LENGTHS = 1.5


def line_handles(
    hm: HeightMap, face: Face, known: list[Fixture], max_handle: float = MAX_SHADE_HANDLE
) -> list[Fixture]:
    """Handles that only the frames' thin light or dark lines show (a 1 cm steel bar that neither
    the depth nor the averaged colour resolves, colour not registered with the depth), trusted where
    a run of fronts repeats them: bars along a face axis, 8 cm to ``max_handle`` long and four
    times as long as wide, whose line stops within LINE_END beyond both ends (an edge between
    fronts, a worktop's lip, goes on), in rows of at least two alike (centres level within
    ROW_ALIGN, lengths within ROW_LENGTHS) with no line between them; not where a fixture in
    ``known`` already is."""
    from scipy import ndimage

    if hm.light_lines is None or hm.dark_lines is None:
        return []
    bars = []
    for share in (hm.light_lines, hm.dark_lines):
        lit = np.nan_to_num(share, nan=0.0)
        labels, count = ndimage.label(lines_only(lit >= LINE_SHARE, 3), structure=np.ones((3, 3)))
        for _blob, mean, axis2, length, width in blobs(labels, count, hm):
            along = int(np.argmax(np.abs(axis2)))  # 0: along u (a horizontal bar), 1: along z
            if abs(axis2[along]) < np.cos(np.radians(10)) or not (0.08 <= length <= max_handle and length >= 4 * width):
                continue
            if _line_goes_on(lit, hm, mean, along, length):
                continue
            bars.append((along, mean, length, lit))
    out: list[Fixture] = []
    for k, (along, mean, length, lit) in enumerate(bars):
        row = [
            b
            for j, b in enumerate(bars)
            if j != k
            and b[0] == along
            and abs(b[1][1 - along] - mean[1 - along]) <= ROW_ALIGN
            and max(b[2], length) <= ROW_LENGTHS * min(b[2], length)
            and abs(b[1][along] - mean[along]) >= (b[2] + length) / 2 + LINE_END
            and not _line_between(lit, hm, (mean, length), (b[1], b[2]), along)
        ]
        if not row:
            continue
        if _where_known(known, face, mean, length):
            continue
        center = mean[0] * face.u_axis - face.d * face.normal
        center[2] = mean[1]
        direction = face.u_axis if along == 0 else np.array([0.0, 0.0, 1.0])
        out.append(Fixture("handle", center, direction, length, 0.0, 0))
    return out


def _cells_along(hm: HeightMap, mean: np.ndarray, along: int, start: float, stop: float) -> tuple:
    """The height map's cells on the line through ``mean`` along face axis ``along`` (0: u, 1: z),
    from ``start`` to ``stop`` metres of it."""
    steps = np.arange(start, stop, hm.cell)
    uz = np.repeat(mean[None, :], len(steps), axis=0)
    uz[:, along] += steps
    j = np.floor((uz[:, 0] - hm.u0) / hm.cell).astype(int)
    i = np.floor((uz[:, 1] - hm.z0) / hm.cell).astype(int)
    ok = (i >= 0) & (i < hm.relief.shape[0]) & (j >= 0) & (j < hm.relief.shape[1])
    return i[ok], j[ok]


def _line_goes_on(lit: np.ndarray, hm: HeightMap, mean: np.ndarray, along: int, length: float) -> bool:
    """Whether the thin line of a bar centred at ``mean`` goes on beyond either of its ends (on its
    own row of cells or one beside it: a bar is a cell or two wide)."""
    for sign in (-1.0, 1.0):
        a, b = sorted((sign * (length / 2 + hm.cell), sign * (length / 2 + LINE_END)))
        i, j = _cells_along(hm, mean, along, a, b)
        if not len(i):
            continue
        rows = [np.clip(i + d * (along == 0), 0, lit.shape[0] - 1) for d in (-1, 0, 1)]
        cols = [np.clip(j + d * (along == 1), 0, lit.shape[1] - 1) for d in (-1, 0, 1)]
        if max(float(np.mean(lit[r, c] >= LINE_SHARE)) for r, c in zip(rows, cols, strict=True)) >= 0.5:
            return True
    return False


def _line_between(lit: np.ndarray, hm: HeightMap, a: tuple, b: tuple, along: int) -> bool:
    """Whether a thin line runs along half the way between the ends of two bars (``(centre,
    length)`` each) facing each other: they are pieces of one edge."""
    (first, first_length), (second, second_length) = sorted((a, b), key=lambda bar: float(bar[0][along]))
    start = float(first[along]) + first_length / 2 + hm.cell
    stop = float(second[along]) - second_length / 2 - hm.cell
    if stop <= start:
        return True
    origin = (first + second) / 2
    origin[along] = start
    i, j = _cells_along(hm, origin, along, 0.0, stop - start)
    return bool(len(i)) and float(np.mean(lit[i, j] >= LINE_SHARE)) >= 0.5


def candidate_fronts(
    face: Face,
    hm: HeightMap,
    floor_z: float,
    standoff: tuple[float, float],
    gap_depth: tuple[float, float],
    min_front: float,
    fixture_model: str | None = None,
) -> list[FrontCandidate]:
    """The fronts of ``face`` from its height map, unlabelled: fixtures (by the classifier of the
    sidecar ``fixture_model``, :mod:`.fixture_model`; None: by thresholds on the relief and the
    contrast), then cuts at gaps and between fixture groups."""
    if fixture_model is not None:
        from stratamap.plugins.completers.fronts.fixture_model import load_fixture_model

        fixtures = load_fixture_model(str(fixture_model)).fixtures(hm, face, standoff)
    else:
        fixtures = off_edges(hm, face, fixtures_of(hm, face, standoff), standoff)
        fixtures += contrast_handles(hm, face, fixtures)
        fixtures += line_handles(hm, face, fixtures)
    # Where a face meets the floor, the floor's points and the sensor's mixed pixels stand off it;
    # nothing is opened by a handle that low.
    face.fixtures = [f for f in fixtures if f.center[2] >= floor_z + LOWEST_FIXTURE]
    u0, u1, z0, z1 = face.rect
    z0 = max(z0, floor_z + 0.02)
    rect = (u0, u1, z0, z1)
    relief = hm.relief
    on_face = np.isfinite(relief) & (np.abs(np.nan_to_num(relief)) < max(ON_FACE, NOISE_MARGIN * hm.noise))
    uz = hm.centres(on_face)
    gap = max(gap_depth[0], NOISE_MARGIN * hm.noise)
    recessed = hm.centres(
        lines_only(np.isfinite(relief) & (np.nan_to_num(relief) < -gap) & (np.nan_to_num(relief) > -gap_depth[1]), 5)
    )
    if hm.contrast is not None and np.isfinite(hm.contrast).any():
        # The gaps between fronts are shadowed: dark lines in the colour images.
        c = hm.contrast[np.isfinite(hm.contrast)]
        dark = max(CONTRAST_MIN, NOISE_MARGIN * float(1.4826 * np.median(np.abs(c - np.median(c)))))
        shadowed = lines_only(np.nan_to_num(hm.contrast, nan=0.0) < -dark, 5)
        recessed = np.vstack([recessed, hm.centres(shadowed)])
    groups = fixture_groups(face.fixtures, face.u_axis)
    candidates: list[FrontCandidate] = []
    min_cells = max(20, int(0.25 * (min_front / hm.cell) ** 2))
    for part in split_face(rect, groups, recessed, uz, coverage=GAP_COVERAGE):
        inside = (uz[:, 0] >= part[0]) & (uz[:, 0] <= part[1]) & (uz[:, 1] >= part[2]) & (uz[:, 1] <= part[3])
        if inside.sum() < min_cells or part[1] - part[0] < min_front or part[3] - part[2] < min_front:
            continue
        # A front is a flat panel: most of its rectangle lies on the face (clutter on a worktop,
        # a shelf's contents or a wall behind them do not).
        area_cells = (part[1] - part[0]) * (part[3] - part[2]) / hm.cell**2
        if inside.sum() < MIN_FLAT * area_cells:
            continue
        mine = [f for g in groups_inside(groups, part) for f in g["fixtures"]]
        candidates.append(
            FrontCandidate(
                len(candidates),
                0,
                np.flatnonzero(inside),
                face.normal,
                face.d,
                (part[0], part[1]),
                (part[2], part[3]),
                (u0, u1),
                mine,
            )
        )
    return candidates


def label_fronts(candidates: list[FrontCandidate], floor_z: float, crf: CRF) -> list[Front]:
    """The CRF's label of every candidate (over the graph of neighbouring fronts; one wider than its
    kind opens, ``priors.FRONT_MAX_WIDTH``, is a panel) and the hinge side of every door."""
    if not candidates:
        return []
    X = level2_features(candidates, floor_z)
    E, rel = front_graph(candidates)
    fronts = []
    for cand, lab in zip(candidates, crf.predict(X, E, rel), strict=True):
        cand.label = LEVEL2[int(lab)]
        if cand.width > FRONT_MAX_WIDTH.get(cand.label, np.inf):
            cand.label = "panel"
        hinge = hinge_side(cand) if cand.label in HINGED else None
        fronts.append(Front((*cand.u_range, *cand.z_range), cand.label, hinge, cand.fixtures))
    return fronts


@dataclass(frozen=True)
class FaceParams:
    min_coverage: float = 0.35
    standoff: tuple[float, float] = (0.012, 0.07)
    gap_depth: tuple[float, float] = (0.008, 0.06)
    min_front: float = 0.06
    max_frames: int = 40
    max_range: float = 5.0
    #: The fixture classifier's sidecar (fixture_model.py); None: thresholds.
    fixture_model: str | None = None


#: How far (m) beyond an object's box its face's points are looked for.
OBJECT_REACH = 0.15


def observe_object(
    box: OrientedBox,
    cloud: np.ndarray,
    viewpoints: np.ndarray,
    stream,
    floor_z: float,
    p: FaceParams,
    walls: Sequence[StaticBox] = (),
) -> tuple[Face, HeightMap, list[FrontCandidate]] | None:
    """:func:`observe_front` on the map's points ``cloud`` around the object in ``box``: up to
    OBJECT_REACH beyond its sides (handles stand out of a face a fitted box may stop at)."""
    local = (cloud - box.center) @ box.pose[:3, :3]
    reach = np.asarray(box.size, float)[:2] / 2 + OBJECT_REACH
    near = (
        (np.abs(local[:, 0]) <= reach[0])
        & (np.abs(local[:, 1]) <= reach[1])
        & (cloud[:, 2] >= box.bottom_z - 0.02)
        & (cloud[:, 2] <= box.bottom_z + box.size[2] + 0.02)
    )
    return observe_front(box, cloud[near], viewpoints, stream, floor_z, p, walls)


def observe_front(
    box: OrientedBox,
    cloud: np.ndarray,
    viewpoints: np.ndarray,
    stream,
    floor_z: float,
    p: FaceParams,
    walls: Sequence[StaticBox] = (),
) -> tuple[Face, HeightMap, list[FrontCandidate]] | None:
    """The front face of the object in ``box`` (``cloud``: the map's points around it), its height
    map (from the depth frames of ``stream`` when it has posed ones that saw the face, else from
    ``cloud``) and its unlabelled fronts; None when no face was seen. The front face is the seen
    side whose opposite side stands against a wall (``walls``: the room's wall slabs), then the one
    with the most fixtures (handles and knobs are what a front is opened by), then the largest
    covered one."""
    best, best_key = None, None
    for face, idx in find_faces(box, cloud, viewpoints, p.min_coverage, floor_z):
        seen = frame_points(stream, face, p.max_frames, p.max_range) if p.max_frames and stream is not None else None
        if seen is not None and len(seen) >= 1000:
            hm = height_map(seen, face, FACE_CELL, CELL_MIN)
        else:
            # A fused map's points lie on a voxel grid: cells of 2.5 spacings are never empty between them.
            hm = height_map(cloud, face, 2.5 * point_spacing(cloud[idx]))
        candidates = candidate_fronts(face, hm, floor_z, p.standoff, p.gap_depth, p.min_front, p.fixture_model)
        key = (backed_by_wall(box, face, walls), len(face.fixtures))
        if best is None or key > best_key:
            best, best_key = (face, hm, candidates), key
    return best
