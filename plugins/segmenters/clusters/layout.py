"""Gravity-aware room layout of a point set: floor, walls, ceiling, and the support surfaces on which
objects stand (the first pass of ``clusters``).

``find_layout(points, voxel_size)`` takes world points (z up, gravity-aligned, as every stratamap
map) and returns a :class:`Layout`: a label per point (``NONE``, ``FLOOR``, ``WALL``, ``CEILING``),
the planes they lie on, the floor and ceiling heights when there are any, and the support surfaces
(table, desk and counter tops, shelf boards, seats) as point index sets. Support surfaces are
*not* stuff: they belong to the object they top, which a segmenter builds around them.

How, and why this way: the points are gridded at ``voxel_size`` and each cell gets a normal. With
gravity known, planes need no RANSAC search over all orientations: horizontal cells (normal within
``horizontal_deg`` of z) are grown into connected regions of one height; vertical cells facing one
of the map's dominant horizontal directions (peaks of their azimuth histogram) are grown into
connected regions of one wall plane. Region growing is linear in the cells (one neighbour query),
deterministic (no random sampling, unlike Open3D's parallel ``segment_plane``), and keeps two
tables at the same height apart, which one infinite RANSAC plane does not; directions come first
because neighbour-to-neighbour normals would chain two walls through a room's rounded corner. The
regions are then named by gravity and extent:

* **floor**: the lowest horizontal level (regions within the inlier distance of one height) with
  almost nothing below it, when it is a room's floor rather than a tabletop: its area reaches
  ``floor_min_area`` or the map rises ``room_min_height`` above it. A tabletop scan has no floor.
* **ceiling**: the highest horizontal level at least ``ceiling_min_height`` above the floor with
  almost nothing above it (needs a floor).
* **wall**: a vertical plane spanning at least ``wall_min_height`` and ``wall_min_area`` with
  (almost) no points beyond it within its width and ``wall_margin`` past its ends: the map's
  boundary, seen from the sensor's side. A tall cabinet's front has the wall beside it beyond it,
  so it stays a thing.
* **support surfaces**: other horizontal regions of ``support_min_area`` to ``support_max_area``,
  ``support_heights`` above the floor when there is one (with no floor, any such region).

Without gravity (``gravity=False``) nothing is named: a plane's orientation says nothing about
floor or wall, so every label is ``NONE`` and there are no support surfaces.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.map.instances import members_of
from stratamap.core.map.vocabulary import LAYOUT_CLASSES
from stratamap.plugins.segmenters.clusters.grid import (
    AREA_CELL,
    cell_normals,
    components,
    footprint_area,
    neighbour_pairs,
)
from stratamap.plugins.segmenters.clusters.walls import through_openings, wall_directions

NONE, FLOOR, WALL, CEILING = 0, 1, 2, 3
#: Layout label -> class name (the vocabulary's layout classes); ``NONE`` is no layout.
LAYOUT_NAMES = ("none", *LAYOUT_CLASSES)


class LayoutParams(BaseModel):
    """Thresholds of :func:`find_layout`: distances in voxels of the working grid, sizes in metres."""

    model_config = ConfigDict(extra="forbid")

    plane_voxels: float = Field(
        default=1.5, gt=0.0, description="Inlier distance of a plane (height or wall offset), in voxels."
    )
    normal_voxels: float = Field(default=3.0, gt=0.0, description="Radius of the cell normal estimate, in voxels.")
    horizontal_deg: float = Field(
        default=15.0, gt=0.0, le=45.0, description="Cells whose normal is this close to vertical are horizontal."
    )
    vertical_deg: float = Field(
        default=15.0, gt=0.0, le=45.0, description="Cells whose normal is this close to horizontal are vertical."
    )
    floor_min_area: float = Field(
        default=3.0, gt=0.0, description="A lowest level this large (m^2) is a floor, whatever stands on it."
    )
    room_min_height: float = Field(
        default=1.5, gt=0.0, description="A lowest level the map rises this far above (m) is a floor."
    )
    level_min_area: float = Field(
        default=0.2, gt=0.0, description="Smallest horizontal level (m^2) that may be a floor or ceiling."
    )
    outlier_share: float = Field(
        default=0.02, ge=0.0, le=1.0, description="Share of cells beyond a floor, ceiling or wall tolerated (noise)."
    )
    ceiling_min_height: float = Field(
        default=1.8, gt=0.0, description="A ceiling lies at least this far above the floor (head height), metres."
    )
    wall_min_height: float = Field(
        default=0.4,
        gt=0.0,
        description=(
            "Smallest height span of a wall, metres (a backsplash between a worktop and the wall units above "
            "it is seen 0.4-0.6 m high; the boundary test, not the size, tells a wall from a cabinet front)."
        ),
    )
    wall_min_area: float = Field(default=0.2, gt=0.0, description="Smallest wall area, m^2.")
    direction_min_area: float = Field(
        default=0.4,
        gt=0.0,
        description=(
            "Walls stand only where at least this much vertical surface (m^2, in the whole map) faces one "
            "horizontal direction: a room's rounded corners face every way between its walls, a little each."
        ),
    )
    wall_margin: float = Field(
        default=0.5, ge=0.0, description="A wall has no points behind it within its width and this margin, metres."
    )
    seen_beyond_share: float = Field(
        default=0.25,
        ge=0.0,
        description=(
            "A wall candidate is no wall when the map holds more cells beyond it (within its width and "
            "wall_margin, not seen through a door or window, not on another wall) than this share of its own "
            "cells: a wall hides what lies behind it."
        ),
    )
    doorway_max_width: float = Field(
        default=2.0,
        gt=0.0,
        description=(
            "Widest doorway (m; double doors): a wall candidate's run of empty columns at most this wide is an "
            "opening the sensor may see through, a wider one a gap between two things in one plane."
        ),
    )
    support_heights: tuple[float, float] = Field(
        default=(0.3, 1.4), description="Heights above the floor of table, desk, counter and shelf tops, metres."
    )
    support_min_area: float = Field(default=0.04, gt=0.0, description="Smallest support surface, m^2.")
    support_max_area: float = Field(
        default=10.0, gt=0.0, description="Largest support surface, m^2 (larger at table height is a floor)."
    )


@dataclass
class SupportSurface:
    """A horizontal surface objects stand on: the indices of its points and its height (metres)."""

    indices: np.ndarray
    height: float
    area: float


@dataclass
class LayoutPlane:
    """A floor, wall or ceiling plane ``normal . x = offset``; a wall's ``span`` bounds it along
    its horizontal tangent ``(-n_y, n_x, 0)``."""

    label: int
    normal: np.ndarray
    offset: float
    span: tuple[float, float] = (-np.inf, np.inf)

    def near(self, points: np.ndarray, distance: float) -> np.ndarray:
        """Which points lie within ``distance`` of the plane (and within its span)."""
        close = np.abs(points @ self.normal - self.offset) <= distance
        along = points @ np.array([-self.normal[1], self.normal[0], 0.0])
        return close & (along >= self.span[0] - distance) & (along <= self.span[1] + distance)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Each point's distance to the plane's part that is there: within its span, to the plane; past
        either end, to that end's edge (a partition ending beside a cabinet is not behind it)."""
        across = np.abs(points @ self.normal - self.offset)
        along = points @ np.array([-self.normal[1], self.normal[0], 0.0])
        past = np.maximum(0.0, np.maximum(self.span[0] - along, along - self.span[1]))
        return np.hypot(across, past)


