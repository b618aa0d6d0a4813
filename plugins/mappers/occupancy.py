"""Mapper ``occupancy``: the 2D layers a navigation stack uses.

* ``slam`` -- the laser map. With 2D laser scans: log-odds occupancy by ray casting every beam
  (cells along the beam become freer, the end cell more occupied), as a laser SLAM back end
  builds it. With posed 3D LiDAR sweeps: the same from planar scans of the obstacle band, as ROS's
  pointcloud_to_laserscan makes them (``lidar_planar_scans``). Without either: geometry in a thin
  slice at ``laser_height`` (what a laser would see).
* ``objects`` -- every obstacle in the band [``z_min``, ``robot_height``] projected to the floor:
  from the 3D geometry, or from the object instances (their completions when present). When a
  completer ran before, the geometry is the augmented scene (augmented-representations paper,
  section V-C): observed points within ``epsilon`` of a completed model give way to the model's
  surface, taken from the objects as they stand now (after any physical check), so a completed
  chair's unseen seat and legs are obstacles.
* ``multimap`` -- the two overlaid (first paper, section V-C): occupied where either is, free where
  the laser saw free space and no object stands. A robot planning on it keeps off chair seats and
  tabletops that its laser passes under.

Values follow ``nav_msgs/OccupancyGrid``: -1 unknown, 0 free ... 100 occupied.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import Field, model_validator

from stratamap.core import Mapper, PipelineData, StageConfig, hookimpl
from stratamap.core.errors import DataError
from stratamap.core.geometry.points import FAR_FROM_BULK, far_from_bulk, unit_hint
from stratamap.core.geometry.transforms import apply
from stratamap.core.io.nav2 import FREE_THRESH, OCCUPIED_THRESH
from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import OccupancyGrid, OccupancyMaps
from stratamap.core.map.sensors import LaserScan, LidarScan, SensorStream
from stratamap.plugins.mappers._floor import floor_height

o3d = lazy_module("open3d")
o3c = lazy_module("open3d.core")


class OccupancyConfig(StageConfig):
    resolution: float = Field(default=0.05, gt=0.005, le=1.0, description="Cell size, metres (Nav2's default is 0.05).")
    z_min: float = Field(default=0.1, ge=0.0, description="Lower edge of the obstacle band, metres above the floor.")
    robot_height: float = Field(
        default=1.0, gt=0.0, description="Upper edge of the obstacle band: the robot's height, metres."
    )
    laser_height: float = Field(
        default=0.25, gt=0.0, description="Height of the planar laser (used when there are no scans), metres."
    )
    laser_slice: float = Field(default=0.04, gt=0.0, description="Thickness of the slice around laser_height, metres.")
    objects_from: Literal["geometry", "instances"] = Field(
        default="geometry",
        description="Project the band from the 3D geometry, or from object instances (completions when present).",
    )
    log_odds_hit: float = Field(
        default=0.85, gt=0.0, description="Log-odds added to a cell where a beam ends (p = 0.7)."
    )
    log_odds_miss: float = Field(
        default=-0.4, lt=0.0, description="Log-odds added to cells a beam passes through (p = 0.4)."
    )
    log_odds_clamp: tuple[float, float] = Field(
        default=(-2.0, 3.5), description="Clamping bounds of the log-odds, so cells can change again."
    )
    max_free_range: float = Field(
        default=6.0, gt=0.0, description="Beams without a return clear cells up to this range, metres."
    )
    floor_tolerance: float = Field(
        default=0.05, gt=0.0, description="Geometry this close to the floor is floor (free space), metres."
    )
    min_points_per_cell: int = Field(
        default=2, ge=1, description="A cell is occupied when at least this many geometry points fall in it."
    )
    margin: float = Field(default=0.5, ge=0.0, description="Border of unknown cells around the mapped area, metres.")
    epsilon: float = Field(
        default=0.1,
        gt=0.0,
        description=(
            "With completed objects, the band comes from the augmented scene: observed points this close to a "
            "completed model are replaced by the model's surface, metres (the completers' epsilon)."
        ),
    )

    @model_validator(mode="after")
    def _band(self) -> OccupancyConfig:
        if self.z_min >= self.robot_height:
            raise ValueError(f"z_min ({self.z_min}) must be below robot_height ({self.robot_height})")
        return self


#: Horizontal beams of a planar scan made from a LiDAR sweep (0.25 degrees apart, as a 2D laser's).
LIDAR_BEAMS = 1440
#: Returns nearer than this to the LiDAR are the robot carrying it, metres (KISS-ICP's min_range here).
LIDAR_MIN_RANGE = 0.3
#: A sweep starts a new place once the sensor moved this far (metres) or turned this much (radians)
#: since the last place began, as a SLAM back end keeps keyframes: sweeps at 10 Hz repeat each other.
LIDAR_KEYFRAME_TRAVEL, LIDAR_KEYFRAME_TURN = 0.2, np.radians(10.0)


def sweeps_per_place(cfg: OccupancyConfig) -> int:
    """How many sweeps of one place become planar scans: one more than the misses that take a cell from
    unknown to free (``log_odds_miss`` against Nav2's free threshold: 4 at the defaults), since one look
    makes no cell free: a sensor standing still, or moving less than a keyframe's travel per sweep, would
    otherwise leave a map with no free cell."""
    free = np.log(FREE_THRESH / (1.0 - FREE_THRESH))
    return int(np.ceil(free / cfg.log_odds_miss)) + 1


def lidar_planar_scans(
    sweeps: Sequence[LidarScan], floor_z: float, cfg: OccupancyConfig, keyframes: bool = True
) -> tuple[list[LaserScan], list[np.ndarray]]:
    """3D LiDAR sweeps as planar laser scans, as ROS's pointcloud_to_laserscan makes them for a 2D
    SLAM back end: each beam's range is its nearest return within the obstacle band (``z_min`` to
    ``robot_height`` above the floor); a beam with none there clears cells as far as its farthest
    return on the floor (``floor_tolerance``), which a 2D laser could not see. With ``keyframes``, the
    first :func:`sweeps_per_place` sweeps of each place (a new one once the sensor moved or turned
    ``LIDAR_KEYFRAME_*``), so a long stay costs no more than a pass; without (a static scan's stations,
    each a view of its own), every one. Returns the scans, posed at the sensor with a level x axis, and
    each one's per-beam reach for beams without a return."""
    scans: list[LaserScan] = []
    reaches: list[np.ndarray] = []
    increment = 2 * np.pi / LIDAR_BEAMS
    last: np.ndarray | None = None
    per_place, taken = sweeps_per_place(cfg), 0
    for sweep in sweeps:
        pose = np.asarray(sweep.pose)
        if keyframes and last is not None:
            moved = np.linalg.norm(pose[:2, 3] - last[:2, 3])
            turned = abs(np.arctan2(pose[1, 0], pose[0, 0]) - np.arctan2(last[1, 0], last[0, 0]))
            if moved < LIDAR_KEYFRAME_TRAVEL and min(turned, 2 * np.pi - turned) < LIDAR_KEYFRAME_TURN:
                if taken >= per_place:
                    continue
                taken += 1
            else:
                last, taken = pose, 1
        else:
            last, taken = pose, 1
        world = apply(pose, np.asarray(sweep.points))
        offset = world[:, :2] - pose[:2, 3]
        distance = np.hypot(offset[:, 0], offset[:, 1])
        beam = np.floor((np.arctan2(offset[:, 1], offset[:, 0]) + np.pi) / increment).astype(np.int64) % LIDAR_BEAMS
        height = world[:, 2] - floor_z
        far = distance >= LIDAR_MIN_RANGE
        band = far & (height >= cfg.z_min) & (height <= cfg.robot_height)
        floor = far & (np.abs(height) <= cfg.floor_tolerance)
        ranges = np.full(LIDAR_BEAMS, np.inf)
        np.minimum.at(ranges, beam[band], distance[band])
        reach = np.zeros(LIDAR_BEAMS)
        np.maximum.at(reach, beam[floor], distance[floor])
        level = np.eye(4)
        level[:3, 3] = pose[:3, 3]
        scans.append(LaserScan(sweep.timestamp, -np.pi + increment / 2, increment, ranges, np.inf, level))
        reaches.append(reach)
    return scans, reaches


