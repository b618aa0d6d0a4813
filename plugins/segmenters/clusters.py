"""Segmenter ``clusters``: model-free 3D instances from geometry first (point clouds and fused maps).

1. Scale. Every distance follows the map's resolution: the working grid is the map's voxel size
   (a TSDF map's ``geometry.voxel_size``), or ``spacing_factor`` times a raw cloud's median point
   spacing; the neighbour radius, normal radius, patch size and cut distance are multiples of it,
   and the smallest instance is an area. The same scene mapped at two voxel sizes gives the same
   instances, and a 2 cm room map gets 2 cm-scale parameters instead of a Kinect tabletop's.
2. Layout (``_layout.find_layout``, gravity-aligned planes): floor, walls and ceiling become stuff
   and leave the object search, so they are never a thing; so do an object's cells flush on a
   layout plane, and objects lying mostly near one (``layout_share``: what the plane fit left at
   corners and edges). Horizontal surfaces at table and counter heights are *support surfaces*:
   kept out of the clustering too, so what stands on them comes apart from them, and then given
   back to their object (below). Each takes up to three rings of neighbouring cells within half a
   voxel of its height and inside its footprint (``grow_supports``): the plane fit leaves out the
   top where normals bend at a cup's foot, and that ring would join the cup to the table's rim;
   cells it took under a segment standing there go back to it (``return_feet``).
3. Convexity-aware clustering of the rest (``method: convex``). Neighbouring cells (within
   ``radius_voxels``) stay connected when their surfaces are locally convex,
   ``(n_i - n_j) . (x_i - x_j) >= 0`` for normals facing the sensor, or nearly coplanar; the
   concave crease where a box stands on another, or leans on something, cuts the link (the
   point-level form of locally convex connected patches, LCCP, on supervoxel-like patches).
   ``method: euclidean`` links every pair within the radius instead.
4. Constrained planar cuts (after CPC, Schoeler et al. 2015): where a segment holds sharp concave
   creases between patches, the planes of the faces along them are tried as cuts through the
   whole segment; one is made when most patch edges it severs are concave (two boxes' flush sides).
5. Support surfaces get their object back: a segment touching a support surface *stands on it*
   when its foot is at the surface's height and it rises above it (a cup, a monitor, a box: its
   own instance); otherwise it is part of the support's object (a table's legs and edge, a cabinet
   under its counter top, a chair's back posts), joined through further touching segments that lie
   below the surface and under its convex hull (``below_share``).
6. Instances are the joined segments of at least ``min_area`` (and ``min_cells`` cells). Each
   takes its class from the fused per-point class votes already on the map (the ``semantics``
   layer a previous segmenter or the ``tsdf`` mapper left) when there are any: the majority class
   of its points; a majority of a stuff class makes it stuff. Without votes a support's object
   with a top of ``table_min_area`` is a ``table``, others follow ``class_rules`` or are ``object``.

Memory and time are near-linear in the points: a voxel grid, k-d tree neighbour pairs within a
few voxels, sparse connected components; no all-pairs step. Deterministic: no random sampling.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import voxel_downsample
from stratamap.core.map.instances import NAMING, members_of, set_naming
from stratamap.core.map.layers import Semantics
from stratamap.core.map.sensors import sensor_viewpoints
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters._layout import FLOOR, LAYOUT_NAMES, NONE, WALL, LayoutParams, find_layout
from stratamap.plugins.segmenters._recognition import (
    FLAT,
    FLOOR_GAP,
    HAND_HELD,
    KITCHEN_APPLIANCES,
    NO_RULE_FITS,
    ON_SUPPORTS,
    SEAT_HEIGHTS,
    STANDING_GAP,
    THIN,
    Shape,
    counter_run,
    describe_shape,
    fits_class,
    on_a_support,
    prior_class,
    split_at_step,
    typical_rather,
)
from stratamap.plugins.segmenters._sightlines import Sightlines

#: Pieces of one chair lie one over another at most this far apart (m): the part of a swivel chair's
#: post, or of its legs under the seat, that the map lost.
STACK_GAP = 0.12


#: A piece with this share of its points inside a larger floor-standing object's box is a part of it
#: (``_join_enclosed``), the box grown by this many voxels on every side (the map's noise at its faces).
ENCLOSED_SHARE = 0.8
ENCLOSED_MARGIN_VOXELS = 2.5
#: Seating: furniture stands within a table's, a desk's or a unit's box (a chair pushed under it or
#: close beside it), never within a seat's.
SEATING = ("chair", "sofa", "bench")

#: A chair's back, behind its seat, may reach this far (m) below the seat's top (a swivel chair's back
#: on the bar that holds it).
BACK_BELOW_SEAT = 0.2


class _Piece(NamedTuple):
    """An instance as a possible piece of a chair seen in stacked pieces."""

    points: np.ndarray  # indices of its points
    bottom: float  # m
    top: float  # m
    whole: bool  # on the floor and a whole object of its class by itself
    xy: np.ndarray  # its top view, thinned
    lo: np.ndarray  # the top view's corners
    hi: np.ndarray


class ClassRule(BaseModel):
    """Name a cluster by its size: the first rule that fits wins (used when the map has no class votes)."""

    model_config = ConfigDict(extra="forbid")

    class_name: str = Field(description="Class to give (must be a thing class of the vocabulary).")
    max_extent: float = Field(default=np.inf, gt=0, description="Largest box side, metres.")
    min_extent: float = Field(default=0.0, ge=0, description="Smallest largest-box-side, metres.")
    max_height: float = Field(default=np.inf, description="Highest top above the support, metres.")


class ClustersConfig(StageConfig):
    method: Literal["convex", "euclidean"] = Field(
        default="convex", description="convex: cut concave creases between touching objects; euclidean: distance only."
    )
    voxel_size: float | None = Field(
        default=None,
        gt=0.0,
        description=(
            "Working grid, metres. Default: the map's voxel size (geometry.voxel_size, set by tsdf), else "
            "spacing_factor times the cloud's median point spacing."
        ),
    )
    spacing_factor: float = Field(
        default=3.4,
        gt=0.0,
        description="Working grid of a raw cloud (no voxel size) in median point spacings (raw points are noisy).",
    )
    gravity: Literal["z", "none"] = Field(
        default="z",
        description="z: the map is gravity-aligned, z up (stratamap's world); none: no floor, wall or ceiling named.",
    )
    radius_voxels: float = Field(default=2.4, gt=0.0, description="Cells closer than this are neighbours, in voxels.")
    normal_radius_voxels: float = Field(default=4.0, gt=0.0, description="Radius of the normal estimate, in voxels.")
    smooth_deg: float = Field(
        default=12.0,
        ge=0.0,
        le=90.0,
        description="Neighbours whose normals differ by less than this stay linked even when slightly concave.",
    )
    patch_voxels: float = Field(
        default=4.0, gt=0.0, description="Cell size of the supervoxel patches the convexity test works on, in voxels."
    )
    patch_normal_deg: float = Field(
        default=20.0,
        gt=0.0,
        le=90.0,
        description="Neighbours in one cell whose normals differ by less than this form a patch.",
    )
    convex_votes: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Share of point links across a patch boundary that must be convex (or smooth) to merge.",
    )
    concavity_tolerance: float | None = Field(
        default=None,
        ge=0.0,
        description=(
            "Concavity tolerated (noise), as a fraction of the neighbour distance. Default: 0.2 for a raw cloud (set "
            "on mOSD/learn), 0.4 for a voxel map (set on held-out fused maps: normals over few coarse voxels bend)."
        ),
    )
    min_area: float = Field(
        default=0.0015, gt=0.0, description="Smallest instance, as surface area (cells times voxel area), m^2."
    )
    min_cells: int = Field(default=18, ge=1, description="Smallest instance in working-grid cells (noise).")
    below_share: float = Field(
        default=0.7,
        ge=0.0,
        le=1.0,
        description=(
            "A segment touching a support's object, wholly below the support, joins it when this share of its "
            "footprint lies in the support's convex hull (a table's legs; not a chair pushed beside it)."
        ),
    )
    layout_share: float = Field(
        default=0.6,
        gt=0.0,
        le=1.0,
        description=(
            "An object with this share of its cells near one floor, wall or ceiling plane is that stuff (what the "
            "plane fit left at corners and edges; a poster)."
        ),
    )
    layout_voxels: float = Field(
        default=3.0, gt=0.0, description="Near a floor, wall or ceiling plane: within this distance, in voxels."
    )
    table_min_area: float = Field(
        default=0.3,
        gt=0.0,
        description="Without class votes, a support's object with a top this large is a table, m^2.",
    )
    layout: LayoutParams = Field(
        default_factory=LayoutParams, description="Floor, wall, ceiling and support-surface detection."
    )
    cut_min_links: int = Field(
        default=5,
        ge=0,
        description="Concave patch edges (creases) a segment needs before planar cuts are tried (0: no cuts).",
    )
    cut_concavity_tolerance: float | None = Field(
        default=None,
        ge=0.0,
        description=(
            "Concavity that makes a patch edge a crease for the planar cuts, as concavity_tolerance (default: the "
            "same; stricter makes more cuts, also spurious ones through clean boxes)."
        ),
    )
    cut_concave_share: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Share of the patch edges a cut severs that must be concave for the cut to be made.",
    )
    cut_distance_voxels: float = Field(
        default=3.0,
        gt=0.0,
        description="Crease edges (patch centroid midpoints) this close to a candidate plane support it, in voxels.",
    )
    cut_crease_deg: float = Field(
        default=45.0,
        gt=0.0,
        le=90.0,
        description="Concave edges whose patch normals turn by more than this are creases that propose cut planes.",
    )
    cut_face_patches: int = Field(
        default=10, ge=1, description="Patches that must lie on a cut plane facing its way (the face the cut follows)."
    )
    cut_candidates: int = Field(
        default=20, ge=1, description="Best supported candidate planes tried per segment and cut."
    )
    cut_depth: int = Field(default=2, ge=0, description="Cuts applied in sequence at most per segment.")
    class_rules: list[ClassRule] = Field(
        default_factory=list, description="Size rules naming clusters when the map has no class votes."
    )
    trim_feet: bool = Field(
        default=True,
        description=(
            "Give a thing's points at its foot that lie outside its body's footprint, where the floor or a support "
            "surface goes on beyond them (the ring of table top a detector's mask takes at a cup's foot), back to "
            "that surface."
        ),
    )
    drop_strays: bool = Field(
        default=True,
        description=(
            "A thing's few cells apart from the rest of it and above everything else it holds (a wall corner's "
            "cells a metre above a sofa, left when the corner's flush cells went to the walls) are not the object: "
            "nothing holds them up. They leave the instance before it is named and measured."
        ),
    )
    keep_instances: bool = Field(
        default=False,
        description=(
            "Keep the instances already on the map (a tsdf mapper's, from a detector's masks) and add every "
            "geometric object they leave uncovered as an instance of its own; an instance's unmasked parts (a "
            "table's legs under its masked top) join it. False: the clusters alone are the instances."
        ),
    )
    covered_share: float = Field(
        default=0.5,
        gt=0.0,
        le=1.0,
        description=(
            "keep_instances: a geometric object with less than this share of its points in kept instances is a "
            "new instance (what no detector box covered); otherwise its unmasked points join the nearest instance."
        ),
    )
    recognize: bool = Field(
        default=False,
        description=(
            "Name objects with no thing votes, or with a voted class their size rules out (a 1.7 m box, a 12 cm "
            "table), by class size priors (core/map/priors.py) and support context: what stands on a support "
            "surface, whether it stands against a wall, has a flat top, a solid body or legs."
        ),
    )
    sightlines: bool = Field(
        default=True,
        description=(
            "recognize: with an RGB-D stream, a body its frames' depth rays saw through at its middle heights (the "
            "open space under a table's top, past a low shelf between its legs) is not a closed unit, however many "
            "points lie there. Reads up to 60 frames' depth again; scans and point clouds have no rays."
        ),
    )


def working_voxel(points: np.ndarray, map_voxel: float | None, cfg: ClustersConfig) -> float:
    """The grid everything scales with: the configured one, the map's, or a raw cloud's spacing
    (median nearest-neighbour distance over an evenly strided sample) times ``spacing_factor``."""
    from scipy.spatial import cKDTree

    from stratamap.core.geometry.points import first_of_each_row

    if cfg.voxel_size is not None:
        return cfg.voxel_size
    if map_voxel:
        return float(map_voxel)
    # Spacing between distinct points: a cloud may hold every point twice (a scan saved with its
    # copy), and a repeated point's nearest neighbour is itself.
    points = points[first_of_each_row(points)]
    if len(points) < 2:
        return 0.01
    sample = points[:: max(1, len(points) // 20000)]
    spacing = cKDTree(points).query(sample, k=2)[0][:, 1]
    spacing = spacing[spacing > 0]
    return float(cfg.spacing_factor * np.median(spacing)) if len(spacing) else 0.01


def source_floor(data: PipelineData) -> float | None:
    """The floor's height where an RGB-D source's gravity alignment found it (z = 0), else None."""
    stream = data.stream
    alignment = stream.metadata.get("gravity_alignment") if stream is not None else None
    return 0.0 if alignment and alignment.get("floor_inliers", 0) > 0 else None


def estimate_normals(points: np.ndarray, radius: float, views: np.ndarray) -> np.ndarray:
    """PCA normals within ``radius`` (Open3D), each turned to face the nearest of ``views``."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    normals = np.asarray(cloud.normals).copy()
    nearest = views[cKDTree(views).query(points)[1]]
    flip = np.einsum("ij,ij->i", normals, nearest - points) < 0
    normals[flip] *= -1
    return normals


