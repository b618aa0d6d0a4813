"""Segmenter ``clusters``: model-free 3D instances from geometry alone (the point-cloud-only case).

1. Dominant planes: iterative RANSAC finds horizontal planes holding a large share of the points
   (the floor, a tabletop) and large vertical ones (walls); their inliers, and what lies below a
   supporting plane, become layout and leave the object search.
2. The rest is split where surfaces meet concavely. Neighbouring points (within ``radius``) stay
   connected when their surfaces are locally convex, ``(n_i - n_j) . (x_i - x_j) >= 0`` for normals
   facing the sensor (a sphere or a box corner), or nearly coplanar; the concave crease where a box
   stands on another, or leans on a wall, cuts the link (the point-level form of locally convex
   connected patches, LCCP). ``method: euclidean`` links every pair within ``radius`` instead.
3. Constrained planar cuts (after CPC, Schoeler et al. 2015): where a segment holds sharp concave
   creases between patches, the planes of the faces along them (the top of a box another box
   stands on) are tried as cuts through the whole segment; one is made when most patch edges it
   severs are concave, which also separates faces the crease alone does not (two boxes' flush
   sides). Curved concave surfaces (a bowl's inside) have no sharp creases and no face to cut along.
4. Connected components with at least ``min_points`` points are instances; their class comes from
   ``class_rules`` (first rule whose size and height ranges fit) or is ``object``.

Works on a voxel-downsampled copy (``voxel_size``) and writes the labels back to every point.
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core import PipelineData, Segmenter, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import ransac_plane, voxel_downsample
from stratamap.core.map.layers import Semantics
from stratamap.core.map.vocabulary import Vocabulary


class ClassRule(BaseModel):
    """Name a cluster by its size: the first rule that fits wins."""

    model_config = ConfigDict(extra="forbid")

    class_name: str = Field(description="Class to give (must be a thing class of the vocabulary).")
    max_extent: float = Field(default=np.inf, gt=0, description="Largest box side, metres.")
    min_extent: float = Field(default=0.0, ge=0, description="Smallest largest-box-side, metres.")
    max_height: float = Field(default=np.inf, description="Highest top above the support, metres.")


class ClustersConfig(StageConfig):
    method: Literal["convex", "euclidean"] = Field(
        default="convex", description="convex: cut concave creases between touching objects; euclidean: distance only."
    )
    voxel_size: float = Field(
        default=0.005, gt=0.0, description="Work on a voxel-downsampled copy with this cell size, metres."
    )
    radius: float = Field(default=0.012, gt=0.0, description="Points closer than this are neighbours, metres.")
    normal_radius: float = Field(default=0.02, gt=0.0, description="Radius of the normal estimate, metres.")
    smooth_deg: float = Field(
        default=12.0,
        ge=0.0,
        le=90.0,
        description="Neighbours whose normals differ by less than this stay linked even when slightly concave.",
    )
    patch_size: float = Field(
        default=0.02, gt=0.0, description="Cell size of the supervoxel patches the convexity test works on, metres."
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
    concavity_tolerance: float = Field(
        default=0.2, ge=0.0, description="Concavity tolerated (noise), as a fraction of the neighbour distance."
    )
    plane_distance: float = Field(
        default=0.01, gt=0.0, description="RANSAC inlier distance of the dominant planes, metres."
    )
    plane_share: float = Field(
        default=0.15, gt=0.0, le=1.0, description="A dominant plane holds at least this share of the points."
    )
    max_planes: int = Field(default=3, ge=0, description="Dominant planes removed at most.")
    min_points: int = Field(default=300, ge=1, description="Smallest instance, in points of the input cloud.")
    cut_min_links: int = Field(
        default=5,
        ge=0,
        description="Concave patch edges (creases) a segment needs before planar cuts are tried (0: no cuts).",
    )
    cut_concave_share: float = Field(
        default=0.5,
        ge=0.0,
        le=1.0,
        description="Share of the patch edges a cut severs that must be concave for the cut to be made.",
    )
    cut_distance: float = Field(
        default=0.015,
        gt=0.0,
        description="Crease edges (patch centroid midpoints) this close to a candidate plane support it, metres.",
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
        default_factory=list, description="Size rules naming clusters; unmatched clusters are `object`."
    )


def estimate_normals(points: np.ndarray, radius: float, viewpoint: np.ndarray) -> np.ndarray:
    """PCA normals within ``radius`` (Open3D), turned to face ``viewpoint``."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
    normals = np.asarray(cloud.normals)
    flip = np.einsum("ij,ij->i", normals, viewpoint - points) < 0
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