def flat_cells(xy: np.ndarray, origin: np.ndarray, shape: tuple[int, int], resolution: float) -> np.ndarray:
    """Flat indices (row * columns + column) of the grid cells holding ``xy``; points off the grid are left
    out before they are flattened (a row past the grid would wrap into another)."""
    rc = np.floor((xy[:, [1, 0]] - origin[[1, 0]]) / resolution)
    on = (rc[:, 0] >= 0) & (rc[:, 0] < shape[0]) & (rc[:, 1] >= 0) & (rc[:, 1] < shape[1])
    rc = rc[on].astype(np.int64)
    return rc[:, 0] * shape[1] + rc[:, 1]


class _Station(NamedTuple):
    """A static scan's points seen from one scanner station, as a LiDAR sweep: in a level frame at the
    station (``points``), placed by ``pose``."""

    timestamp: float
    points: np.ndarray
    pose: np.ndarray


def scanner_stations(stream: SensorStream | None) -> list[_Station]:
    """A static cloud's stations (a scanner file's positions and which of them saw each point), each
    with the points it saw; none unless the file said both."""
    if stream is None or stream.points is None or stream.point_sensor_ids is None:
        return []
    positions = np.asarray(stream.metadata.get("sensor_positions") or [], float).reshape(-1, 3)
    ids = np.asarray(stream.point_sensor_ids)
    points = np.asarray(stream.points)
    stations = []
    for k, position in enumerate(positions):
        mine = ids == k
        if mine.any():
            pose = np.eye(4)
            pose[:3, 3] = position
            stations.append(_Station(float(k), points[mine] - position, pose))
    return stations