def convex_links(
    points: np.ndarray, normals: np.ndarray, pairs: np.ndarray, smooth_deg: float, tolerance: float
) -> np.ndarray:
    """Which neighbour pairs are locally convex or smooth (kept)."""
    i, j = pairs[:, 0], pairs[:, 1]
    diff = points[i] - points[j]
    dist = np.linalg.norm(diff, axis=1)
    convexity = np.einsum("ij,ij->i", normals[i] - normals[j], diff)
    smooth = np.einsum("ij,ij->i", normals[i], normals[j]) >= np.cos(np.radians(smooth_deg))
    return smooth | (convexity >= -tolerance * dist)


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = (
        coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        if len(pairs)
        else coo_matrix((n, n))
    )
    # int64: patch-pair keys are products of patch ids, which overflow int32 past 46,341 patches
    return connected_components(graph, directed=False)[1].astype(np.int64)


class PatchGraph(NamedTuple):
    """Smooth patches (supervoxels) and their adjacency, each edge convex (kept) or concave."""

    patch: np.ndarray  # patch id per point
    centroid: np.ndarray  # (patches, 3)
    normal: np.ndarray  # (patches, 3), unit, facing the sensor
    size: np.ndarray  # points per patch
    edges: np.ndarray  # (edges, 2) adjacent patch pairs
    convex: np.ndarray  # per edge: convex or flat, and most point links across it agree
    crease: np.ndarray  # per edge: concave at the cuts' stricter tolerance (planar cuts follow these)


def patch_graph(
    points: np.ndarray,
    normals: np.ndarray,
    pairs: np.ndarray,
    cfg: ClustersConfig,
    patch_size: float,
    tolerance: float,
    cut_tolerance: float,
) -> PatchGraph:
    """Smooth patches inside coarse cells of side ``patch_size`` (metres), and which adjacent
    patches meet convexly at concavity ``tolerance`` (and at ``cut_tolerance``, for the cuts). A
    patch pair's boundary is convex when the patches' mean normals and centroids say so and most
    point links across it agree; one noisy link cannot join two objects."""
    cell = np.floor(points / patch_size).astype(np.int64)
    same_cell = np.all(cell[pairs[:, 0]] == cell[pairs[:, 1]], axis=1)
    smooth = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) >= np.cos(
        np.radians(cfg.patch_normal_deg)
    )
    patch = _components(len(points), pairs[same_cell & smooth])
    n_patch = int(patch.max()) + 1
    count = np.bincount(patch, minlength=n_patch).astype(float)
    centroid = (
        np.stack([np.bincount(patch, weights=points[:, k], minlength=n_patch) for k in range(3)], 1) / count[:, None]
    )
    normal = np.stack([np.bincount(patch, weights=normals[:, k], minlength=n_patch) for k in range(3)], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    a, b = patch[pairs[:, 0]], patch[pairs[:, 1]]
    between = a != b
    lo, hi = np.minimum(a[between], b[between]), np.maximum(a[between], b[between])
    key = lo * n_patch + hi
    keys, inverse = np.unique(key, return_inverse=True)
    pa, pb = keys // n_patch, keys % n_patch
    diff = centroid[pa] - centroid[pb]
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
    convexity = np.einsum("ij,ij->i", normal[pa] - normal[pb], diff)
    flat = np.einsum("ij,ij->i", normal[pa], normal[pb]) >= np.cos(np.radians(cfg.smooth_deg))

    def kept(tolerance: float) -> np.ndarray:
        link_ok = convex_links(points, normals, pairs[between], cfg.smooth_deg, tolerance)
        votes = np.bincount(inverse, weights=link_ok.astype(float)) / np.bincount(inverse)
        return ((convexity >= -tolerance * dist) | flat) & (votes >= cfg.convex_votes)

    return PatchGraph(
        patch,
        centroid,
        normal,
        count,
        np.stack([pa, pb], 1),
        kept(tolerance),
        ~kept(cut_tolerance),
    )


def convex_segments(graph: PatchGraph) -> np.ndarray:
    """LCCP: patches merged across convex boundaries; a segment id per patch."""
    return _components(len(graph.centroid), graph.edges[graph.convex])


def _cut_side(
    graph: PatchGraph, members: np.ndarray, n: np.ndarray, p0: np.ndarray, cfg: ClustersConfig, cut_distance: float
) -> np.ndarray | None:
    """Which of a segment's patches lie beyond the face plane (n, p0), the plane first refit to
    the face; None when the plane follows no real face or leaves one side empty."""
    centroid, normal = graph.centroid, graph.normal
    cos_par, cos_crease = np.cos(np.radians(cfg.smooth_deg)), np.cos(np.radians(cfg.cut_crease_deg))
    # A crease patch's normal is bent by its neighbour across the crease: refit the plane to the
    # face's patches (near it, facing its way), twice.
    for tolerance in (2 * cut_distance, cut_distance):
        face = members[(np.abs((centroid[members] - p0) @ n) <= tolerance) & (normal[members] @ n >= cos_par)]
        if len(face) < 3:
            break
        w = graph.size[face] / graph.size[face].sum()
        p0 = w @ centroid[face]
        refit = np.linalg.svd((centroid[face] - p0) * np.sqrt(w)[:, None], full_matrices=False)[2][2]
        n = refit if refit @ n >= 0 else -refit
    offset = (centroid[members] - p0) @ n
    # Patches on the plane turned less than a crease from it belong to the face (its rim and
    # crease patches have normals bent by their neighbours), hence to the solid behind it.
    on_face = (np.abs(offset) <= cut_distance) & (normal[members] @ n >= cos_crease)
    side = (offset > 0) & ~on_face
    # A cut follows a real face (the top a box stands on), not a curved surface's tangent plane
    # (a bowl's concave inside).
    if side.all() or not side.any() or on_face.sum() < cfg.cut_face_patches:
        return None
    return side


def planar_cuts(graph: PatchGraph, segments: np.ndarray, cfg: ClustersConfig, cut_distance: float) -> np.ndarray:
    """Split segments along planes through their concave creases (CPC's idea, simplified).

    Candidate planes: for every concave edge inside a segment, the plane of each of its two
    patches. A candidate's support is the concave edges lying on it (midpoint within
    ``cut_distance``, metres) with one patch facing its way. The best supported plane cuts the segment
    when at least ``cut_concave_share`` of the patch edges it severs are concave: a box's own
    faces meet at convex edges, so a plane through its top severs convex edges only. Patches on
    the plane facing its way are the face itself and stay with the solid behind it. Returns a
    segment id per patch."""
    # Creases at the cuts' own (stricter) tolerance: merging forgives noise, cutting follows real creases.
    centroid, normal, edges, convex = graph.centroid, graph.normal, graph.edges, ~graph.crease
    labels = segments.copy()
    next_label = int(labels.max()) + 1 if len(labels) else 0
    cos_par, cos_crease = np.cos(np.radians(cfg.smooth_deg)), np.cos(np.radians(cfg.cut_crease_deg))
    side_of = np.zeros(len(labels), bool)
    for _ in range(cfg.cut_depth):
        changed = False
        same = labels[edges[:, 0]] == labels[edges[:, 1]]
        # Each segment's own edges and patches, found once a pass (a cut relabels only the segment cut).
        edges_of = members_of(np.where(same, labels[edges[:, 0]], -1), next_label)
        patches_of = members_of(labels, next_label)
        for seg in np.unique(labels[edges[same & ~convex, 0]]):
            own, own_convex = edges[edges_of[seg]], convex[edges_of[seg]]
            ca, cb = own[~own_convex, 0], own[~own_convex, 1]
            # Creases, not curvature: the faces meeting there turn by more than cut_crease_deg
            # (a box side on a box top: 90 degrees; a bowl's inside: a few degrees per patch).
            sharp = np.einsum("ij,ij->i", normal[ca], normal[cb]) <= cos_crease
            if sharp.sum() < cfg.cut_min_links:
                continue
            ca, cb = ca[sharp], cb[sharp]
            mid = 0.5 * (centroid[ca] + centroid[cb])
            cand_n = np.concatenate([normal[ca], normal[cb]])
            cand_p = np.concatenate([centroid[ca], centroid[cb]])
            score = np.zeros(len(cand_n), np.int64)
            for start in range(0, len(cand_n), 256):  # candidates x creases, in chunks (large maps)
                n, p = cand_n[start : start + 256], cand_p[start : start + 256]
                near = np.abs(n @ mid.T - np.einsum("ij,ij->i", n, p)[:, None]) <= cut_distance
                aligned = (np.abs(n @ normal[ca].T) >= cos_par) | (np.abs(n @ normal[cb].T) >= cos_par)
                score[start : start + 256] = (near & aligned).sum(1)
            members = patches_of[seg]
            chosen, chosen_share = None, cfg.cut_concave_share
            # The best supported planes, each tried; the one severing the most concave share wins.
            tried: list[tuple[np.ndarray, float]] = []
            for best in np.argsort(-score, kind="stable"):
                if len(tried) >= cfg.cut_candidates or score[best] == 0:
                    break
                n, p0 = cand_n[best], cand_p[best]
                # Distinct planes only: the support of one crease repeats the same plane many times.
                if any(abs(n @ m) >= cos_par and abs(n @ p0 - d) <= cut_distance for m, d in tried):
                    continue
                tried.append((n, float(n @ p0)))
                side = _cut_side(graph, members, n, p0, cfg, cut_distance)
                if side is None:
                    continue
                side_of[members] = side
                crossing = side_of[own[:, 0]] != side_of[own[:, 1]]
                side_of[members] = False
                share = (crossing & ~own_convex).sum() / max(crossing.sum(), 1)
                if crossing.any() and share >= chosen_share:
                    chosen, chosen_share = side, share
            if chosen is None:
                continue
            labels[members[chosen]] = next_label
            next_label += 1
            changed = True
        if not changed:
            break
    # A side may fall apart into pieces: keep connected parts apart.
    same = labels[edges[:, 0]] == labels[edges[:, 1]]
    return _components(len(labels), edges[same])


class Supports(NamedTuple):
    """Which working cells belong to which support surface, and the surfaces' heights and areas."""

    of_cell: np.ndarray  # support index per cell, -1 none
    height: np.ndarray
    area: np.ndarray


def absorb_lines(cells: np.ndarray, segment: np.ndarray, pairs: np.ndarray, voxel: float) -> np.ndarray:
    """Segments that are a line of cells (a box's edge or a rim the normals could not place; second
    principal spread under half a voxel) join the neighbouring segment they share most links with."""
    n = int(segment.max()) + 1 if len(segment) else 0
    if n == 0:
        return segment
    count = np.bincount(segment, minlength=n).astype(float)
    mean = np.stack([np.bincount(segment, weights=cells[:, k], minlength=n) for k in range(3)], 1) / count[:, None]
    centred = cells - mean[segment]
    cov = (
        np.stack(
            [
                np.stack(
                    [np.bincount(segment, weights=centred[:, a] * centred[:, b], minlength=n) for b in range(3)], 1
                )
                for a in range(3)
            ],
            1,
        )
        / count[:, None, None]
    )
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(cov)[:, 1], 0.0))
    line = spread < 0.5 * voxel
    a, b = segment[pairs[:, 0]], segment[pairs[:, 1]]
    cross = a != b
    a, b = np.concatenate([a[cross], b[cross]]), np.concatenate([b[cross], a[cross]])
    keep = line[a] & ~line[b]
    if not keep.any():
        return segment
    links, counts = np.unique(np.stack([a[keep], b[keep]], 1), axis=0, return_counts=True)
    order = np.lexsort((links[:, 1], -counts, links[:, 0]))  # per line segment: most links first
    links = links[order]
    first = np.unique(links[:, 0], return_index=True)[1]
    target = np.arange(n)
    target[links[first, 0]] = links[first, 1]
    return target[segment]