@dataclass
class Layout:
    """Per-point layout labels (``NONE``, ``FLOOR``, ``WALL``, ``CEILING``), the planes they lie on,
    and support surfaces."""

    labels: np.ndarray  # (N,) int8
    floor_height: float | None = None
    ceiling_height: float | None = None
    supports: list[SupportSurface] = field(default_factory=list)
    planes: list[LayoutPlane] = field(default_factory=list)

    @property
    def walls(self) -> int:
        return sum(plane.label == WALL for plane in self.planes)


def wall_yaws(layout: Layout) -> list[float]:
    """The yaws (radians, modulo 90 degrees) the layout's walls stand at: the directions furniture
    stands square to (more than one in a room whose walls are not all at right angles)."""
    return [float(np.arctan2(p.normal[1], p.normal[0])) % (np.pi / 2) for p in layout.planes if p.label == WALL]


def _regions(
    cells: np.ndarray, normals: np.ndarray, pairs: np.ndarray, member: np.ndarray, tol: float, max_turn_deg: float
) -> np.ndarray:
    """Connected regions of the ``member`` cells: neighbours with nearly parallel normals, each
    lying within ``tol`` of the other's tangent plane. -1 for cells outside ``member``."""
    i, j = pairs[:, 0], pairs[:, 1]
    keep = member[i] & member[j]
    i, j = i[keep], j[keep]
    parallel = np.abs(np.einsum("ij,ij->i", normals[i], normals[j])) >= np.cos(np.radians(max_turn_deg))
    diff = cells[i] - cells[j]
    coplanar = (np.abs(np.einsum("ij,ij->i", normals[i], diff)) <= tol) & (
        np.abs(np.einsum("ij,ij->i", normals[j], diff)) <= tol
    )
    ok = parallel & coplanar
    comp = components(len(cells), np.stack([i[ok], j[ok]], 1))
    out = np.full(len(cells), -1, np.int64)
    idx = np.flatnonzero(member)
    _, out[idx] = np.unique(comp[idx], return_inverse=True)
    return out