#: The most cells a layer may hold: a 500 x 500 m floor at 5 cm, about 0.8 GB per layer of counts.
#: A room scanned in millimetres and read as metres spans kilometres (65 GB of counts): past it, the
#: error names the units only where the geometry's bulk says so (:func:`unit_hint`).
MAX_CELLS = 100_000_000


class OccupancyMapper(Mapper[OccupancyConfig]):
    """2D occupancy: laser log-odds (or a laser-height slice), the object band, and the multimap."""

    name = "occupancy"
    Config = OccupancyConfig
    requires = frozenset({"frames"})
    optional = frozenset({"geometry", "semantics", "instances"})
    provides = frozenset({"occupancy"})

    def map(self, data: PipelineData) -> dict[str, Any]:
        cfg = self.config
        stream = data.stream
        scans = [s for s in (stream.laser_scans if stream is not None else []) if s.pose is not None]
        geom = data.map.geometry
        if not scans and (geom is None or len(geom) == 0):
            raise DataError("occupancy: needs 2D laser scans or a geometry layer (run tsdf or points first)")
        floor_z = floor_height(data)
        origin, shape = self._extent(cfg, scans, geom)

        def cells(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rc = np.floor((xy[:, [1, 0]] - origin[[1, 0]]) / cfg.resolution).astype(np.int64)
            ok = (rc[:, 0] >= 0) & (rc[:, 0] < shape[0]) & (rc[:, 1] >= 0) & (rc[:, 1] < shape[1])
            return rc[ok, 0], rc[ok, 1]

        def hits(xy: np.ndarray) -> np.ndarray:
            r, c = cells(xy)
            counts = np.bincount(r * shape[1] + c, minlength=shape[0] * shape[1]).reshape(shape)
            return counts >= cfg.min_points_per_cell

        floor_seen = np.zeros(shape, bool)
        if geom is not None and len(geom):
            z = geom.points[:, 2] - floor_z
            floor_seen = hits(geom.points[np.abs(z) <= cfg.floor_tolerance, :2])

        sweeps = [s for s in (stream.lidar_scans if stream is not None else []) if s.pose is not None]
        stations = scanner_stations(stream) if not scans and not sweeps else []
        if scans:
            slam = self._laser_log_odds(scans, origin, shape, cfg)
            self.note("slam_source", f"{len(scans)} laser scans (log-odds)")
        elif sweeps and len(sweeps) >= sweeps_per_place(cfg):
            planar, reaches = lidar_planar_scans(sweeps, floor_z, cfg)
            slam = self._laser_log_odds(planar, origin, shape, cfg, reaches)
            self.note(
                "slam_source",
                f"{len(planar)} of {len(sweeps)} LiDAR sweeps as planar scans of the {cfg.z_min:g}-"
                f"{cfg.robot_height:g} m band (log-odds)",
            )
        elif sweeps:
            # Fewer sweeps than it takes a cell to become free: each is taken as one long look, as a station's.
            planar, reaches = lidar_planar_scans(sweeps, floor_z, cfg, keyframes=False)
            slam = self._one_look_each(planar, origin, shape, cfg, reaches, floor_seen)
            self.note(
                "slam_source",
                f"{len(planar)} LiDAR sweeps, too few to add up, each one long look as planar scans of the "
                f"{cfg.z_min:g}-{cfg.robot_height:g} m band (log-odds)",
            )
        elif stations:
            planar, reaches = lidar_planar_scans(stations, floor_z, cfg, keyframes=False)
            slam = self._one_look_each(planar, origin, shape, cfg, reaches, floor_seen)
            self.note(
                "slam_source",
                f"{len(planar)} scanner station(s) of a static scan as planar scans of the {cfg.z_min:g}-"
                f"{cfg.robot_height:g} m band (log-odds)",
            )
        else:
            z = geom.points[:, 2] - floor_z  # type: ignore[union-attr]
            in_slice = np.abs(z - cfg.laser_height) <= cfg.laser_slice / 2
            laser = hits(geom.points[in_slice, :2])  # type: ignore[union-attr]
            slam = np.full(shape, -1, np.int8)
            slam[floor_seen] = 0
            slam[laser] = 100
            self.note("slam_source", "geometry slice at the laser height")

        def in_band(points: np.ndarray) -> np.ndarray:
            z = points[:, 2] - floor_z
            return points[(z >= cfg.z_min) & (z <= cfg.robot_height)]

        completed = data.map.instances.completed() if data.map.instances is not None else []
        band = np.zeros(shape, bool)
        if cfg.objects_from == "instances" and data.map.instances is not None:
            band = self._instances_band(data, cfg, floor_z, cells, shape)
        elif geom is not None and len(geom):
            band = hits(in_band(geom.points)[:, :2])
            if completed:
                # The augmented scene A = (G \ S) U O (as the completers build it, from the objects as they
                # stand now, after any physical check): a completed chair's unseen seat and legs are obstacles.
                kept, model_points = self._augmented_points(geom.points, completed, cfg)
                band = hits(in_band(kept)[:, :2])
                r, c = cells(in_band(model_points)[:, :2])
                band[r, c] = True
        objects = np.full(shape, -1, np.int8)
        objects[floor_seen | (slam == 0)] = 0
        objects[band] = 100
        multimap = slam.copy()
        multimap[band] = 100
        origin3 = (float(origin[0]), float(origin[1]), 0.0)
        grids = OccupancyMaps(
            slam=OccupancyGrid(slam, cfg.resolution, origin3),
            objects=OccupancyGrid(objects, cfg.resolution, origin3),
            multimap=OccupancyGrid(multimap, cfg.resolution, origin3),
        )
        if completed and cfg.objects_from == "geometry":
            self.note("objects_from", f"augmented scene ({len(completed)} completed objects)")
        self.note("floor_z", float(floor_z))
        return {"occupancy": grids}

    def _extent(self, cfg: OccupancyConfig, scans: list[LaserScan], geom: Any) -> tuple[np.ndarray, tuple[int, int]]:
        """The grid's origin and shape: the geometry and the laser scans' beam ends, less those far from
        the rest (:func:`far_from_bulk`: one stray point 100 km away would make the grid 4e12 cells)."""
        xy = []
        if geom is not None and len(geom):
            xy.append(geom.points[:, :2])
        for s in scans:
            ranges = np.where(np.isfinite(s.ranges), s.ranges, np.nan)
            ang = s.angles + np.arctan2(s.pose[1, 0], s.pose[0, 0])
            end = s.pose[:2, 3] + np.stack([np.cos(ang), np.sin(ang)], 1) * np.nan_to_num(ranges, nan=0.0)[:, None]
            xy.append(np.vstack([end, s.pose[:2, 3][None]]))
        pts = np.vstack(xy)
        far = far_from_bulk(np.c_[pts, np.zeros(len(pts))])
        if far.any() and not far.all():
            self.warn(
                f"occupancy: {int(far.sum())} of {len(pts)} points and beam ends lie far from the rest (more than "
                f"{FAR_FROM_BULK:g} times the extent of their bulk outside it, or not finite): left off the grid"
            )
            pts = pts[~far]
        lo = pts.min(0) - cfg.margin
        hi = pts.max(0) + cfg.margin
        origin = np.floor(lo / cfg.resolution) * cfg.resolution
        shape = (int(np.ceil((hi[1] - origin[1]) / cfg.resolution)), int(np.ceil((hi[0] - origin[0]) / cfg.resolution)))
        if shape[0] * shape[1] > MAX_CELLS:
            span = pts.max(0) - pts.min(0)
            hint = unit_hint(geom.points) if geom is not None and len(geom) else None
            raise DataError(
                f"occupancy: the map spans {span[0]:,.0f} x {span[1]:,.0f} m, {shape[1]:,} x {shape[0]:,} cells of "
                f"{cfg.resolution:g} m (at most {MAX_CELLS:,.0f}): "
                + (
                    f"{hint} (else set a coarser occupancy resolution)"
                    if hint
                    else "set a coarser occupancy resolution"
                )
            )
        return origin, shape

    def _one_look_each(
        self,
        planar: list[LaserScan],
        origin: np.ndarray,
        shape: tuple[int, int],
        cfg: OccupancyConfig,
        reaches: list[np.ndarray],
        floor_seen: np.ndarray,
    ) -> np.ndarray:
        """Log-odds of scans that are each one long look from a tripod (a static scan's stations, or a
        recording of too few sweeps to add up), not a pass of a moving laser: what a beam crossed is free,
        and where it ended occupied, from that one scan (full log-odds); floor the geometry saw is free."""
        lo, hi = cfg.log_odds_clamp
        static = cfg.model_copy(update={"log_odds_miss": lo, "log_odds_hit": hi})
        slam = self._laser_log_odds(planar, origin, shape, static, reaches)
        slam[floor_seen & (slam < 0)] = 0
        return slam

    @staticmethod
    def _laser_log_odds(
        scans: list[LaserScan],
        origin: np.ndarray,
        shape: tuple[int, int],
        cfg: OccupancyConfig,
        no_return_reach: list[np.ndarray] | None = None,
    ) -> np.ndarray:
        """Log-odds of the scans, trinary. A beam without a return clears cells to ``max_free_range``,
        or, where ``no_return_reach`` gives one per beam, to that range (0: none)."""
        logodds = np.zeros(shape, np.float64)
        seen = np.zeros(shape, bool)
        step = cfg.resolution / 2
        lo, hi = cfg.log_odds_clamp
        for k, s in enumerate(scans):
            yaw = np.arctan2(s.pose[1, 0], s.pose[0, 0])
            ang = s.angles + yaw
            ret = np.isfinite(s.ranges) & (s.ranges <= s.range_max)
            missed = min(cfg.max_free_range, s.range_max) if no_return_reach is None else no_return_reach[k]
            # Past the grid's farthest corner a beam marks nothing: a bogus range of 1e9 m would cost 4e10 samples.
            corners = origin + np.array([[0, 0], [0, shape[0]], [shape[1], 0], [shape[1], shape[0]]]) * cfg.resolution
            beyond = float(np.max(np.hypot(*(corners - s.pose[:2, 3]).T))) + cfg.resolution
            reach = np.minimum(np.where(ret, s.ranges, missed), beyond)
            if not np.any(reach > 0):
                continue
            n = int(np.ceil(reach.max() / step)) + 1
            t = np.arange(n) * step
            dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
            # Free samples along every beam, stopping half a cell before the hit.
            mask = t[None, :] < (reach[:, None] - cfg.resolution / 2)
            pts = s.pose[:2, 3] + dirs[:, None, :] * t[None, :, None]
            flat_free = np.unique(flat_cells(pts[mask], origin, shape, cfg.resolution))
            hit_xy = s.pose[:2, 3] + dirs[ret] * s.ranges[ret, None]
            flat_hit = np.unique(flat_cells(hit_xy, origin, shape, cfg.resolution))
            flat_free = np.setdiff1d(flat_free, flat_hit, assume_unique=True)
            lf = logodds.reshape(-1)
            lf[flat_free] = np.clip(lf[flat_free] + cfg.log_odds_miss, lo, hi)
            lf[flat_hit] = np.clip(lf[flat_hit] + cfg.log_odds_hit, lo, hi)
            sf = seen.reshape(-1)
            sf[flat_free] = True
            sf[flat_hit] = True
        # Trinary, as map_saver writes a SLAM map for nav2: confident cells are 0 or 100, the rest unknown.
        prob = 1.0 / (1.0 + np.exp(-logodds))
        out = np.full(shape, -1, np.int8)
        out[seen & (prob > OCCUPIED_THRESH)] = 100
        out[seen & (prob < FREE_THRESH)] = 0
        return out

    @staticmethod
    def _instances_band(
        data: PipelineData, cfg: OccupancyConfig, floor_z: float, cells: Any, shape: tuple[int, int]
    ) -> np.ndarray:
        from stratamap.core.simulation.kinematics import object_mesh

        band = np.zeros(shape, bool)
        for inst in data.map.instances or []:
            mesh, pose = object_mesh(inst)
            world = mesh.copy()
            world.apply_transform(pose)
            pts = (
                world.sample(max(2000, int(world.area / (cfg.resolution / 3) ** 2)), seed=inst.id)
                if world.area > 0
                else world.vertices
            )
            pts = np.vstack([pts, world.vertices])
            z = pts[:, 2] - floor_z
            r, c = cells(pts[(z >= cfg.z_min) & (z <= cfg.robot_height), :2])
            band[r, c] = True
        return band

    @staticmethod
    def _augmented_points(
        points: np.ndarray, completed: list[Any], cfg: OccupancyConfig
    ) -> tuple[np.ndarray, np.ndarray]:
        """The observed points farther than ``epsilon`` from every completed model, and points on the
        models' surfaces (spaced a third of a cell, so every cell a model covers gets some)."""
        from stratamap.core.simulation.kinematics import object_mesh

        scene = o3d.t.geometry.RaycastingScene()
        samples = []
        for inst in completed:
            mesh, pose = object_mesh(inst)
            world = mesh.copy()
            world.apply_transform(pose)
            if len(world.faces) == 0:
                continue
            scene.add_triangles(
                o3c.Tensor(np.asarray(world.vertices, np.float32)), o3c.Tensor(np.asarray(world.faces, np.uint32))
            )
            count = max(2000, int(world.area / (cfg.resolution / 3) ** 2))
            samples.append(np.vstack([world.sample(count, seed=inst.id), world.vertices]))
        if not samples:
            return points, np.zeros((0, 3))
        dist = scene.compute_distance(o3c.Tensor(points.astype(np.float32))).numpy()
        return points[dist > cfg.epsilon], np.vstack(samples)


@hookimpl
def stratamap_register_mappers():
    return [OccupancyMapper]
