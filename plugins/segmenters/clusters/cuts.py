"""Constrained planar cuts (after CPC, Schoeler et al. 2015), in the ``segment`` pass: where a segment
holds sharp concave creases between patches, the planes of the faces along them are tried as cuts
through the whole segment; one is made when most patch edges it severs are concave (two boxes'
flush sides)."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.plugins.segmenters.clusters.config import ClustersConfig
from stratamap.plugins.segmenters.clusters.grid import linked
from stratamap.plugins.segmenters.clusters.patches import PatchGraph


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
    return linked(len(labels), edges[same])