def patch_graph(points: np.ndarray, normals: np.ndarray, pairs: np.ndarray, cfg: ClustersConfig) -> PatchGraph:
    """Smooth patches inside coarse cells, and which adjacent patches meet convexly. A patch pair's
    boundary is convex when the patches' mean normals and centroids say so and most point links
    across it agree; one noisy link cannot join two objects."""
    cell = np.floor(points / cfg.patch_size).astype(np.int64)
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
    link_ok = convex_links(points, normals, pairs[between], cfg.smooth_deg, cfg.concavity_tolerance)
    lo, hi = np.minimum(a[between], b[between]), np.maximum(a[between], b[between])
    key = lo * n_patch + hi
    keys, inverse = np.unique(key, return_inverse=True)
    votes = np.bincount(inverse, weights=link_ok.astype(float)) / np.bincount(inverse)
    pa, pb = keys // n_patch, keys % n_patch
    diff = centroid[pa] - centroid[pb]
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
    convex = np.einsum("ij,ij->i", normal[pa] - normal[pb], diff) >= -cfg.concavity_tolerance * dist
    flat = np.einsum("ij,ij->i", normal[pa], normal[pb]) >= np.cos(np.radians(cfg.smooth_deg))
    return PatchGraph(
        patch, centroid, normal, count, np.stack([pa, pb], 1), (convex | flat) & (votes >= cfg.convex_votes)
    )


def convex_segments(graph: PatchGraph) -> np.ndarray:
    """LCCP: patches merged across convex boundaries; a segment id per patch."""
    return _components(len(graph.centroid), graph.edges[graph.convex])


def _cut_side(
    graph: PatchGraph, members: np.ndarray, n: np.ndarray, p0: np.ndarray, cfg: ClustersConfig
) -> np.ndarray | None:
    """Which of a segment's patches lie beyond the face plane (n, p0), the plane first refit to
    the face; None when the plane follows no real face or leaves one side empty."""
    centroid, normal = graph.centroid, graph.normal
    cos_par, cos_crease = np.cos(np.radians(cfg.smooth_deg)), np.cos(np.radians(cfg.cut_crease_deg))
    # A crease patch's normal is bent by its neighbour across the crease: refit the plane to the
    # face's patches (near it, facing its way), twice.
    for tolerance in (2 * cfg.cut_distance, cfg.cut_distance):
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
    on_face = (np.abs(offset) <= cfg.cut_distance) & (normal[members] @ n >= cos_crease)
    side = (offset > 0) & ~on_face
    # A cut follows a real face (the top a box stands on), not a curved surface's tangent plane
    # (a bowl's concave inside).
    if side.all() or not side.any() or on_face.sum() < cfg.cut_face_patches:
        return None
    return side


def planar_cuts(graph: PatchGraph, segments: np.ndarray, cfg: ClustersConfig) -> np.ndarray:
    """Split segments along planes through their concave creases (CPC's idea, simplified).

    Candidate planes: for every concave edge inside a segment, the plane of each of its two
    patches. A candidate's support is the concave edges lying on it (midpoint within
    ``cut_distance``) with one patch facing its way. The best supported plane cuts the segment
    when at least ``cut_concave_share`` of the patch edges it severs are concave: a box's own
    faces meet at convex edges, so a plane through its top severs convex edges only. Patches on
    the plane facing its way are the face itself and stay with the solid behind it. Returns a
    segment id per patch."""
    centroid, normal, edges, convex = graph.centroid, graph.normal, graph.edges, graph.convex
    labels = segments.copy()
    next_label = int(labels.max()) + 1 if len(labels) else 0
    cos_par, cos_crease = np.cos(np.radians(cfg.smooth_deg)), np.cos(np.radians(cfg.cut_crease_deg))
    for _ in range(cfg.cut_depth):
        changed = False
        same = labels[edges[:, 0]] == labels[edges[:, 1]]
        for seg in np.unique(labels[edges[same & ~convex, 0]]):
            inside = same & (labels[edges[:, 0]] == seg)
            ca, cb = edges[inside & ~convex, 0], edges[inside & ~convex, 1]
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
                near = np.abs(n @ mid.T - np.einsum("ij,ij->i", n, p)[:, None]) <= cfg.cut_distance
                aligned = (np.abs(n @ normal[ca].T) >= cos_par) | (np.abs(n @ normal[cb].T) >= cos_par)
                score[start : start + 256] = (near & aligned).sum(1)
            members = np.flatnonzero(labels == seg)
            side_of = np.zeros(len(labels), bool)
            chosen, chosen_share = None, cfg.cut_concave_share
            # The best supported planes, each tried; the one severing the most concave share wins.
            tried: list[tuple[np.ndarray, float]] = []
            for best in np.argsort(-score, kind="stable"):
                if len(tried) >= cfg.cut_candidates or score[best] == 0:
                    break
                n, p0 = cand_n[best], cand_p[best]
                # Distinct planes only: the support of one crease repeats the same plane many times.
                if any(abs(n @ m) >= cos_par and abs(n @ p0 - d) <= cfg.cut_distance for m, d in tried):
                    continue
                tried.append((n, float(n @ p0)))
                side = _cut_side(graph, members, n, p0, cfg)
                if side is None:
                    continue
                side_of[:] = False
                side_of[members] = side
                crossing = inside & (side_of[edges[:, 0]] != side_of[edges[:, 1]])
                share = (crossing & ~convex).sum() / max(crossing.sum(), 1)
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


