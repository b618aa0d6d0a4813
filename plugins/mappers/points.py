"""Mapper ``points``: a static point cloud (or accumulated LiDAR sweeps) as the geometry layer."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from pydantic import Field

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import FAR_FROM_BULK, far_from_bulk
from stratamap.core.geometry.transforms import apply
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import Geometry
from stratamap.core.map.sensors import LidarScan

o3d = lazy_module("open3d")


class PointsConfig(StageConfig):
    voxel_size: float = Field(
        default=0.0,
        ge=0.0,
        description="Voxel-grid downsampling, metres (0 keeps every point, so per-point labels stay aligned).",
    )
    normals_radius: float = Field(
        default=0.03, ge=0.0, description="Radius for normal estimation, metres (0: no normals)."
    )


class PointsMapper(Mapper[PointsConfig]):
    """Static clouds or LiDAR sweeps (posed) into the geometry layer, with normals."""

    name = "points"
    Config = PointsConfig
    requires = frozenset({"frames"})
    provides = frozenset({"geometry"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        stream = data.stream
        assert stream is not None
        colors = stream.point_colors
        from_sweeps, strays = False, 0
        if stream.points is not None and len(stream.points):
            pts = np.asarray(stream.points, dtype=np.float64)
        elif stream.lidar_scans:
            missing = [k for k, s in enumerate(stream.lidar_scans) if s.pose is None]
            if missing:
                raise DataError(f"points: {len(missing)} LiDAR sweeps have no pose; enable odometry")
            pts, strays = self._accumulate(stream.lidar_scans)
            colors, from_sweeps = None, True
        else:
            raise DataError(
                f"points: the stream {stream.name!r} has neither a point cloud nor LiDAR sweeps (use tsdf for RGB-D)"
            )
        if cfg.voxel_size > 0 or from_sweeps:
            # Every point of a cloud kept (voxel_size 0) stays aligned with the stream's per-point labels; else
            # one stray return at 1e9 m would stretch the voxel grid past what Open3D indexes.
            far = far_from_bulk(pts)
            strays += int(far.sum())
            pts, colors = pts[~far], None if colors is None else np.asarray(colors)[~far]
        if strays:
            self.warn(
                f"points: {strays} points lie far from the rest (more than {FAR_FROM_BULK:g} times the extent of "
                "their bulk outside it, or not finite): left out of the geometry"
            )
        if cfg.voxel_size > 0 and len(pts):
            span = float(np.max(pts.max(0) - pts.min(0)))
            if span / cfg.voxel_size > MAX_VOXELS_PER_AXIS:
                raise DataError(
                    f"points: the map spans {span:.3g} m, more than {MAX_VOXELS_PER_AXIS:.0e} voxels of voxel_size "
                    f"{cfg.voxel_size:g} m: set a larger stages' points voxel_size"
                )
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        del pts  # the cloud holds its own copy
        if colors is not None:
            pcd.colors = o3d.utility.Vector3dVector(np.asarray(colors, dtype=np.float64))
        if cfg.voxel_size > 0:
            pcd = pcd.voxel_down_sample(cfg.voxel_size)
        normals = None
        if cfg.normals_radius > 0:
            pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=cfg.normals_radius, max_nn=30))
            pcd.orient_normals_to_align_with_direction(np.array([0.0, 0.0, 1.0]))
            normals = np.asarray(pcd.normals)
        out_colors = np.asarray(pcd.colors) if pcd.has_colors() else None
        return {
            "geometry": Geometry(
                points=np.asarray(pcd.points), colors=out_colors, normals=normals, voxel_size=cfg.voxel_size or None
            )
        }

    def _accumulate(self, sweeps: Sequence[LidarScan]) -> tuple[np.ndarray, int]:
        """The sweeps in the world frame, one after another, and how many of their points lay far from the
        rest of their sweep (:func:`far_from_bulk`), left out. With a voxel size, the pile is thinned to
        one point per voxel whenever it passes ``COMPACT_POINTS``, so a long recording costs the memory
        of the map rather than of every return (an hour of a 64-beam LiDAR: 3.6 billion points, 86 GB);
        below that the result is the same as thinning once at the end."""
        piles: list[np.ndarray] = []
        held, limit, strays = 0, COMPACT_POINTS, 0
        for scan in sweeps:
            world = apply(scan.pose, scan.points)
            far = far_from_bulk(world)
            strays += int(far.sum())
            piles.append(world[~far])
            held += len(piles[-1])
            if self.config.voxel_size > 0 and held > limit:
                pile = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.vstack(piles)))
                piles = [np.asarray(pile.voxel_down_sample(self.config.voxel_size).points)]
                held = len(piles[0])
                limit = max(COMPACT_POINTS, 2 * held)  # a map larger than the limit is not thinned every sweep
        return (np.vstack(piles) if piles else np.zeros((0, 3))), strays


#: Open3D indexes voxels by 32-bit integers ("voxel_size is too small" past 2.1e9 along an axis).
MAX_VOXELS_PER_AXIS = 2e9
#: Accumulated LiDAR points above which a voxel-thinned map is thinned as it grows (240 MB of points).
COMPACT_POINTS = 10_000_000


@hookimpl
def stratamap_register_mappers():
    return [PointsMapper]