def _too_much_beyond(outside: np.ndarray, cell_label: np.ndarray, band_limit: float, own_limit: float) -> bool:
    """Whether the cells ``outside`` a wall candidate are too many for it to be the room's boundary:
    more than ``band_limit`` in all, or more than ``own_limit`` not on another wall."""
    return len(outside) > band_limit or int((cell_label[outside] != WALL).sum()) > own_limit


def find_layout(
    points: np.ndarray,
    voxel_size: float,
    normals: np.ndarray | None = None,
    gravity: bool = True,
    params: LayoutParams | None = None,
    viewpoints: np.ndarray | None = None,
    floor_hint: float | None = None,
) -> Layout:
    """Floor, walls, ceiling (per-point labels) and support surfaces of world points (z up).

    ``voxel_size`` is the working grid (a TSDF map's voxel, or a few times a raw cloud's point
    spacing); ``normals`` (per point, any orientation) skip the normal estimate; ``viewpoints``
    (sensor positions, (k, 3)) tell a wall's inside: without them it is the side with more of the
    map, which a partial map (a lone cabinet before a lone wall) can get wrong. ``floor_hint`` is the
    height where the source found the floor (its gravity alignment): a level there is tried first and
    may have more than ``outlier_share`` below it (one frame's floor bends down by centimetres at
    range), though it must still be a room's floor by area or rise. Partial maps are fine: a tabletop
    scan gives one support surface and no floor, a lone wall a wall."""
    p = params or LayoutParams()
    points = np.asarray(points, dtype=np.float64)
    labels = np.zeros(len(points), np.int8)
    if not gravity or len(points) < 10:
        return Layout(labels)
    cells, cell_of_point = voxel_downsample(points, voxel_size)
    if len(cells) < 10:
        return Layout(labels)
    if normals is not None:
        first = np.full(len(cells), -1, np.int64)
        first[cell_of_point[::-1]] = np.arange(len(points))[::-1]  # the first point of each cell
        normal = np.asarray(normals, float)[first]
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    else:
        normal = cell_normals(cells, p.normal_voxels * voxel_size)
    tol = p.plane_voxels * voxel_size
    views = None if viewpoints is None or len(viewpoints) == 0 else np.asarray(viewpoints, float).reshape(-1, 3)
    pairs = neighbour_pairs(cells, 1.8 * voxel_size)
    cell_label = np.zeros(len(cells), np.int8)
    nz = np.abs(normal[:, 2])
    z = cells[:, 2]
    area_of_cell = voxel_size * voxel_size

    # Horizontal regions, each with its height and footprint area.
    horizontal = nz >= np.cos(np.radians(p.horizontal_deg))
    h_region = _regions(cells, normal, pairs, horizontal, tol, p.horizontal_deg)
    n_h = int(h_region.max()) + 1 if (h_region >= 0).any() else 0
    h_members = members_of(h_region, n_h)
    h_height = np.array([np.median(z[m]) for m in h_members]) if n_h else np.zeros(0)
    h_area = np.array([footprint_area(cells[m, :2], voxel_size) for m in h_members]) if n_h else np.zeros(0)

    def level(height: float) -> np.ndarray:
        """Regions within the inlier distance of ``height``."""
        return np.flatnonzero(np.abs(h_height - height) <= tol)

    floor_height = ceiling_height = None
    planes: list[LayoutPlane] = []
    candidates = np.flatnonzero(h_area >= p.level_min_area)
    # The floor: the lowest level with almost nothing below it, when the map is a room on it.
    order = candidates[np.argsort(h_height[candidates], kind="stable")]
    hinted = np.zeros(len(order), bool)
    if floor_hint is not None:
        off = np.abs(h_height[order] - floor_hint)
        hinted = off <= 2 * tol
        # The level nearest the source's floor first.
        order = np.concatenate([order[hinted][np.argsort(off[hinted], kind="stable")], order[~hinted]])
        hinted = np.sort(hinted)[::-1]
    for k, at_hint in zip(order, hinted, strict=True):
        height = float(h_height[k])
        if (z < height - 2 * tol).mean() > p.outlier_share and not at_hint:
            continue
        rise = float(np.percentile(z, 99)) - height
        # The floor's size on a grid of at least AREA_CELL: a real scan's far floor is sparser than
        # the working voxel, and its gaps would hide how large it is.
        at_level = np.concatenate([h_members[i] for i in level(height)])
        floor_area = footprint_area(cells[at_level, :2], max(voxel_size, AREA_CELL))
        if floor_area >= p.floor_min_area or rise >= p.room_min_height:
            floor_height = height
        break
    if floor_height is not None:
        # Every horizontal-ish cell at floor height is floor (not the vertical side of what stands on it).
        near = (np.abs(z - floor_height) <= 0.5 * tol) & (nz >= 0.5)
        cell_label[near | np.isin(h_region, level(floor_height))] = FLOOR
        planes.append(LayoutPlane(FLOOR, np.array([0.0, 0.0, 1.0]), floor_height))
        for k in candidates[np.argsort(-h_height[candidates], kind="stable")]:
            height = float(h_height[k])
            if height - floor_height < p.ceiling_min_height:
                break
            if (z > height + 2 * tol).mean() <= p.outlier_share:
                ceiling_height = height
                at_ceiling = ((np.abs(z - height) <= 0.5 * tol) & (nz >= 0.5)) | np.isin(h_region, level(height))
                cell_label[at_ceiling] = CEILING
                planes.append(LayoutPlane(CEILING, np.array([0.0, 0.0, 1.0]), height))
            break

    # Walls: vertical cells facing one of the map's dominant horizontal directions, grown into
    # coplanar regions; the regions of one plane join (a wall broken by a cabinet in front of it).
    # Directions first, not neighbour-to-neighbour normals: the rounded normals of a room's corner
    # would otherwise chain two walls into one region.
    vertical = (nz <= np.sin(np.radians(p.vertical_deg))) & (cell_label == NONE)
    direction = wall_directions(normal, vertical, p.vertical_deg, max(3, int(p.direction_min_area / area_of_cell)))
    for n in direction:
        member = vertical & (np.abs(normal @ n) >= np.cos(np.radians(p.vertical_deg)))
        along_n = cells @ n
        i, j = pairs[:, 0], pairs[:, 1]
        keep = member[i] & member[j] & (np.abs(along_n[i] - along_n[j]) <= tol)
        comp = components(len(cells), pairs[keep])
        idx = np.flatnonzero(member)
        _, region = np.unique(comp[idx], return_inverse=True)
        members = members_of(region, int(region.max()) + 1 if len(region) else 0)
        offsets = np.array([np.median(along_n[idx[m]]) for m in members])
        sizes = np.array([len(m) for m in members])
        # Regions of one plane (offsets within the inlier distance, largest first) form one wall candidate.
        taken = np.zeros(len(members), bool)
        tangent = np.array([-n[1], n[0], 0.0])
        for k in np.argsort(-sizes, kind="stable"):
            if taken[k] or sizes[k] * area_of_cell < 0.05 * p.wall_min_area:
                continue
            same = ~taken & (np.abs(offsets - offsets[k]) <= tol)
            taken |= same
            m = idx[np.concatenate([members[q] for q in np.flatnonzero(same)])]
            d = float(np.median(along_n[m]))
            span = np.percentile(z[m], 98) - np.percentile(z[m], 2)
            if span < p.wall_min_height or len(m) * area_of_cell < p.wall_min_area:
                continue
            t = cells[m] @ tangent
            along = cells @ tangent
            band = (along >= t.min()) & (along <= t.max())
            offset = along_n - d
            # The boundary test looks past the region's ends too: the wall on either side of a tall
            # cabinet lies behind the cabinet's front, though the cabinet hides the wall behind itself.
            wide = (along >= t.min() - p.wall_margin) & (along <= t.max() + p.wall_margin)
            if views is not None:
                # The room is on the side the sensor saw the wall from; nothing may lie beyond it but
                # what a sensor saw through the wall's doors and windows.
                facing = 1.0 if np.median(views @ n - d) >= 0 else -1.0
            else:  # the room is on the side with more of the map
                facing = 1.0 if (wide & (offset > 2 * tol)).sum() >= (wide & (offset < -2 * tol)).sum() else -1.0
            outside = np.flatnonzero(wide & (offset * facing < -2 * tol))
            # Nothing beyond: at most outlier_share of the band (a cabinet front or a partition inside the
            # room has more) and, as a wall hides what lies behind it, fewer than seen_beyond_share of its
            # own cells (a tall cabinet's front and a counter's plinth in one plane, the worktop seen behind
            # them, are few cells of a wide band); another wall behind it is a real wall's drifted double
            # surface and does not count.
            limits = (p.outlier_share * wide.sum(), p.seen_beyond_share * len(m))
            if views is not None and _too_much_beyond(outside, cell_label, *limits):
                through = through_openings(
                    cells[outside], views, n, d, tangent, cells[m], 2.0 * voxel_size, p.doorway_max_width
                )
                outside = outside[~through]
            if _too_much_beyond(outside, cell_label, *limits):
                continue
            on_wall = band & (np.abs(offset) <= tol) & (np.abs(normal @ n) >= np.cos(np.radians(30.0)))
            # What lies behind the wall plane (within its width) is wall too: its thickness, noise.
            behind = band & (offset * facing < -tol)
            cell_label[(on_wall | behind) & (cell_label == NONE)] = WALL
            planes.append(LayoutPlane(WALL, n, d, (float(t.min()), float(t.max()))))

    # Support surfaces: other horizontal regions of a table's size (at a table's height over a floor).
    supports: list[SupportSurface] = []
    lo, hi = p.support_heights
    for k in range(n_h):
        m = h_members[k]
        if not (p.support_min_area <= h_area[k] <= p.support_max_area):
            continue
        if (cell_label[m] != NONE).mean() > 0.5:
            continue
        if floor_height is not None and not (lo <= h_height[k] - floor_height <= hi):
            continue
        supports.append(SupportSurface(m[cell_label[m] == NONE], float(h_height[k]), float(h_area[k])))
    labels = cell_label[cell_of_point]
    if supports:  # cells so far; callers get points
        support_of_cell = np.full(len(cells), -1, np.int64)
        for k, s in enumerate(supports):
            support_of_cell[s.indices] = k
        for s, members in zip(supports, members_of(support_of_cell[cell_of_point], len(supports)), strict=True):
            s.indices = np.sort(members)
    return Layout(labels, floor_height, ceiling_height, supports, planes)
