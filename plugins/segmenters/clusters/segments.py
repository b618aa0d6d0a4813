"""Pass ``segment``: convexity-aware clustering of the cells that are neither stuff nor support
surface (``method: convex``: neighbouring cells stay linked where their surfaces are locally convex
or nearly coplanar, LCCP on supervoxel-like patches, then planar cuts; ``method: euclidean``: every
pair within the radius), and lines of cells joined to their neighbours."""

from __future__ import annotations

import numpy as np

from stratamap.plugins.segmenters.clusters.cuts import planar_cuts
from stratamap.plugins.segmenters.clusters.grid import estimate_normals, linked
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import NONE
from stratamap.plugins.segmenters.clusters.patches import convex_segments, patch_graph

#: Concavity tolerated by default, as a fraction of the neighbour distance: a raw cloud's (set on
#: mOSD/learn) and a voxel map's (set on held-out fused maps: normals over few coarse voxels bend).
CLOUD_CONCAVITY = 0.2
MAP_CONCAVITY = 0.4


def segment_free(lab: Labelling) -> None:
    """Sets ``segment``: a segment id per free cell, -1 for stuff and support surfaces."""
    cfg, cells, voxel = lab.cfg, lab.cells, lab.voxel
    free = np.flatnonzero((lab.layout.labels == NONE) & (lab.supports.of_cell < 0))
    segment = np.full(len(cells), -1, np.int64)
    if len(free):
        local = np.full(len(cells), -1, np.int64)
        local[free] = np.arange(len(free))
        free_pairs = local[lab.pairs]
        free_pairs = free_pairs[(free_pairs >= 0).all(axis=1)]
        if cfg.method == "convex" and len(free_pairs):
            # Normals again without the layout and support cells: a table top no longer bends the
            # normals at the foot of what stands on it.
            free_normals = estimate_normals(cells[free], cfg.normal_radius_voxels * voxel, lab.views)
            tolerance = cfg.concavity_tolerance
            if tolerance is None:
                tolerance = MAP_CONCAVITY if lab.voxel_map else CLOUD_CONCAVITY
            cut_tolerance = tolerance if cfg.cut_concavity_tolerance is None else cfg.cut_concavity_tolerance
            graph = patch_graph(
                cells[free], free_normals, free_pairs, cfg, cfg.patch_voxels * voxel, tolerance, cut_tolerance
            )
            comp = convex_segments(graph)
            if cfg.cut_min_links > 0:
                comp = planar_cuts(graph, comp, cfg, cfg.cut_distance_voxels * voxel)
            comp = comp[graph.patch]
        else:
            comp = linked(len(free), free_pairs)
        segment[free] = absorb_lines(cells[free], comp, free_pairs, voxel)
    lab.segment = segment


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