def _hull_equations(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-planes ``a @ p + b <= 0`` of the 2D convex hull of ``xy`` (a point's box if degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        eq = ConvexHull(xy).equations
        return eq[:, :2], eq[:, 2]
    except (QhullError, ValueError):
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        return np.array([[1.0, 0], [-1, 0], [0, 1], [0, -1]]), np.array([-hi[0], lo[0], -hi[1], lo[1]])


def _share_within(xy: np.ndarray, around: np.ndarray, margin: float = 0.05) -> float:
    """The share of points ``xy`` within ``margin`` (m) of the convex hull of ``around`` (top view)."""
    a, b = _hull_equations(around)
    return float(((xy @ a.T + b) <= margin).all(axis=1).mean())


def grow_supports(
    cells: np.ndarray,
    supports: Supports,
    free: np.ndarray,
    pairs: np.ndarray,
    tolerance: float,
    voxel: float,
    rings: int = 3,
) -> np.ndarray:
    """Grow each support surface, in place, by up to ``rings`` rings of neighbouring ``free`` cells
    within ``tolerance`` of its height and inside its footprint (convex hull, grown by a voxel);
    returns the cells taken. Next to what stands on a table the normals bend and the layout's fit
    leaves a ring of the top out, through which a cup's segment would reach the table's edge and
    legs and join the table. Neighbours only: a chair's back at the table's height under its edge
    stays the chair's. One pass over the neighbour pairs per ring, whatever the number of surfaces."""
    n_sup = len(supports.height)
    if not n_sup or not len(pairs):
        return np.zeros(0, np.int64)
    z = cells[:, 2]
    hulls = [_hull_equations(cells[m, :2]) if len(m) >= 3 else None for m in members_of(supports.of_cell, n_sup)]
    both = np.concatenate([pairs, pairs[:, ::-1]])
    # Only pairs from a cell that could join a surface (free, not on one, at a surface's height) matter.
    lo, hi = supports.height.min() - tolerance, supports.height.max() + tolerance
    both = both[free[both[:, 1]] & (z[both[:, 1]] >= lo) & (z[both[:, 1]] <= hi)]
    grown = []
    for _ in range(rings):
        k = supports.of_cell[both[:, 0]]
        open_ = (k >= 0) & (supports.of_cell[both[:, 1]] < 0)
        cand, k = both[open_, 1], k[open_]
        ok = np.abs(z[cand] - supports.height[k]) <= tolerance
        cand, k = cand[ok], k[ok]
        inside = np.zeros(len(cand), bool)
        for surface in np.unique(k):
            if hulls[surface] is None:
                continue
            sel = np.flatnonzero(k == surface)
            a, b = hulls[surface]
            inside[sel] = ((cells[cand[sel], :2] @ a.T + b) <= voxel).all(axis=1)
        cand, k = cand[inside], k[inside]
        if not len(cand):
            break
        # A cell next to two surfaces joins the lowest-numbered (deterministic).
        order = np.lexsort((k, cand))
        cand, k = cand[order], k[order]
        first = np.r_[True, cand[1:] != cand[:-1]]
        supports.of_cell[cand[first]] = k[first]
        grown.append(cand[first])
    return np.concatenate(grown) if grown else np.zeros(0, np.int64)


#: A small part of an instance this many voxels or more away from the rest of it and as far above all of
#: it is a stray, not a piece the map saw apart (a chair's back over an unseen joint is no small part).
STRAY_GAP_VOXELS = 4.0


def stray_points(points: np.ndarray, radius: float, gap: float, smallest: int) -> np.ndarray:
    """Which of one instance's points (z up) are strays: connected parts (neighbours within
    ``radius``) of fewer than ``smallest`` points, other than its largest part, that lie ``gap`` or
    more from that largest part and rise ``gap`` or more above the highest of all its other points.
    Nothing holds such a part up: a few cells of a wall corner a metre above a sofa double its box,
    and no rule names a 1.7 m sofa. A part beside the rest (a swivel chair's caster past its unseen
    spoke, on the floor) or within its height (the scraps of a worktop's edge) stays."""
    from scipy.spatial import cKDTree

    from stratamap.plugins.segmenters._layout import components, neighbour_pairs

    stray = np.zeros(len(points), bool)
    if len(points) < 2:
        return stray
    part = components(len(points), neighbour_pairs(points, radius))
    size = np.bincount(part)
    main = int(size.argmax())
    top = np.full(len(size), -np.inf)
    np.maximum.at(top, part, points[:, 2])
    order = np.argsort(-top, kind="stable")
    # The highest point of all the other parts: the highest part's, or for that part the next one's.
    others_top = np.where(np.arange(len(size)) == order[0], top[order[min(1, len(order) - 1)]], top[order[0]])
    candidate = (size < smallest) & (top >= others_top + gap)
    candidate[main] = False
    if not candidate.any():
        return stray
    apart = np.full(len(size), np.inf)
    on_candidate = candidate[part]
    np.minimum.at(apart, part[on_candidate], cKDTree(points[part == main]).query(points[on_candidate])[0])
    return (candidate & (apart >= gap))[part]


def trim_feet(
    points: np.ndarray,
    class_ids: np.ndarray,
    instance_ids: np.ndarray,
    surface_of_point: np.ndarray,
    voxel: float,
) -> int:
    """A thing gives back its points at its foot (within half a voxel of its lowest point) outside the
    top-view convex hull of its body (its points more than 1.5 voxels up) by more than half a voxel,
    where a surface things stand on goes on beyond them (``surface_of_point``: a support surface's id
    or the floor's, -1 for none): such a point takes the class and instance of a point of something
    else in such a surface, level with it (within half a voxel) and within two voxels, or of one of
    its own that did so first, from the outside in; in place. Returns how many moved.

    A detector's mask around a cup takes a ring of the table top with it, which widens the cup's box
    by half; its own base and a chair's feet lie under their bodies and stay, and a surface that is
    the thing's own (a seat's top, under a back) has nothing else in it to give back to. Things with
    no body above their base layer (a sheet of paper, a book lying flat) are left as they are."""
    from scipy.spatial import cKDTree

    n = int(instance_ids.max()) if len(instance_ids) else 0
    rings = []
    for k, idx in enumerate(members_of(instance_ids, n + 1)):
        if k == 0 or len(idx) < 4:
            continue
        z = points[idx, 2]
        foot = float(z.min())
        body = z > foot + 1.5 * voxel
        layer = np.flatnonzero(z <= foot + 0.5 * voxel)
        if body.sum() < 3 or not len(layer):
            continue
        a, b = _hull_equations(points[idx[body], :2])
        beyond = (points[idx[layer], :2] @ a.T + b).max(axis=1)
        outside = beyond > 0.5 * voxel
        if outside.any():
            rings.append((idx[layer[outside]], beyond[outside]))
    if not rings:
        return 0
    ring = np.concatenate([r for r, _ in rings])
    # Farthest from the body first, so that a ring wider than the search radius moves from outside in.
    ring = ring[np.argsort(-np.concatenate([d for _, d in rings]), kind="stable")]
    near_dist, near = cKDTree(points).query(points[ring], k=16, distance_upper_bound=2.0 * voxel)
    owner = instance_ids[ring].copy()
    surface_of_point = surface_of_point.copy()
    pending = np.ones(len(ring), bool)
    while pending.any():
        moved_now = 0
        for row in np.flatnonzero(pending):
            for d, j in zip(near_dist[row], near[row], strict=True):
                if not np.isfinite(d):
                    break
                level = abs(points[j, 2] - points[ring[row], 2]) <= 0.5 * voxel
                if instance_ids[j] != owner[row] and surface_of_point[j] >= 0 and level:
                    class_ids[ring[row]], instance_ids[ring[row]] = class_ids[j], instance_ids[j]
                    surface_of_point[ring[row]] = surface_of_point[j]
                    pending[row] = False
                    moved_now += 1
                    break
        if not moved_now:
            break
    return int((~pending).sum())


def return_feet(
    cells: np.ndarray, obj: np.ndarray, segment: np.ndarray, grown: np.ndarray, pairs: np.ndarray, supports: Supports
) -> None:
    """Cells a support took by :func:`grow_supports` that touch a clustered cell above them (the
    bottom row of a cup standing on a table) go back to that cell's object (the nearest such) and
    leave the support, in place."""
    if not len(grown) or not len(pairs):
        return
    is_grown = np.zeros(len(cells), bool)
    is_grown[grown] = True
    both = np.concatenate([pairs, pairs[:, ::-1]])
    foot, above = both[:, 0], both[:, 1]
    keep = is_grown[foot] & (segment[above] >= 0) & (obj[above] >= 0) & (cells[above, 2] > cells[foot, 2])
    foot, above = foot[keep], above[keep]
    if not len(foot):
        return
    order = np.lexsort((above, np.linalg.norm(cells[above] - cells[foot], axis=1), foot))
    foot, above = foot[order], above[order]
    first = np.r_[True, foot[1:] != foot[:-1]]
    obj[foot[first]] = obj[above[first]]
    supports.of_cell[foot[first]] = -1  # no longer the support's top


#: A part of a segment rising above a support surface within its footprint stands on it (a cup) when
#: it spans at most this share of the surface's narrower side; wider, it is the support's own (a
#: counter's upstand along its back, a desk's hutch).
STANDING_SHARE = 0.5


def split_standing(
    cells: np.ndarray, segment: np.ndarray, supports: Supports, pairs: np.ndarray, voxel: float, cfg: ClustersConfig
) -> np.ndarray:
    """Where one segment holds both something standing on a support surface and what lies below
    that surface (a mug flush with a table's edge: its wall and the table's apron meet smoothly, so
    convexity did not part them): each connected part of its cells above the surface that lies wholly
    over the surface's footprint, rises above it from its height and spans at most STANDING_SHARE of
    the surface's narrower side becomes a segment of its own, which ``join_supports`` then keeps
    apart. Returns the segments. Linear in the map's size: each segment's cells and links are found
    with one sort, not one pass over the map per segment."""
    segment = segment.copy()
    n_sup = len(supports.height)
    n_seg = int(segment.max()) + 1 if (segment >= 0).any() else 0
    if not n_sup or not n_seg:
        return segment
    z = cells[:, 2]
    rise, off_surface = 2.5 * voxel, cfg.layout.plane_voxels * voxel
    min_cells = max(cfg.min_cells, int(np.ceil(cfg.min_area / voxel**2)))
    surface_cells, segment_cells = members_of(supports.of_cell, n_sup), members_of(segment, n_seg)
    pair_surface, pair_segment = supports.of_cell[pairs], segment[pairs]
    # Which segments touch which surface, in the order of the surfaces.
    touch = np.concatenate([pair_surface[:, [1]], pair_segment[:, [0]], pair_surface[:, [0]], pair_segment[:, [1]]], 1)
    touch = touch.reshape(-1, 2)
    touch = touch[(touch >= 0).all(axis=1)]
    key = np.unique(touch[:, 0] * n_seg + touch[:, 1])  # one 1-D unique: a row-wise one is slow on many pairs
    touch = np.stack([key // n_seg, key % n_seg], 1)
    inner = (pair_segment[:, 0] == pair_segment[:, 1]) & (pair_segment[:, 0] >= 0)
    inner_pairs = pairs[inner]
    inner_of_segment = members_of(pair_segment[inner, 0], n_seg)
    next_id, shape_of = n_seg, {}
    for sup, seg in touch:
        members = surface_cells[sup]
        if len(members) < 3:
            continue
        if sup not in shape_of:
            xy = cells[members, :2]
            # The surface's narrower side: its extent across its principal axis.
            centred = xy - xy.mean(axis=0)
            axes = np.linalg.svd(centred, full_matrices=False)[2]
            shape_of[sup] = (xy, axes, float(np.ptp(centred @ axes[-1])))
        xy, axes, narrow = shape_of[sup]
        height = float(supports.height[sup])
        own = segment_cells[seg]
        still = segment[own] == seg  # not split off for another surface
        if not still.any() or z[own[still]].min() >= height - off_surface:
            continue  # it stands there as a whole
        is_above = still & (z[own] > height + off_surface)
        above = own[is_above]
        if len(above) < min_cells:
            continue
        # The surface's footprint with its rim: the segment's cells at its height (a top's edge,
        # whose normals bend, is left out of the surface and clustered with the apron).
        rim = own[still & (np.abs(z[own] - height) <= off_surface)]
        a, b = _hull_equations(np.concatenate([xy, cells[rim, :2]]))
        over = ((cells[above, :2] @ a.T + b) <= voxel).all(axis=1)
        links = np.searchsorted(own, inner_pairs[inner_of_segment[seg]])
        links = links[is_above[links].all(axis=1)]
        part = _components(len(above), (np.cumsum(is_above) - 1)[links])
        lifted = still & (z[own] > height + 0.5 * voxel)  # candidates for a split part's foot
        for k in range(int(part.max()) + 1):
            # Wholly over the surface: a sofa's back rising behind its seat reaches beyond it.
            if not over[part == k].all():
                continue
            piece = above[part == k]
            if len(piece) < min_cells or z[piece].max() < height + rise:
                continue
            if z[piece].min() > height + off_surface + 1.5 * voxel:
                continue  # held above the surface, not standing on it
            span = float(np.ptp(cells[piece, :2] @ axes.T, axis=0).max())
            if span > STANDING_SHARE * narrow:
                continue
            # Its foot: the segment's cells off the surface by half a voxel, under its top view.
            pa, pb = _hull_equations(cells[piece, :2])
            foot = own[lifted & ((cells[own, :2] @ pa.T + pb) <= 0.5 * voxel).all(axis=1)]
            segment[np.union1d(piece, foot)] = next_id
            next_id += 1
    return segment


def join_supports(
    cells: np.ndarray,
    segment: np.ndarray,
    supports: Supports,
    pairs: np.ndarray,
    voxel: float,
    cfg: ClustersConfig,
    has_floor: bool = True,
) -> np.ndarray:
    """Give each support surface its object back. ``segment``: segment id per cell (-1 for cells
    not clustered: stuff and supports); ``pairs``: neighbouring cells. Returns an object id per
    cell (-1 for stuff): segments standing on a support stay apart from it, the rest of what touches
    it (edges, legs, the body under a counter top, and what touches those below the surface) joins it.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_seg = int(segment.max()) + 1 if (segment >= 0).any() else 0
    n_sup = len(supports.height)
    z = cells[:, 2]
    clustered = segment >= 0
    # A segment's foot and top, and its size.
    bottom, top = np.full(n_seg, np.inf), np.full(n_seg, -np.inf)
    np.minimum.at(bottom, segment[clustered], z[clustered])
    np.maximum.at(top, segment[clustered], z[clustered])
    count = np.bincount(segment[clustered], minlength=n_seg)
    node = np.where(clustered, segment, np.where(supports.of_cell >= 0, n_seg + supports.of_cell, -1))
    a, b = node[pairs[:, 0]], node[pairs[:, 1]]
    touching = (a >= 0) & (b >= 0) & (a != b)
    edges = np.unique(np.sort(np.stack([a[touching], b[touching]], 1), axis=1), axis=0)
    links: list[tuple[int, int]] = []
    if n_sup and n_seg:
        # Each support's footprint: the convex hull of its top, so the hole an object's shadow
        # leaves in the scanned top still counts as on it; grown by a voxel for its rim.
        hulls = [_hull_equations(cells[m, :2]) for m in members_of(supports.of_cell, n_sup)]
        order = np.argsort(segment, kind="stable")
        starts = np.searchsorted(segment[order], np.arange(n_seg + 1))
        rise = 2.5 * voxel
        stand_tol = 2.0 * cfg.layout.plane_voxels * voxel

        def inside(seg: int, sup: int) -> float:
            xy = cells[order[starts[seg] : starts[seg + 1]], :2]
            a, b = hulls[sup]
            return float(((xy @ a.T + b) <= voxel).all(axis=1).mean())

        sup_edges = edges[(edges[:, 0] < n_seg) & (edges[:, 1] >= n_seg)]
        stands = np.zeros(n_seg, bool)
        for seg, sup_node in sup_edges:
            sup = sup_node - n_seg
            # Its foot at the surface and rising above it: it stands there (a cup, or a box at the edge
            # of a partly seen table, its footprint out of the hull). What reaches below is the table's.
            if bottom[seg] >= supports.height[sup] - stand_tol and top[seg] >= supports.height[sup] + rise:
                stands[seg] = True
        owners: list[list[int]] = [[] for _ in range(n_seg)]  # the supports a segment joined
        for seg, sup_node in sup_edges:
            if not stands[seg]:
                links.append((int(seg), int(sup_node)))
                owners[seg].append(int(sup_node - n_seg))
        # What touches a joined segment and lies wholly below one of its supports (legs under the
        # edge) joins too.
        seg_edges = edges[edges[:, 1] < n_seg]
        grown = True
        while grown:  # each round joins at least one segment, so at most n_seg rounds
            grown = False
            for s1, s2 in np.concatenate([seg_edges, seg_edges[:, ::-1]]):
                if not owners[s1] or owners[s2] or stands[s2]:
                    continue
                for sup in owners[s1]:
                    if top[s2] <= supports.height[sup] + stand_tol and inside(s2, sup) >= cfg.below_share:
                        owners[s2].append(sup)
                        links.append((int(s2), int(n_seg + sup)))
                        grown = True
                        break
        if not has_floor:
            # No floor (a tabletop scan): what lies wholly below the largest support is its
            # furniture (its edge, legs, what stands under it); the scan sees nothing else there.
            main = int(np.argmax(supports.area))
            below = np.flatnonzero((top <= supports.height[main] + stand_tol) & ~stands & (count > 0))
            links += [(int(seg), n_seg + main) for seg in below]
    n = n_seg + n_sup
    if n == 0:  # all stuff (a scan of a bare floor)
        return np.full(len(cells), -1, np.int64)
    pairs_ = np.array(links, np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs_)), (pairs_[:, 0], pairs_[:, 1])), shape=(n, n))
    obj = connected_components(graph, directed=False)[1].astype(np.int64)
    return np.where(node >= 0, obj[np.maximum(node, 0)], -1)


def _rests_on_another(
    points: np.ndarray,
    sel: np.ndarray,
    iid: int,
    instance_ids: np.ndarray,
    holder: np.ndarray,
    tops: np.ndarray,
    top_tree: Any,
    reach: float,
) -> bool:
    """Whether instance ``iid`` (its points ``sel``) rests on another object: its foot (its lowest
    3 cm) within ``reach`` of the points ``tops`` (a k-d tree over them: support surfaces and other
    instances, keyed by ``holder``) lying no higher, and 90 % of it at least 5 cm inside the outline of
    what it touches there. A chair's back seen over a desk's far edge, or at the edge of a table it is
    pushed under, its legs hidden, touches the top too, but not well inside it."""
    z = points[sel, 2]
    foot = points[sel][z <= z.min() + 0.03]
    hits = top_tree.query_ball_point(foot, reach)
    near = np.unique(np.concatenate([np.asarray(h, np.int64) for h in hits]))
    near = tops[near]
    near = near[(instance_ids[near] != iid) & (points[near, 2] <= foot[:, 2].max())]
    return any(
        _share_within(foot[:, :2], points[holder == k, :2], margin=-0.05) >= 0.9 for k in np.unique(holder[near])
    )


def _largest_top(
    support_of_point: np.ndarray, support_areas: np.ndarray, support_heights: np.ndarray, foot: float, top: float
) -> float:
    """The area (m^2) of the largest support surface among an object's points (``support_of_point``: -1
    none) that the object holds: not one at its ``foot`` that it rises above by more than THIN, which
    it stands on (a chair's mask takes the floor between its runners along). A surface at its foot
    that is also its top (a desk top seen without its legs) it holds."""
    held = support_of_point[support_of_point >= 0]
    height = support_heights[held]
    held = held[(height > foot) | (top - height <= THIN)]
    return float(support_areas[held].max()) if len(held) else 0.0


def _thing_shapes(
    points: np.ndarray,
    class_ids: np.ndarray,
    instance_ids: np.ndarray,
    vocab: Vocabulary,
    base_z: float,
    walls: list[Any],
    sight: Sightlines | None,
) -> dict[int, tuple[str, Shape, np.ndarray]]:
    """Each instance of a thing class (its points' most frequent) with 4 points or more, by id: its
    class, its shape and its point indices."""
    from stratamap.core.map.instances import instance_members

    info = {}
    for iid, sel in instance_members(instance_ids).items():
        cls = int(np.bincount(class_ids[sel]).argmax())
        if len(sel) >= 4 and vocab.is_thing[cls]:
            info[iid] = (vocab.name(cls), describe_shape(points[sel], base_z, walls, sight), sel)
    return info


def _thin(pts: np.ndarray) -> bool:
    """Thinner than THIN across, in height (2-98 % of its points: a single frame's floor bends by
    centimetres at range) or in depth (a poster on a wall), and flat: at most FLAT times as thick as
    it is broad. A cup standing against a wall, 10 cm every way, is no piece of that wall."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    low, high = np.percentile(pts[:, 2], [2.0, 98.0])
    sides = sorted((float(high - low), *map(float, gravity_aligned_box(pts).size[:2])))
    return sides[0] < THIN and sides[0] <= FLAT * sides[1]


def _voted(name: str, share: float) -> tuple[str, str]:
    """The naming (``set_naming``'s by, why) of an object its fused votes named."""
    return "votes", f"{share:.0%} of its points were voted {name}"


#: _class_of's reason when none of the class rules names an object.
NO_CLASS_RULE_FITS = "no class rule fits"


def _ruled(by: str, rule: str) -> tuple[str, str]:
    """The naming of an object a rule named (``by``, the rule), or ``unnamed`` where no rule fitted it."""
    return ("unnamed", rule) if rule in (NO_RULE_FITS, NO_CLASS_RULE_FITS) else (by, rule)


def _hand_held(shape: Shape) -> bool:
    """Whether an object of this shape may be a thing of a hand's size (a cup, a bottle)."""
    return any(fits_class(name, shape) for name in HAND_HELD)


class ClustersSegmenter(Segmenter[ClustersConfig]):
    """Model-free instances: gravity-aligned layout as stuff, convexity-aware clustering around support surfaces."""

    name = "clusters"
    Config = ClustersConfig
    requires = frozenset({"geometry"})
    optional = frozenset({"semantics"})
    provides = frozenset({"semantics", "instances"})

    @classmethod
    def example_params(cls) -> dict:
        return {"min_cells": 5}

    def segment(self, data: PipelineData) -> dict[str, Any]:
        from stratamap.core.map.instances import instances_from_semantics
        from stratamap.plugins.segmenters._layout import neighbour_pairs

        cfg = self.config
        geometry = data.map.geometry
        if geometry is None or len(geometry.points) == 0:
            raise DataError("clusters: the geometry layer has no points")
        points = geometry.points
        votes = (
            data.map.semantics if data.map.semantics is not None and len(data.map.semantics) == len(points) else None
        )
        vocab = (
            votes.vocabulary
            if votes is not None
            else data.map.vocabulary
            or (data.ground_truth.vocabulary if data.ground_truth is not None else Vocabulary.default())
        )
        for rule in cfg.class_rules:
            if rule.class_name not in vocab or not vocab.is_thing[vocab.id(rule.class_name)]:
                raise DataError(
                    f"clusters: class_rules names {rule.class_name!r}, which is not a thing class of the vocabulary"
                )
        voxel = working_voxel(points, geometry.voxel_size, cfg)
        cells, cell_of_point = voxel_downsample(points, voxel)
        views = sensor_viewpoints(data.stream, cells)
        normals = estimate_normals(cells, cfg.normal_radius_voxels * voxel, views)

        # 1. Layout: floor, walls, ceiling (stuff) and support surfaces (objects' tops).
        layout = find_layout(
            cells,
            voxel,
            normals=normals,
            gravity=cfg.gravity == "z",
            params=cfg.layout,
            viewpoints=views,
            floor_hint=source_floor(data),
        )
        supports = Supports(
            np.full(len(cells), -1, np.int64),
            np.array([s.height for s in layout.supports]),
            np.array([s.area for s in layout.supports]),
        )
        for k, surface in enumerate(layout.supports):
            supports.of_cell[surface.indices] = k
        stuff = layout.labels != NONE
        objects = np.flatnonzero(~stuff)
        pairs = objects[neighbour_pairs(cells[objects], cfg.radius_voxels * voxel)]
        grown = grow_supports(cells, supports, ~stuff, pairs, 0.5 * voxel, voxel)
        free = np.flatnonzero(~stuff & (supports.of_cell < 0))
        # 2. Clustering of the rest.
        segment = np.full(len(cells), -1, np.int64)
        if len(free):
            local = np.full(len(cells), -1, np.int64)
            local[free] = np.arange(len(free))
            free_pairs = local[pairs]
            free_pairs = free_pairs[(free_pairs >= 0).all(axis=1)]
            if cfg.method == "convex" and len(free_pairs):
                # Normals again without the layout and support cells: a table top no longer bends the
                # normals at the foot of what stands on it.
                free_normals = estimate_normals(cells[free], cfg.normal_radius_voxels * voxel, views)
                tolerance = cfg.concavity_tolerance
                if tolerance is None:
                    tolerance = 0.4 if geometry.voxel_size else 0.2
                cut_tolerance = tolerance if cfg.cut_concavity_tolerance is None else cfg.cut_concavity_tolerance
                graph = patch_graph(
                    cells[free], free_normals, free_pairs, cfg, cfg.patch_voxels * voxel, tolerance, cut_tolerance
                )
                comp = convex_segments(graph)
                if cfg.cut_min_links > 0:
                    comp = planar_cuts(graph, comp, cfg, cfg.cut_distance_voxels * voxel)
                comp = comp[graph.patch]
            else:
                comp = _components(len(free), free_pairs)
            segment[free] = absorb_lines(cells[free], comp, free_pairs, voxel)
        # 3. Support surfaces get their objects back; objects standing on them stay apart.
        segment = split_standing(cells, segment, supports, pairs, voxel, cfg)
        obj = join_supports(cells, segment, supports, pairs, voxel, cfg, layout.floor_height is not None)
        return_feet(cells, obj, segment, grown, pairs, supports)

        # Cells of an object lying on a layout plane and facing its way are the plane's (where the
        # object touches a wall, the normals there are bent and the layout fit left them out).
        tol = cfg.layout.plane_voxels * voxel
        for plane in layout.planes:
            flush = (obj >= 0) & plane.near(cells, tol) & (np.abs(normals @ plane.normal) >= np.cos(np.radians(45.0)))
            obj[flush] = -1
            layout.labels[flush] = plane.label
        # 4. Instances: large enough objects, numbered by size (deterministic), named by votes or geometry.
        point_obj = obj[cell_of_point]
        min_cells = max(cfg.min_cells, int(np.ceil(cfg.min_area / voxel**2)))
        n_obj = int(obj.max()) + 1 if (obj >= 0).any() else 0
        cell_count = np.bincount(obj[obj >= 0], minlength=n_obj)
        kept = np.flatnonzero(cell_count >= min_cells)
        kept = kept[np.lexsort((kept, -cell_count[kept]))]
        stuff_ids = np.array([vocab.id(n) if n in vocab else 0 for n in LAYOUT_NAMES], np.int32)
        stuff_ids[NONE] = 0
        class_ids = stuff_ids[layout.labels[cell_of_point]]
        instance_ids = np.zeros(len(points), np.int32)
        vote_table = self._vote_table(point_obj, votes, n_obj, len(vocab)) if votes is not None else None
        top_area = np.zeros(n_obj)
        if len(supports.area):
            has = (supports.of_cell >= 0) & (obj >= 0)
            np.maximum.at(top_area, obj[has], supports.area[supports.of_cell[has]])
        base_z = (
            layout.floor_height
            if layout.floor_height is not None
            else float(supports.height.min())
            if len(supports.height)
            else float(points[:, 2].min())
        )
        on_plane = self._on_layout_planes(cells, obj, layout, n_obj, cfg.layout_voxels * voxel)
        next_id, things, turned_stuff, on_layout = 1, 0, 0, 0
        walls = [plane for plane in layout.planes if plane.label == WALL]
        sight = Sightlines.from_stream(data.stream) if cfg.recognize and cfg.sightlines else None
        why: dict[int, tuple[str, str]] = {}  # how each instance got its class (NAMED_BY), where this stage named it
        if cfg.keep_instances and votes is not None and (votes.instance_ids > 0).any():
            class_ids, instance_ids, added, why = self._complete_instances(
                points,
                point_obj,
                kept,
                on_plane,
                cell_count,
                top_area,
                votes,
                class_ids,
                supports,
                base_z,
                walls,
                sight,
                voxel,
            )
            kept = kept[:0]  # the loop below is the clusters-only naming
            things = added
        points_of = members_of(point_obj, n_obj) if len(kept) else []
        for k in kept:
            mask = points_of[k]
            name = None
            label = int(np.argmax(on_plane[k]))
            if top_area[k] == 0 and on_plane[k, label] >= cfg.layout_share * cell_count[k]:
                class_ids[mask] = stuff_ids[label]
                on_layout += 1
                continue
            if vote_table is not None:
                name = self._voted_name(vote_table[k], points[mask], stuff_ids, vocab)
                if name is not None:
                    reason = _voted(name, vote_table[k, vocab.id(name)] / len(mask))
            if name is None and cfg.recognize:
                shape = describe_shape(points[mask], base_z, walls, sight)
                name, rule = self._prior(shape, vocab, base_z, supports.height, voxel)
                reason = _ruled("shape", rule)
            if name is None:
                name, rule = self._class_of(points[mask], top_area[k], base_z, vocab, cfg)
                reason = _ruled("size rules", rule)
            class_ids[mask] = vocab.id(name)
            if vocab.is_thing[vocab.id(name)]:
                why[next_id] = reason
                instance_ids[mask] = next_id
                next_id += 1
                things += 1
            else:
                turned_stuff += 1
        strays = 0
        if cfg.drop_strays:
            radius, gap = cfg.radius_voxels * voxel, STRAY_GAP_VOXELS * voxel
            for members in members_of(instance_ids, int(instance_ids.max(initial=0)) + 1)[1:]:
                # On the working grid's cells: a raw scan holds many points per cell.
                own, cell_of_member = np.unique(cell_of_point[members], return_inverse=True)
                if len(own) > 1:
                    stray_cell = stray_points(cells[own], radius, gap, self._scrap_size())
                    stray = members[stray_cell[cell_of_member.reshape(-1)]]
                    class_ids[stray], instance_ids[stray] = stuff_ids[layout.labels[cell_of_point[stray]]], 0
                    strays += len(stray)
        if cfg.trim_feet:
            surface_of_cell = np.where(layout.labels == FLOOR, len(supports.height), supports.of_cell)
            feet = trim_feet(points, class_ids, instance_ids, surface_of_cell[cell_of_point], voxel)
        else:
            feet = 0
        if cfg.recognize:
            class_ids, instance_ids = self._recognize(
                points,
                class_ids,
                instance_ids,
                vocab,
                base_z,
                walls,
                sight,
                supports.height,
                voxel,
                supports.of_cell[cell_of_point],
                supports.area,
                why,
            )
        self.note(
            "segments",
            {
                "voxel_size": round(voxel, 5),
                "foot_points_given_back": feet,
                "stray_points_dropped": strays,
                "floor_height": None if layout.floor_height is None else round(layout.floor_height, 3),
                "walls": layout.walls,
                "supports": len(layout.supports),
                "segments": int(segment.max()) + 1 if (segment >= 0).any() else 0,
                "instances": things,
                "stuff_by_votes": turned_stuff,
                "stuff_on_planes": on_layout,
            },
        )
        semantics = Semantics(class_ids, instance_ids, vocab)
        instances = instances_from_semantics(points, geometry.colors, semantics, 1)
        before = data.map.instances if cfg.keep_instances else None
        for inst in instances:
            if inst.id in why:
                set_naming(inst, *why[inst.id])
            elif before is not None and inst.id in before and NAMING in before[inst.id].attributes:
                inst.attributes[NAMING] = dict(before[inst.id].attributes[NAMING])
            else:
                set_naming(inst, "labels", "kept from the previous stage's objects with their class")
        return {"semantics": semantics, "instances": instances}

    def _complete_instances(
        self,
        points: np.ndarray,
        point_obj: np.ndarray,
        kept: np.ndarray,
        on_plane: np.ndarray,
        cell_count: np.ndarray,
        top_area: np.ndarray,
        votes: Semantics,
        layout_class: np.ndarray,
        supports: Supports,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        voxel: float,
    ) -> tuple[np.ndarray, np.ndarray, int, dict[int, tuple[str, str]]]:
        """keep_instances: the map's instances stay; each geometric object they leave (mostly)
        uncovered becomes an instance; the unmasked points of a covered one join the nearest
        instance. Stuff is where the fused map's own layout puts it (not each frame's guess).
        Returns point classes, point instances, how many instances were added and how each added
        one got its class (``(by, why)`` by instance id)."""
        from scipy.spatial import cKDTree

        cfg = self.config
        vocab = votes.vocabulary
        prev_c, prev_i = votes.class_ids.astype(np.int32), votes.instance_ids.astype(np.int32)
        smallest = self._scrap_size()
        out_c, out_i = prev_c.copy(), prev_i.copy()
        free = prev_i == 0
        relabel = free & (layout_class > 0)
        out_c[relabel] = layout_class[relabel]
        stuff_ids = [vocab.id(n) for n in LAYOUT_NAMES[1:] if n in vocab]
        inst_size = np.bincount(prev_i[prev_i > 0], minlength=int(prev_i.max()) + 1)
        tol = self._standing_tolerance(voxel)
        # Each mask instance's class (its points' most frequent one).
        votes_by_instance = np.zeros((int(prev_i.max()) + 1, len(vocab)), np.int64)
        np.add.at(votes_by_instance, (prev_i, prev_c), 1)
        inst_class = votes_by_instance.argmax(axis=1)
        next_id, added = int(prev_i.max()) + 1, 0
        why: dict[int, tuple[str, str]] = {}
        points_of = members_of(point_obj, int(point_obj.max(initial=-1)) + 1)
        instance_points = members_of(prev_i, int(prev_i.max(initial=0)) + 1)
        for k in kept:
            mask = points_of[k]
            inside = prev_i[mask] > 0
            carried_by = None  # the class of the instance whose mask took this object along, if any
            if inside.mean() >= cfg.covered_share:
                owner = np.bincount(prev_i[mask[inside]]).argmax()
                owner_class = int(inst_class[owner])
                standing = on_a_support(float(points[mask, 2].min()), supports.height, tol) and top_area[k] == 0
                # A small object standing on a support, inside a larger object's mask (a cup in the
                # table's box), or of a hand-held thing's size there inside any other thing's mask (a
                # mug framed with a strip of worktop as a "table"): an object of its own.
                own = standing and (
                    len(mask) < 0.15 * inst_size[owner]
                    or (
                        vocab.name(owner_class) not in HAND_HELD
                        and _hand_held(describe_shape(points[mask], base_z, walls, sight))
                    )
                )
                if not own:
                    rest = mask[~inside]
                    if len(rest):
                        near = cKDTree(points[mask[inside]]).query(points[rest])[1]
                        out_i[rest] = prev_i[mask[inside][near]]
                        out_c[rest] = prev_c[mask[inside][near]]
                    continue
                rest = mask
                owner_shape = describe_shape(points[instance_points[owner]], base_z, walls, sight)
                if not fits_class(vocab.name(owner_class), owner_shape):
                    carried_by = owner_class
            else:
                rest = mask[~inside]
                label = int(np.argmax(on_plane[k]))
                if top_area[k] == 0 and on_plane[k, label] >= cfg.layout_share * cell_count[k]:
                    continue
            if len(rest) < smallest:
                continue
            # Mostly voted floor, wall or ceiling and thin: that stuff where the map's layout missed it (a
            # floor patch, a poster). Thicker, the votes say nothing: a tall unit's front the frames took
            # for a wall.
            if np.isin(prev_c[rest], stuff_ids).mean() > 0.5 and _thin(points[rest]):
                continue
            # Instances lying within this object whose own class their shape rules out (a detector box
            # that framed one side of a unit) are pieces of it.
            for piece in np.unique(prev_i[mask[inside]]):
                members = instance_points[piece]
                if (point_obj[members] == k).mean() < 0.8:
                    continue
                if not fits_class(
                    vocab.name(int(inst_class[piece])), describe_shape(points[members], base_z, walls, sight)
                ):
                    rest = np.union1d(rest, members)
            thing = [c for c in np.unique(prev_c[rest]) if c > 0 and vocab.is_thing[c]]
            shape = describe_shape(points[rest], base_z, walls, sight)
            counts = {int(c): int((prev_c[rest] == c).sum()) for c in thing}
            # Leftover votes name it only where they hold most of its points (a vote its size rules
            # out is kept for now: the piece may join an object of that class, else recognition renames it).
            # A vote for the class of the object it stands on, which that object's own size rules out, came
            # with that object's mask (a detector without a 'counter' label framed the counter as a "box"
            # and took the mug along): it names neither.
            if carried_by is not None:
                counts.pop(carried_by, None)
            voted = [vocab.name(c) for c in sorted(counts, key=lambda c: -counts[c]) if counts[c] >= 0.5 * len(rest)]
            prior, rule = self._prior(shape, vocab, base_z, supports.height, voxel) if cfg.recognize else ("object", "")
            name = voted[0] if voted else prior
            if voted:
                why[next_id] = _voted(name, counts[vocab.id(name)] / len(rest))
            elif cfg.recognize:
                why[next_id] = _ruled("shape", rule)
            else:
                why[next_id] = ("unnamed", "no vote named it, and recognize is off")
            out_i[rest] = next_id
            out_c[rest] = vocab.id(name) if name in vocab else 0
            next_id += 1
            added += 1
        # Scraps (a few points of a mask that missed its object) are no instances.
        sizes = np.bincount(out_i[out_i > 0], minlength=int(out_i.max()) + 1)
        scrap = (out_i > 0) & (sizes[out_i] < smallest)
        out_c[scrap], out_i[scrap] = 0, 0
        return out_c, out_i, added, why

    def _scrap_size(self) -> int:
        """Fewer cells than this are a scrap, no object (a few cells of a mask that missed its object)."""
        return max(self.config.min_cells, 30)

    def _standing_tolerance(self, voxel: float) -> float:
        """How close (m) an object's foot lies to a support surface's height when it stands on it."""
        return 2.0 * self.config.layout.plane_voxels * voxel

    def _prior(
        self, shape: Shape, vocab: Vocabulary, base_z: float, support_heights: np.ndarray, voxel: float
    ) -> tuple[str, str]:
        """``prior_class`` with the object's support context: whether its foot is at a support's height."""
        on_support = on_a_support(base_z + shape.bottom, support_heights, self._standing_tolerance(voxel))
        return prior_class(shape, vocab, on_support)

    def _recognize(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        support_heights: np.ndarray,
        voxel: float,
        support_of_point: np.ndarray | None = None,
        support_areas: np.ndarray | None = None,
        why: dict[int, tuple[str, str]] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Instances named ``object`` or by a class their size rules out take the class the priors
        and their support context give (``prior_class``), after pieces joined the object they belong
        to (``_join_parts``) and chairs seen in stacked pieces were assembled (``_assemble_chairs``);
        each change is noted. An instance of a class that stands on no other object (NOT_STACKED: a
        chair, a table) whose foot rests well inside the top of another instance or of a support
        surface (``support_of_point``: the support index of each point, -1 none) is none of that
        class: a unit on a desk that a weak "chair" box framed. Nor is one holding a level surface
        larger than its class's ``max_top_area`` (``support_areas``: each support's area; a desk top
        in a "chair"). Returns the point classes and instances; ``why`` (instance id -> ``(by, why)``)
        takes each renamed instance's reason."""
        from scipy.spatial import cKDTree

        from stratamap.core.map.instances import instance_members
        from stratamap.core.map.priors import CLASS_SIZES, NOT_STACKED

        class_ids = class_ids.copy()
        instance_ids = instance_ids.copy()
        why = {} if why is None else why
        self._split_units(points, class_ids, instance_ids, vocab, base_z, why)
        self._join_parts(points, class_ids, instance_ids, vocab, base_z, walls, sight, support_heights, voxel)
        self._assemble_chairs(points, class_ids, instance_ids, vocab, base_z, walls, sight, why)
        self._join_seating(points, class_ids, instance_ids, vocab, base_z, walls, sight, voxel, why)
        self._join_enclosed(
            points, class_ids, instance_ids, vocab, base_z, walls, sight, support_heights, support_of_point, voxel
        )
        # What an object may stand on: support surfaces and other instances, each by its own key.
        n_supports = len(support_areas) if support_areas is not None else 0
        holder = np.where(instance_ids > 0, n_supports + instance_ids, -1)
        if support_of_point is not None:
            holder = np.where(support_of_point >= 0, support_of_point, holder)
        tops = np.flatnonzero(holder >= 0)
        top_tree = cKDTree(points[tops]) if len(tops) else None
        changes = []
        for iid, sel in instance_members(instance_ids).items():
            cls = int(np.bincount(class_ids[sel]).argmax())
            name = vocab.name(cls)
            if len(sel) < 4 or not vocab.is_thing[cls]:
                continue
            shape = describe_shape(points[sel], base_z, walls, sight)
            new, reason = self._prior(shape, vocab, base_z, support_heights, voxel)
            carried = (
                top_tree is not None
                and name in NOT_STACKED
                and shape.bottom > FLOOR_GAP
                and _rests_on_another(points, sel, iid, instance_ids, holder, tops, top_tree, 2.5 * voxel)
            )
            largest_top = CLASS_SIZES[name].max_top_area if name in CLASS_SIZES else None
            too_large_top = (
                largest_top is not None
                and support_of_point is not None
                and support_areas is not None
                and _largest_top(
                    support_of_point[sel],
                    support_areas,
                    support_heights,
                    base_z + shape.bottom + self._standing_tolerance(voxel),
                    base_z + shape.bottom + shape.height,
                )
                > largest_top
            )
            if (
                name != "object"
                and fits_class(name, shape)
                and not carried
                and not too_large_top
                and not typical_rather(new, name, shape)
            ):
                continue
            if carried:
                reason = f"stands on another object's top, which a {name} does not; {reason}"
            elif too_large_top:
                reason = f"holds a level surface larger than a {name}'s; {reason}"
            if new != name:
                class_ids[sel] = vocab.id(new)
                changes.append({"instance": iid, "from": name, "to": new, "why": reason})
                why[iid] = ("shape", f"{reason} (was {name})")
        changes += self._counters_need_a_kitchen(points, class_ids, instance_ids, vocab, base_z, walls, sight, why)
        if changes:
            self.note("recognition", changes)
        return class_ids, instance_ids

    def _counters_need_a_kitchen(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        why: dict[int, tuple[str, str]],
    ) -> list[dict[str, Any]]:
        """A unit the priors called a counter by its size alone (a solid unit with a flat top at
        worktop height) is as likely a chest of drawers or a storage unit: where nothing in the map
        says kitchen (no counter run longer than one unit, ``counter_run``; no counter another source
        named; no KITCHEN_APPLIANCES), such units are cabinets: those no longer than one unit, and
        longer ones with no one top along them (two units that came out as one). In place; returns
        the changes."""
        from stratamap.core.map.instances import instance_members

        if "counter" not in vocab or "cabinet" not in vocab:
            return []
        short = []
        for iid, sel in instance_members(instance_ids).items():
            name = vocab.name(int(np.bincount(class_ids[sel]).argmax()))
            if name in KITCHEN_APPLIANCES:
                return []
            if name != "counter":
                continue
            shape = describe_shape(points[sel], base_z, walls, sight)
            if counter_run(shape) or why.get(iid, ("labels", ""))[0] != "shape":
                return []
            if fits_class("cabinet", shape):
                short.append((iid, sel))
        changes = []
        reason = "a counter's size, but nothing in the map says kitchen (no counter run, no appliance): a unit"
        for iid, sel in short:
            class_ids[sel] = vocab.id("cabinet")
            changes.append({"instance": iid, "from": "counter", "to": "cabinet", "why": reason})
            why[iid] = ("context", f"{reason} (was counter)")
        return changes

    def _split_units(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        why: dict[int, tuple[str, str]],
    ) -> None:
        """Units side by side that came out as one instance (``split_at_step``) become two; the taller
        one takes a new instance id (and the reason for its class, ``why``). In place; each split is
        noted."""
        from stratamap.core.map.instances import instance_members

        splits = []
        next_id = int(instance_ids.max()) + 1
        for iid, sel in instance_members(instance_ids).items():
            cls = int(np.bincount(class_ids[sel]).argmax())
            if len(sel) < 200 or not vocab.is_thing[cls]:
                continue
            tall = split_at_step(points[sel], base_z)
            if tall is None:
                continue
            instance_ids[sel[tall]] = next_id
            splits.append({"instance": iid, "taller_unit": next_id, "points": int(tall.sum())})
            if iid in why:
                by, reason = why[iid]
                why[next_id] = (by, f"{reason} (split from object {iid} where their tops step)")
            next_id += 1
        if splits:
            self.note("units_split", splits)

    def _assemble_chairs(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        why: dict[int, tuple[str, str]],
    ) -> None:
        """A chair seen in pieces stacked one over another (a swivel chair's base under its seat and
        back, the post between them too thin for the map): instances each resting on another's top
        within one footprint, whose union stands on the floor, is of a chair's size and has no flat top
        (a back rises over one side of the seat), become one chair. What a class of things that stand
        on others fits (a cup, a monitor, a box on a cabinet) is never a piece, and nothing is
        assembled onto a whole object standing on the floor (a lamp on a cabinet). In place; each
        assembly is noted."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        from stratamap.core.map.instances import instance_members

        if "chair" not in vocab:
            return
        stands_on_others = [name for name in (*ON_SUPPORTS, "monitor", "laptop", "book", "microwave") if name in vocab]
        pieces = {}
        for iid, sel in instance_members(instance_ids).items():
            cls = int(np.bincount(class_ids[sel]).argmax())
            if len(sel) < 4 or not vocab.is_thing[cls]:
                continue
            name = vocab.name(cls)
            shape = describe_shape(points[sel], base_z, walls, sight)
            if name in stands_on_others and fits_class(name, shape):
                continue
            z = points[sel, 2]
            # On the floor and a whole object of its class by itself (a cabinet, a table): what rests on
            # it stands on it.
            whole = name != "object" and shape.bottom <= FLOOR_GAP and fits_class(name, shape)
            xy = points[sel[:: max(1, len(sel) // 2000)], :2]  # top views, thinned for the hulls
            if len(np.unique(xy, axis=0)) >= 3:
                pieces[iid] = _Piece(sel, float(z.min()), float(z.max()), whole, xy, xy.min(axis=0), xy.max(axis=0))
        ids = sorted(pieces)
        edges = []
        for a, upper_id in enumerate(ids):
            for b, lower_id in enumerate(ids):
                upper, lower = pieces[upper_id], pieces[lower_id]
                # ``upper`` rests on ``lower``'s top (a gap of a thin post at most) within its footprint, or
                # over it; a back behind a seat reaches below the seat's top.
                at_seat = SEAT_HEIGHTS[0] <= lower.top - base_z <= SEAT_HEIGHTS[1]
                if a == b or not -(BACK_BELOW_SEAT if at_seat else 0.05) <= upper.bottom - lower.top <= STACK_GAP:
                    continue
                if np.any(upper.lo > lower.hi) or np.any(lower.lo > upper.hi):  # apart in the top view
                    continue
                if max(_share_within(upper.xy, lower.xy), _share_within(lower.xy, upper.xy)) >= 0.5:
                    edges.append((a, b))
        if not edges:
            return
        pairs = np.array(edges)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(ids), len(ids)))
        _, component = connected_components(graph, directed=False)
        groups: dict[int, list[int]] = {}
        for k, iid in enumerate(ids):
            groups.setdefault(int(component[k]), []).append(iid)
        assembled = []
        for group in groups.values():
            if len(group) < 2:
                continue
            sel = np.concatenate([pieces[i].points for i in group])
            shape = describe_shape(points[sel], base_z, walls, sight)
            # Standing on the floor, of a chair's size, its top no flat surface over its footprint (a
            # back rises over one side of the seat). Against a wall or not: chairs stand there too.
            if shape.bottom > FLOOR_GAP or shape.flat_top or not fits_class("chair", shape):
                continue
            # A whole object on the floor carries what rests on it (a lamp on a cabinet), unless it is a
            # seat and the rest its back: its top at sitting height, the rest reaching below that top
            # (behind the seat, not standing on it), and the two seating seen from above (a swivel
            # chair's seat and base that a "table" box named, its back apart).
            wholes = [i for i in group if pieces[i].whole]
            if wholes:
                seat_top = min(pieces[i].top for i in wholes)
                back = all(pieces[i].bottom <= seat_top - 0.05 for i in group if not pieces[i].whole)
                if not (shape.seat and back and seat_top - base_z <= SEAT_HEIGHTS[1]):
                    continue
            keep = max(group, key=lambda i: (len(pieces[i].points), -i))
            instance_ids[sel] = keep
            class_ids[sel] = vocab.id("chair")
            assembled.append({"instance": keep, "pieces": sorted(group)})
            why[keep] = ("shape", f"{len(group)} pieces stacked into a seat with a back, of a chair's size")
        if assembled:
            self.note("chairs_assembled", assembled)

    def _join_seating(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        voxel: float,
        why: dict[int, tuple[str, str]],
    ) -> None:
        """A sofa seen as seats side by side (a detector boxed it as chairs, and the mapper's size
        prior cut the over-long "chair" in two): floor-standing instances voted chair or sofa, or with
        no votes seating seen from above (``seat``), that touch (within two voxels) and together are
        seating too long for one chair that fits a sofa, become one sofa. Two armchairs a hand apart
        touch nowhere. In place; each join is noted."""
        from scipy.spatial import cKDTree

        from stratamap.core.map.instances import instance_members

        if "sofa" not in vocab:
            return
        seats = {}
        for iid, sel in instance_members(instance_ids).items():
            name = vocab.name(int(np.bincount(class_ids[sel]).argmax()))
            if len(sel) < 4 or name not in ("chair", "sofa", "object"):
                continue
            shape = describe_shape(points[sel], base_z, walls, sight)
            # Seating by its votes or, with none, by its shape.
            if shape.bottom <= FLOOR_GAP and not shape.flat_top and (shape.seat or name != "object"):
                seats[iid] = sel

        def sofa_pair() -> tuple[int, int] | None:
            """The ids of two seats that touch and together are a sofa, not a chair; None: no such two."""
            ids = sorted(seats)
            for a, first in enumerate(ids):
                tree = cKDTree(points[seats[first]])
                for second in ids[a + 1 :]:
                    near, _ = tree.query(points[seats[second]], distance_upper_bound=2.0 * voxel)
                    if not np.isfinite(near).any():
                        continue
                    union = np.concatenate([seats[first], seats[second]])
                    shape = describe_shape(points[union], base_z, walls, sight)
                    is_sofa = fits_class("sofa", shape) and not fits_class("chair", shape)
                    if shape.seat and not shape.flat_top and is_sofa:
                        return first, second
            return None

        joined = []
        while (pair := sofa_pair()) is not None:
            first, second = pair
            union = np.concatenate([seats[first], seats.pop(second)])
            instance_ids[union] = first
            class_ids[union] = vocab.id("sofa")
            seats[first] = union
            joined.append({"instance": first, "joined": second})
            why[first] = ("shape", "seating side by side, too long for one chair: a sofa")
        if joined:
            self.note("seating_joined", joined)

    def _join_enclosed(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        support_heights: np.ndarray,
        support_of_point: np.ndarray | None,
        voxel: float,
    ) -> None:
        """A piece lying within a larger floor-standing object's box (ENCLOSED_SHARE of its points, the
        box grown by ENCLOSED_MARGIN_VOXELS) is a part of it: a chair's slat or post, a fridge's handle,
        a worktop's edge that frames boxed on their own. It joins that object, whose class must still
        fit it, unless it is an object of its own there: a small thing standing on a support surface
        (``support_of_point``: the support index of each point, -1 none; a cup on the worktop, or on
        the table a chair is pushed under), or at the height (``support_heights``) of a support surface
        of the object around it; or furniture standing on the floor, whose class its shape fits, within
        anything but seating (a chair under a table or a desk). In place; each join is noted."""
        from scipy.spatial import cKDTree

        from stratamap.core.geometry.boxes import gravity_aligned_box
        from stratamap.core.map.priors import NOT_STACKED, ON_A_SUPPORT

        info = _thing_shapes(points, class_ids, instance_ids, vocab, base_z, walls, sight)
        # Floor-standing objects hold pieces, each as the class it will have: its own where its shape
        # fits it, else the one its shape makes most likely (a unit a detector called a table).
        holders, kind = {}, {}
        for iid, (name, shape, sel) in info.items():
            if shape.bottom <= FLOOR_GAP:
                holders[iid] = gravity_aligned_box(points[sel])
                fits = name != "object" and fits_class(name, shape)
                kind[iid] = name if fits else self._prior(shape, vocab, base_z, np.zeros(0), voxel)[0]
        if not holders:
            return
        tolerance = self._standing_tolerance(voxel)
        on_top = np.flatnonzero(support_of_point >= 0) if support_of_point is not None else np.zeros(0, np.int64)
        surfaces = cKDTree(points[on_top]) if len(on_top) else None
        # A seat's surface holds pieces of its chair far more often than things: it spares none.
        seats = [h for h, k in kind.items() if k in SEATING]
        joined = []
        for iid in sorted(info, key=lambda i: (len(info[i][2]), i)):
            name, shape, sel = info[iid]
            heights = np.zeros(0)
            if surfaces is not None:
                # The support surfaces under the piece's foot (by place, not only by height), its own
                # points left out (a worktop's edge is support surface itself).
                foot = points[sel][points[sel, 2] <= base_z + shape.bottom + voxel]
                near = on_top[sorted({int(j) for hits in surfaces.query_ball_point(foot, tolerance) for j in hits})]
                heights = points[near[(instance_ids[near] != iid) & ~np.isin(instance_ids[near], seats)], 2] - base_z
            # A small thing on a support surface is an object of its own. The surface under a cup is
            # hidden by it, and its edge may be too: at a support's height, a small thing stands on the
            # object around it where that object holds a support surface at that height (a worktop);
            # else it is level with a support elsewhere (a chair's post beside a table's top).
            shelved = self._prior(shape, vocab, base_z, heights + base_z, voxel)[0] in ON_SUPPORTS or (
                name in ON_A_SUPPORT and fits_class(name, shape)
            )
            if shelved and on_a_support(shape.bottom, heights, tolerance):
                continue
            level = shelved and on_a_support(base_z + shape.bottom, support_heights, tolerance)
            furniture = (
                name in NOT_STACKED and fits_class(name, shape) and shape.bottom <= FLOOR_GAP and not _thin(points[sel])
            )
            for holder in sorted(holders, key=lambda i: (-len(info[i][2]), i)):
                h_name, _, h_sel = info[holder]
                if holder == iid or len(h_sel) <= len(sel):
                    continue
                if furniture and kind[holder] not in SEATING:
                    continue
                within = holders[holder].contains(points[sel], ENCLOSED_MARGIN_VOXELS * voxel).mean()
                if within < ENCLOSED_SHARE:
                    continue
                if level and support_of_point is not None and kind[holder] not in SEATING:
                    held = support_of_point[h_sel] >= 0
                    if on_a_support(base_z + shape.bottom, points[h_sel[held], 2], tolerance):
                        continue
                merged = np.concatenate([h_sel, sel])
                if kind[holder] != "object" and not fits_class(
                    kind[holder], describe_shape(points[merged], base_z, walls, sight)
                ):
                    continue
                instance_ids[sel] = holder
                class_ids[sel] = vocab.id(h_name)
                info[holder] = (h_name, info[holder][1], merged)
                holders.pop(iid, None)
                joined.append({"instance": iid, "into": holder, "class": h_name, "was": name})
                break
        if joined:
            self.note("enclosed_joined", joined)

    def _join_parts(
        self,
        points: np.ndarray,
        class_ids: np.ndarray,
        instance_ids: np.ndarray,
        vocab: Vocabulary,
        base_z: float,
        walls: list[Any],
        sight: Sightlines | None,
        support_heights: np.ndarray,
        voxel: float,
    ) -> None:
        """Pieces that are no object by themselves join the floor-standing object (a class of
        NOT_STACKED: chairs, tables, counters) they lie over or under: a swivel chair's base under
        its seat, an armrest over it. A piece is one named ``object`` by the priors, one voted
        the anchor's class that cannot be of it alone (a 20 cm "chair" at seat height), or one that
        nothing of its own holds up (off the floor, off the walls, of no floor-standing class: a
        backrest's top voted "monitor"). In place."""
        from stratamap.core.map.priors import NOT_STACKED, OPEN_BELOW

        if len(np.unique(instance_ids[instance_ids > 0])) < 2:
            return
        info = {
            iid: (name, shape, sel, self._prior(shape, vocab, base_z, support_heights, voxel)[0])
            for iid, (name, shape, sel) in _thing_shapes(
                points, class_ids, instance_ids, vocab, base_z, walls, sight
            ).items()
        }
        # Anchors by the class they will have: the voted one where their size allows it, else the
        # priors' (a counter a detector without a 'counter' label framed as a "box").
        anchor_class, standing_class = {}, {}
        for i, (name, shape, _, alone) in info.items():
            settled = name if name != "object" and fits_class(name, shape) else alone
            if settled != "object" and fits_class(settled, shape) and shape.bottom <= FLOOR_GAP:
                standing_class[i] = settled
            if settled in NOT_STACKED and fits_class(settled, shape):
                anchor_class[i] = settled
        joined = []

        def join(iid: int, anchor: int, name: str, relabel: np.ndarray) -> None:
            instance_ids[info[iid][2]] = anchor
            class_ids[relabel] = vocab.id(name)
            joined.append({"instance": iid, "into": anchor, "class": name})
            anchor_class.pop(iid, None)
            standing_class.pop(iid, None)

        for iid in sorted(info, key=lambda i: len(info[i][2])):
            name, shape, sel, alone = info[iid]
            # A small thing by its size, its foot at the height of a support surface (a mug on a worktop).
            supported = alone in ON_SUPPORTS and on_a_support(base_z + shape.bottom, support_heights, 1.5 * voxel)
            # Held up by nothing of its own: neither floor-standing, nor hung on a wall, nor a small thing
            # named as one on a support, its foot off the floor. Within a floor-standing object it is a
            # piece of it, whatever it was voted (a chair's backrest seen as a "monitor"); on it, it rises
            # above its top.
            floating = (
                name not in NOT_STACKED
                and not shape.against_wall
                and shape.bottom > STANDING_GAP
                and not (supported and name in ON_SUPPORTS)
            )
            # Off the floor and not on a support: within a floor-standing object that reaches lower, it is
            # a piece of that, whatever it was voted (a counter's upper front that a detector called a
            # chair or a monitor; a mug voted "table" on the worktop stays a mug).
            lifted = shape.bottom > FLOOR_GAP and not supported
            if (iid in anchor_class and not lifted) or (
                name != "object" and fits_class(name, shape) and not floating and not lifted
            ):
                continue
            z = points[sel, 2]
            # A piece off the floor lies within any floor-standing object (a sliver of a sideboard's top),
            # other pieces join only objects that stand on no other one (chairs, tables, counters).
            anchors = {**standing_class, **anchor_class} if lifted else anchor_class
            for anchor in sorted(anchors, key=lambda i: -len(info[i][2])):
                a_name, a_sel = anchors[anchor], info[anchor][2]
                if anchor == iid or (not floating and not lifted and alone != "object" and a_name != name):
                    continue
                # A small thing standing at a support's height stands on a table's top, whatever the table's
                # mask made of it: not a piece of the table.
                if supported and a_name in OPEN_BELOW:
                    continue
                # Within the anchor's height or under it: what rises above its top stands on it (a cup on a table).
                az = points[a_sel, 2]
                if z.max() < az.min() - 0.15:
                    continue
                if z.max() > az.max() + 0.05:
                    # Rising above the anchor's top, it stands on it (a cup on a table), unless it is of a
                    # class that stands on no other object, its foot at the anchor's top and the anchor
                    # wholly under it: one object (a chair's back and seat over its seat and legs).
                    if not (
                        lifted
                        and anchor in anchor_class
                        and name in NOT_STACKED
                        and fits_class(name, shape)
                        and z.min() <= az.max() + FLOOR_GAP
                        and _share_within(points[a_sel, :2], points[sel, :2]) >= 0.9
                    ):
                        continue
                    merged = np.concatenate([sel, a_sel])
                    if fits_class(name, describe_shape(points[merged], base_z, walls, sight)):
                        a_name = name
                        anchor_class[anchor] = name
                    join(iid, anchor, a_name, merged)
                    break
                if lifted and not az.min() < z.min() - FLOOR_GAP:
                    # Under a lifted anchor of a class that stands on no other object, its foot on this
                    # piece's top and its footprint over it: one object (a swivel chair's seat under its
                    # back, their post unseen).
                    if (
                        alone == "object"
                        and anchor in anchor_class
                        and a_name in NOT_STACKED
                        and z.max() - 0.05 <= az.min() <= z.max() + FLOOR_GAP
                        and _share_within(points[a_sel, :2], points[sel, :2]) >= 0.5
                        and fits_class(
                            a_name, describe_shape(points[np.concatenate([sel, a_sel])], base_z, walls, sight)
                        )
                    ):
                        join(iid, anchor, a_name, sel)
                        break
                    continue
                inside = _share_within(points[sel, :2], points[a_sel, :2])
                # A lifted piece lies wholly within (a table top beside a chair overlaps its footprint).
                if lifted and inside < 0.9:
                    continue
                # Never into an object its class's size then rules out (a strip of floor clutter under a
                # chair's base would make a 1.4 m "chair").
                if inside >= 0.5 and fits_class(
                    a_name, describe_shape(points[np.concatenate([sel, a_sel])], base_z, walls, sight)
                ):
                    join(iid, anchor, a_name, sel)
                    break
        if joined:
            self.note("parts_joined", joined)

    @staticmethod
    def _on_layout_planes(cells: np.ndarray, obj: np.ndarray, layout: Any, n_obj: int, distance: float) -> np.ndarray:
        """Per object and layout label, how many of its cells lie near a plane of that label."""
        table = np.zeros((n_obj, len(LAYOUT_NAMES)), np.int64)
        member = obj >= 0
        for plane in layout.planes:
            near = member & plane.near(cells, distance)
            table[:, plane.label] += np.bincount(obj[near], minlength=n_obj)
        return table

    @staticmethod
    def _voted_name(
        votes: np.ndarray,
        pts: np.ndarray,
        stuff_ids: np.ndarray,
        vocab: Vocabulary,
    ) -> str | None:
        """The class an object's fused votes give it, if any. Floor, wall or ceiling votes make it that
        stuff where they hold most of its points and it is thin (a floor patch the layout missed); else
        thing votes name it. A thick object whose only votes are the floor its foot stands on (a wardrobe
        in a frame where the detector boxed nothing) is no floor."""
        stuff = np.zeros(len(votes), bool)
        stuff[stuff_ids[stuff_ids > 0]] = True
        if votes[stuff].sum() > 0.5 * len(pts) and _thin(pts):
            return vocab.name(int(np.argmax(np.where(stuff, votes, 0))))
        things = np.where(stuff, 0, votes)
        return vocab.name(int(np.argmax(things))) if things.sum() > 0 else None

    @staticmethod
    def _vote_table(point_obj: np.ndarray, votes: Semantics, n_obj: int, n_classes: int) -> np.ndarray:
        """Per object, how many of its points each class was fused for (unknown left out)."""
        voted = (point_obj >= 0) & (votes.class_ids > 0) & (votes.class_ids < n_classes)
        key = point_obj[voted] * n_classes + votes.class_ids[voted]
        return np.bincount(key, minlength=n_obj * n_classes).reshape(n_obj, n_classes)

    @staticmethod
    def _class_of(
        pts: np.ndarray, top_area: float, base_z: float, vocab: Vocabulary, cfg: ClustersConfig
    ) -> tuple[str, str]:
        """The class clusters' own rules give an object without votes (and why)."""
        if top_area >= cfg.table_min_area and "table" in vocab and vocab.is_thing[vocab.id("table")]:
            return "table", f"a support surface of {top_area:.2f} m^2 on it (table_min_area {cfg.table_min_area:g})"
        extent = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
        top = float(pts[:, 2].max() - base_z)
        for rule in cfg.class_rules:
            if rule.min_extent <= extent <= rule.max_extent and top <= rule.max_height:
                return rule.class_name, (
                    f"extent {extent:.2f} m in {rule.min_extent:g}-{rule.max_extent:g}, top {top:.2f} m "
                    f"<= {rule.max_height:g} (class_rules)"
                )
        fallback = "object" if "object" in vocab else next(vocab.name(i) for i in vocab.thing_ids())
        return fallback, NO_CLASS_RULE_FITS


@hookimpl
def stratamap_register_segmenters():
    return [ClustersSegmenter]