class ClustersSegmenter(Segmenter[ClustersConfig]):
    """Model-free instances: dominant planes removed, then convexity-aware (or Euclidean) clustering."""

    name = "clusters"
    Config = ClustersConfig
    requires = frozenset({"geometry"})
    provides = frozenset({"semantics", "instances"})

    @classmethod
    def example_params(cls) -> dict:
        return {"min_points": 20, "voxel_size": 0.01, "radius": 0.025, "normal_radius": 0.04}

    def segment(self, data: PipelineData) -> dict[str, Any]:
        from scipy.spatial import cKDTree

        from stratamap.core.map.instances import instances_from_semantics

        cfg = self.config
        geometry = data.map.geometry
        if geometry is None or len(geometry.points) == 0:
            raise DataError("clusters: the geometry layer has no points")
        vocab = data.map.vocabulary or (
            data.ground_truth.vocabulary if data.ground_truth is not None else Vocabulary.default()
        )
        for rule in cfg.class_rules:
            if rule.class_name not in vocab or not vocab.is_thing[vocab.id(rule.class_name)]:
                raise DataError(
                    f"clusters: class_rules names {rule.class_name!r}, which is not a thing class of the vocabulary"
                )
        points = geometry.points
        cells, cell_of_point = voxel_downsample(points, cfg.voxel_size)
        weight = np.bincount(cell_of_point, minlength=len(cells))
        stream = data.stream
        transform = np.asarray((stream.metadata.get("world_transform") if stream is not None else None) or np.eye(4))
        viewpoint = (
            transform[:3, 3] if stream is not None and stream.points is not None else cells.mean(axis=0) + [0, 0, 2.0]
        )

        # 1. Dominant planes.
        layout = np.zeros(len(cells), np.int32)  # class id of layout cells, 0 = still free
        free = np.ones(len(cells), bool)
        for k in range(cfg.max_planes):
            idx = np.flatnonzero(free)
            if len(idx) < 3:
                break
            normal, d, inliers = ransac_plane(cells[idx], cfg.plane_distance, iterations=300, seed=k)
            if weight[idx[inliers]].sum() < cfg.plane_share * len(points):
                break
            horizontal = abs(normal[2]) >= 0.9
            name = "table" if horizontal else "wall"
            if name not in vocab:
                name = "floor" if horizontal else "wall"
            layout[idx[inliers]] = vocab.id(name) if name in vocab else 0
            free[idx[inliers]] = False
            if horizontal:  # what lies below a support plane is not on it
                height = cells @ (normal if normal[2] > 0 else -normal) + (d if normal[2] > 0 else -d)
                below = free & (height < -cfg.plane_distance)
                layout[below] = layout[idx[inliers][0]]
                free[below] = False
        # 2. Clustering of the rest.
        idx = np.flatnonzero(free)
        labels = np.full(len(cells), -1, np.int64)
        if len(idx):
            sub = cells[idx]
            pairs = cKDTree(sub).query_pairs(cfg.radius, output_type="ndarray")
            if cfg.method == "convex" and len(pairs):
                graph = patch_graph(sub, estimate_normals(sub, cfg.normal_radius, viewpoint), pairs, cfg)
                comp = convex_segments(graph)
                if cfg.cut_min_links > 0:
                    comp = planar_cuts(graph, comp, cfg)
                comp = comp[graph.patch]
            else:
                comp = _components(len(sub), pairs)
            labels[idx] = comp
        # 3. Instances: big enough components, numbered by size (deterministic), named by rules.
        point_label = labels[cell_of_point]
        comp_ids, comp_sizes = np.unique(point_label[point_label >= 0], return_counts=True)
        order = np.lexsort((comp_ids, -comp_sizes))
        class_ids = layout[cell_of_point].astype(np.int32)
        instance_ids = np.zeros(len(points), np.int32)
        next_id = 1
        if (class_ids > 0).any():
            for cid in np.unique(class_ids[class_ids > 0]):
                if vocab.is_thing[int(cid)]:
                    instance_ids[class_ids == cid] = next_id
                    next_id += 1
        support_z = (
            float(np.percentile(points[class_ids > 0, 2], 90)) if (class_ids > 0).any() else float(points[:, 2].min())
        )
        kept = 0
        for k in order:
            if comp_sizes[k] < cfg.min_points:
                break
            mask = point_label == comp_ids[k]
            class_ids[mask] = vocab.id(self._class_of(points[mask], support_z, cfg))
            instance_ids[mask] = next_id
            next_id += 1
            kept += 1
        self.note(
            "segments",
            {"planes": int(len(np.unique(layout[layout > 0]))), "clusters": int(len(comp_ids)), "instances": kept},
        )
        semantics = Semantics(class_ids, instance_ids, vocab)
        return {"semantics": semantics, "instances": instances_from_semantics(points, geometry.colors, semantics, 1)}

    @staticmethod
    def _class_of(pts: np.ndarray, support_z: float, cfg: ClustersConfig) -> str:
        extent = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
        top = float(pts[:, 2].max() - support_z)
        for rule in cfg.class_rules:
            if rule.min_extent <= extent <= rule.max_extent and top <= rule.max_height:
                return rule.class_name
        return "object"


@hookimpl
def stratamap_register_segmenters():
    return [ClustersSegmenter]
