"""The front face of a storage object in a fused map.

The face is a vertical side of the object's box that the sensors stood in front of: among the map's
points around the side, RANSAC finds the vertical plane whose inliers fill the most of a face
(within FACE_TILT_DEG of the side: a fitted box is a few degrees off the furniture where other
points joined it), and the side is kept where that plane's points cover enough of it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.furniture.faces import face_coords, plane_axes
from stratamap.core.furniture.fixtures import Fixture
from stratamap.core.map.layers import OrientedBox
from stratamap.core.simulation.structure import StaticBox

#: How far (m) out of and behind a box side the face may lie (handles and a worktop's overhang push
#: a fitted box's side out of the face they stand on; a box a few degrees off the face puts its
#: ends decimetres in front of or behind the side).
FACE_SEARCH = (-0.4, 0.15)
#: Cell (m) in which the face's coverage is counted.
COVERAGE_CELL = 0.04
#: Sensors this far (m) in front of a side, or farther, saw it.
SEEN_FROM = 0.3
#: A side's opposite side stands against a wall when one of the room's wall planes, parallel to it
#: (within BACKED_TILT_DEG), lies at most BACKED_BY (m) behind it (or BACKED_INSIDE inside: a fitted
#: box reaches into a wall's noise) along BACKED_SHARE of its width. Storage furniture stands with its
#: back to a wall and opens to the room; a fridge's or an oven's exposed side, however well seen and
#: whatever noise stands out of it, does not. Planes, not points: an object hides the wall right
#: behind it from every view, and the plane runs on behind it from what was seen either side.
BACKED_BY = 0.3
BACKED_INSIDE = 0.1
BACKED_TILT_DEG = 15.0
BACKED_SHARE = 0.5


@dataclass
class Face:
    """A vertical face of an object: plane ``x . normal + d = 0`` (normal out of the object)."""

    normal: np.ndarray
    d: float
    rect: tuple[float, float, float, float]  # (u0, u1, z0, z1) in face coordinates
    coverage: float  # share of the side's area the map covers
    offset: float  # the face's distance out of the box side (m; negative: behind it)
    side: int  # box axis (0: x, 1: y) the side is normal to
    sign: float  # +1 / -1: which end of that axis
    fixtures: list[Fixture] = field(default_factory=list)

    @property
    def u_axis(self) -> np.ndarray:
        return plane_axes(self.normal)[0]


def _side_frame(box: OrientedBox, axis: int, sign: float) -> tuple[np.ndarray, float, float]:
    """(outward normal, half extent along it, half extent along the side)."""
    rot = box.pose[:3, :3]
    normal = sign * rot[:, axis]
    half = np.asarray(box.size, float) / 2
    return normal, float(half[axis]), float(half[1 - axis])


def backed_by_wall(box: OrientedBox, face: Face, walls: Sequence[StaticBox]) -> bool:
    """Whether the side of ``box`` opposite ``face`` stands against one of ``walls`` (the room's wall
    slabs, :func:`stratamap.core.simulation.structure.room_structure`: local x along the wall,
    local -y out of the room)."""
    normal, half, half_along = _side_frame(box, face.side, face.sign)
    back = np.asarray(box.center, float) - normal * half
    for wall in walls:
        rot, centre = wall.pose[:3, :3], wall.pose[:3, 3]
        along, outward = rot[:, 0], -rot[:, 1]
        if float(-normal @ outward) < np.cos(np.radians(BACKED_TILT_DEG)):
            continue
        gap = float((centre - back) @ outward) - float(wall.size[1]) / 2
        if not -BACKED_INSIDE < gap < BACKED_BY:
            continue
        # How much of the side's width, seen along the wall, the wall runs behind.
        offset = float((back - centre) @ along)
        reach = half_along * abs(float(normal[1] * along[0] - normal[0] * along[1]))
        overlap = min(offset + reach, wall.size[0] / 2) - max(offset - reach, -wall.size[0] / 2)
        if overlap >= BACKED_SHARE * 2 * half_along:
            return True
    return False


#: A face's top row spans at least this share of its fullest row's width.
SPAN_SHARE = 0.5


def spanned_top(uz: np.ndarray, rect: tuple[float, float, float, float]) -> float:
    """The top of a face whose points (face coordinates ``uz``) lie in ``rect``: the top of the
    highest row of COVERAGE_CELL whose points span SPAN_SHARE of the width the fullest row spans.
    Fronts span their face; what stands at a worktop's front edge, in the face's plane, spans a
    part of it (on the real kitchen, picture stands took a counter run's face from 0.9 m up to
    1.14 m, and its worktop's lip into the face's middle)."""
    u0, u1, z0, z1 = rect
    rows = np.floor((uz[:, 1] - z0) / COVERAGE_CELL).astype(np.int64)
    cols = np.floor((uz[:, 0] - u0) / COVERAGE_CELL).astype(np.int64)
    inside = (rows >= 0) & (uz[:, 1] <= z1) & (cols >= 0) & (uz[:, 0] <= u1)
    if not inside.any():
        return z1
    cells = np.unique(np.stack([rows[inside], cols[inside]], axis=1), axis=0)
    span = np.bincount(cells[:, 0])
    spanned = np.flatnonzero(span >= SPAN_SHARE * span.max())
    return float(min(z1, z0 + (spanned.max() + 1) * COVERAGE_CELL))


def find_faces(
    box: OrientedBox, cloud: np.ndarray, viewpoints: np.ndarray, min_coverage: float, floor_z: float
) -> list[tuple[Face, np.ndarray]]:
    """The sides of the object in ``box`` that the sensors faced and the map's points ``cloud``
    (N, 3) cover enough, each as a face with the indices of its points in ``cloud``, the largest
    covered area first. Points within 3 cm of ``floor_z`` are the floor's; the plane is sought
    below the object's top 5 cm (a worktop's points fill a line across it); the face ends at its
    highest row that spans half its width (:func:`spanned_top`)."""
    if len(cloud) == 0:
        return []
    center = np.asarray(box.center, float)
    rot = box.pose[:3, :3]
    local = (cloud - center) @ rot
    z0, z1 = max(box.bottom_z, floor_z + 0.03), box.bottom_z + float(box.size[2])
    in_height = (cloud[:, 2] >= z0) & (cloud[:, 2] <= z1)
    below_top = cloud[:, 2] <= z1 - 0.05
    rng = np.random.default_rng(0)
    found: list[tuple[float, Face, np.ndarray]] = []
    for axis in (0, 1):
        for sign in (1.0, -1.0):
            normal, half, half_along = _side_frame(box, axis, sign)
            face_center = center + normal * half
            face_center[2] = (z0 + z1) / 2
            if not np.any((viewpoints - face_center) @ normal > SEEN_FROM):
                continue
            out = sign * local[:, axis] - half
            along = local[:, 1 - axis]
            band = np.flatnonzero(
                in_height
                & below_top
                & (np.abs(along) <= half_along + 0.1)
                & (out > FACE_SEARCH[0])
                & (out < FACE_SEARCH[1])
            )
            if len(band) < 50:
                continue
            plane = _face_plane(cloud[band], normal, rng)
            if plane is None:
                continue
            plane_normal, d = plane
            u_axis = plane_axes(plane_normal)[0]
            h = cloud @ plane_normal + d
            on_face = in_height & (np.abs(h) < ON_FACE)
            # The face spans the side's width, measured along the face.
            side_u = float(face_center @ u_axis)
            fu = cloud @ u_axis
            on_face &= np.abs(fu - side_u) <= half_along + 0.05
            if on_face.sum() < 50:
                continue
            cells = np.unique(
                np.stack(
                    [
                        np.floor((fu[on_face] - side_u) / COVERAGE_CELL),
                        np.floor((cloud[on_face, 2] - z0) / COVERAGE_CELL),
                    ],
                    axis=1,
                ),
                axis=0,
            )
            # Over the face's own height: what stands on a unit's top is not its face.
            top = float(np.percentile(cloud[on_face, 2], 99))
            n_cells = max(1, int(np.ceil(2 * half_along / COVERAGE_CELL)) * int(np.ceil((top - z0) / COVERAGE_CELL)))
            coverage = min(1.0, len(cells) / n_cells)
            area = len(cells) * COVERAGE_CELL**2
            if coverage < min_coverage:
                continue
            # How far the face lies out of the box side, at the side's centre.
            offset = float(-(face_center @ plane_normal + d))
            face = Face(plane_normal, d, (0.0, 0.0, 0.0, 0.0), coverage, offset, axis, sign)
            idx = np.flatnonzero(on_face)
            uz = face_coords(cloud[idx], face.normal)
            lo, hi = np.percentile(uz, 0.5, axis=0), np.percentile(uz, 99.5, axis=0)
            top = spanned_top(uz, (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])))
            face.rect = (float(lo[0]), float(hi[0]), float(lo[1]), top)
            found.append((area, face, idx))
    found.sort(key=lambda item: -item[0])
    return [(face, idx) for _, face, idx in found]


#: A face's normal lies within this angle of its box side's (a box's yaw is off the furniture's by
#: up to this much where other points joined the object: a wall's end, a chair's back).
FACE_TILT_DEG = 20.0
#: Line hypotheses tried per side (top view).
FACE_TRIES = 300


def _face_plane(points: np.ndarray, side_normal: np.ndarray, rng) -> tuple[np.ndarray, float] | None:
    """The vertical plane of the most of a side's points (RANSAC on lines in the top view, scored by
    the 4 cm cells of face its inliers fill, so that a line across a worktop's points does not
    win), its normal within FACE_TILT_DEG of ``side_normal``, refitted to its inliers."""
    xy = points[:, :2]
    cos_tilt = np.cos(np.radians(FACE_TILT_DEG))
    best, best_score = None, 0
    pairs = rng.integers(0, len(xy), size=(FACE_TRIES, 2))
    for i, j in pairs:
        v = xy[j] - xy[i]
        length = float(np.hypot(*v))
        if length < 0.1:
            continue
        n2 = np.array([-v[1], v[0]]) / length
        if n2 @ side_normal[:2] < 0:
            n2 = -n2
        if n2 @ side_normal[:2] < cos_tilt:
            continue
        d = -float(n2 @ xy[i])
        inliers = np.abs(xy @ n2 + d) < ON_FACE
        if inliers.sum() <= best_score:
            continue
        u = xy[inliers] @ np.array([-n2[1], n2[0]])
        score = _cells_filled(u, points[inliers, 2], 0.04)
        if score > best_score:
            best, best_score = inliers, score
    if best is None or best.sum() < 10:
        return None
    return _fit_plane(points[best], side_normal)


def _cells_filled(u: np.ndarray, z: np.ndarray, cell: float) -> int:
    """How many ``cell``-sized squares of a face the points (``u`` along it, ``z`` up) fall in (one
    integer key per square: a 1-D unique, ten times faster than unique rows of floats)."""
    from stratamap.core.geometry.points import cell_keys

    return len(np.unique(cell_keys(np.stack([u, np.zeros_like(u), z], axis=1), cell)))


#: Points this far (m) from the fitted face plane lie on it.
ON_FACE = 0.012


def _fit_plane(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """The vertical plane through a face's points (a box's yaw is a few degrees off a face, which
    across a 2 m counter puts one end centimetres in front of the side): a line fitted to them from
    above, refitted to the points within 1 cm of it; its normal on ``normal``'s side."""
    xy = points[:, :2]
    for _ in range(2):
        mean = xy.mean(0)
        _, _, vt = np.linalg.svd(xy - mean, full_matrices=False)
        n2 = vt[1] if vt[1] @ normal[:2] > 0 else -vt[1]
        d = -float(mean @ n2)
        keep = np.abs(xy @ n2 + d) < 0.01
        if keep.sum() < 10:
            break
        xy = xy[keep]
    return np.array([n2[0], n2[1], 0.0]), d
