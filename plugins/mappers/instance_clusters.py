"""Mapper ``instance_clusters``: instance post-processing of the augmented-representations paper.

1. Split each *thing* class's points into objects by Euclidean clustering, or by difference of
   normals (DoN: points whose normals at a small and a large scale disagree lie on edges between
   touching objects; removing them before clustering separates the objects).
2. Shape filter: reject clusters that are planar (smallest covariance eigenvalue near zero
   relative to the largest: label bleeding onto walls and floors) and clusters whose extent
   (farthest point from the centroid) is outside the class's range.

Semantics with instance ids (e.g. from the panoptic ``tsdf``) are only filtered unless
``recluster: always``; class-only semantics (``semantic_tsdf``) are clustered.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.lazy import lazy_module
from stratamap.core.map.instances import instance_members, instances_from_semantics
from stratamap.core.map.layers import Semantics
from stratamap.core.map.priors import class_extents

o3d = lazy_module("open3d")


class InstanceClustersConfig(StageConfig):
    method: Literal["euclidean", "don"] = Field(
        default="euclidean", description="Euclidean clustering, or difference of normals before it."
    )
    recluster: Literal["auto", "always", "never"] = Field(
        default="auto",
        description="auto: cluster only classes whose points carry no instance ids; always: recluster everything.",
    )
    tolerance: float = Field(default=0.05, gt=0.0, description="Euclidean clustering distance, metres (DBSCAN radius).")
    min_points: int = Field(default=50, ge=1, description="Clusters with fewer points are dropped.")
    don_radii: tuple[float, float] = Field(
        default=(0.02, 0.08), description="Small and large normal radii of DoN, metres."
    )
    don_threshold: float = Field(
        default=0.25, gt=0.0, le=2.0, description="Points with |n_small - n_large| above this are boundaries (DoN)."
    )
    shape_filter: bool = Field(
        default=True, description="Reject planar clusters and clusters outside the class's extent range."
    )
    planarity: float = Field(
        default=0.002, ge=0.0, description="Planar when the smallest/largest covariance eigenvalue ratio is below this."
    )
    extents: dict[str, tuple[float, float]] = Field(
        default_factory=class_extents, description="Per class (min, max) extent, metres."
    )


def planar(points: np.ndarray, ratio: float) -> bool:
    if len(points) < 4:
        return True
    ev = np.linalg.eigvalsh(np.cov((points - points.mean(0)).T))
    return bool(ev[0] <= ratio * max(ev[-1], 1e-12))


def extent(points: np.ndarray) -> float:
    return float(np.linalg.norm(points - points.mean(0), axis=1).max())


class InstanceClustersMapper(Mapper[InstanceClustersConfig]):
    """Splits thing classes into objects (Euclidean or DoN clustering) and applies the shape filter."""

    name = "instance_clusters"
    Config = InstanceClustersConfig
    requires = frozenset({"geometry", "semantics"})
    provides = frozenset({"semantics", "instances"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        geom, sem = data.map.geometry, data.map.semantics
        assert geom is not None and sem is not None
        pts = geom.points
        cls = sem.class_ids.copy()
        inst = sem.instance_ids.copy()
        vocab = sem.vocabulary
        next_id = int(inst.max(initial=0)) + 1
        rejected: dict[str, int] = {}
        for c in np.unique(cls):
            if c <= 0 or not vocab.is_thing[c]:
                continue
            sel = np.flatnonzero(cls == c)
            has_ids = (inst[sel] > 0).mean() > 0.5
            if cfg.recluster == "always" or (cfg.recluster == "auto" and not has_ids):
                inst[sel] = 0
                for group in self._cluster(pts[sel], cfg):
                    inst[sel[group]] = next_id
                    next_id += 1
                noise = sel[inst[sel] == 0]
                cls[noise] = 0  # in no cluster: belongs to no object of this class
        name_of = vocab.names
        for sel in instance_members(inst).values():
            c = int(np.bincount(cls[sel]).argmax())
            reason = None
            if len(sel) < cfg.min_points:
                reason = "too few points"
            elif cfg.shape_filter:
                if planar(pts[sel], cfg.planarity):
                    reason = "planar"
                elif name_of[c] in cfg.extents:
                    lo, hi = cfg.extents[name_of[c]]
                    if not lo <= extent(pts[sel]) <= hi:
                        reason = "extent"
            if reason:
                inst[sel] = 0
                cls[sel] = 0
                rejected[reason] = rejected.get(reason, 0) + 1
        self.note("rejected", rejected)
        semantics = Semantics(cls, inst, vocab)
        return {
            "semantics": semantics,
            "instances": instances_from_semantics(
                pts, geom.colors, semantics, cfg.min_points, naming=("labels", "the map's labels, clustered")
            ),
        }

    @staticmethod
    def _cluster(points: np.ndarray, cfg: InstanceClustersConfig) -> list[np.ndarray]:
        if len(points) < cfg.min_points:
            return []
        keep = np.arange(len(points))
        if cfg.method == "don":
            small, large = cfg.don_radii
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(small))
            pc.orient_normals_to_align_with_direction([0, 0, 1.0])
            n_small = np.asarray(pc.normals).copy()
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(large))
            pc.orient_normals_to_align_with_direction([0, 0, 1.0])
            don = np.linalg.norm(n_small - np.asarray(pc.normals), axis=1) / 2
            keep = np.flatnonzero(don < cfg.don_threshold)
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[keep]))
        labels = np.asarray(pc.cluster_dbscan(eps=cfg.tolerance, min_points=3))
        groups = [keep[labels == k] for k in range(labels.max() + 1 if len(labels) else 0)]
        if cfg.method == "don" and groups:
            # Boundary points go back to the nearest cluster.
            from scipy.spatial import cKDTree

            owner = np.full(len(points), -1)
            for k, g in enumerate(groups):
                owner[g] = k
            rest = np.flatnonzero(owner < 0)
            if len(rest):
                tree = cKDTree(points[owner >= 0])
                _, nn = tree.query(points[rest])
                owner[rest] = owner[np.flatnonzero(owner >= 0)[nn]]
            groups = [np.flatnonzero(owner == k) for k in range(len(groups))]
        return [g for g in groups if len(g) >= cfg.min_points]


@hookimpl
def stratamap_register_mappers():
    return [InstanceClustersMapper]
