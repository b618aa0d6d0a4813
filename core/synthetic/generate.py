"""From a scene spec to sensor data with ground truth, in memory.

Frames are rendered on access (and a few cached), so a long sequence costs no memory until it
is read; the sequence pickles as its spec and re-renders identically wherever it is unpickled.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from stratamap.core.geometry.transforms import make_pose, yaw_of
from stratamap.core.map.groundtruth import GroundTruth
from stratamap.core.map.layers import OccupancyMaps
from stratamap.core.map.sensors import FrameSegmentation, LaserScan, LidarScan, RGBDFrame, SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.synthetic.occupancy import VoxelOccupancy, scene_occupancy
from stratamap.core.synthetic.render import SceneRenderer, apply_kinect_noise, laser_directions, lidar_directions
from stratamap.core.synthetic.scene import Scene, generate_scene
from stratamap.core.synthetic.spec import SceneSpec
from stratamap.core.synthetic.trajectory import drift, make_trajectory


def robot_pose(camera_pose: np.ndarray) -> tuple[float, float, float]:
    """(x, y, heading) of the robot base under a camera: the optical axis projected on the floor."""
    forward = camera_pose[:3, 2]
    return float(camera_pose[0, 3]), float(camera_pose[1, 3]), float(np.arctan2(forward[1], forward[0]))


def _nbytes(item: tuple[RGBDFrame, FrameSegmentation]) -> int:
    frame, seg = item
    return int(frame.rgb.nbytes + frame.depth.nbytes + seg.class_ids.nbytes + seg.instance_ids.nbytes)


class SyntheticWorld:
    """A generated scene with its sensors; everything is a deterministic function of the spec."""

    #: Rendered frames are kept up to this many bytes (at least 4 frames) when the whole sequence fits:
    #: a segmenter and a mapper that read the same frames one after the other then ray cast them once.
    CACHE_BYTES = 768 * 2**20

    def __init__(self, spec: SceneSpec):
        self.spec = spec
        self.vocabulary = Vocabulary.default()
        self.scene: Scene = generate_scene(spec)
        self.renderer = SceneRenderer(self.scene, self.vocabulary)
        self.intrinsics = spec.camera.intrinsics()
        self.true_poses = make_trajectory(self.scene, spec.trajectory, spec.seed, self.renderer.cast)
        self.reported_poses = drift(self.true_poses, spec.noise.pose_drift, spec.seed)
        self._cache: OrderedDict[int, tuple[RGBDFrame, FrameSegmentation]] = OrderedDict()
        self._cache_bytes = 0

    def __len__(self) -> int:
        return len(self.true_poses)

    def timestamp(self, k: int) -> float:
        return round(k / self.spec.camera.frame_rate, 6)

    def frame(self, k: int) -> tuple[RGBDFrame, FrameSegmentation]:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        if not 0 <= k < len(self):
            raise IndexError(f"frame {k} out of range (sequence has {len(self)} frames)")
        cam, noise = self.spec.camera, self.spec.noise
        view = self.renderer.render(self.intrinsics, self.true_poses[k], cam.max_range)
        depth = view.depth
        if noise.depth == "kinect":
            rng = np.random.default_rng([self.spec.seed, k, 31])
            depth = apply_kinect_noise(
                view, rng, noise.min_range, cam.max_range, noise.grazing_angle_deg, noise.edge_dropout
            )
        out = (
            RGBDFrame(k, self.timestamp(k), view.rgb, depth, self.reported_poses[k].copy()),
            FrameSegmentation(k, view.class_ids, view.instance_ids),
        )
        self._cache[k] = out
        self._cache_bytes += _nbytes(out)
        # A sequence that does not fit keeps 4 frames: stages that read it in turn (an eager segmenter,
        # then the mapper) would find none of theirs left in the cache anyway, and stages that read it
        # in step (lazy labels) need no more; memory then stays the same however long the walk.
        fits = _nbytes(out) * len(self) <= self.CACHE_BYTES
        while len(self._cache) > 4 and (self._cache_bytes > self.CACHE_BYTES or not fits):
            self._cache_bytes -= _nbytes(self._cache.popitem(last=False)[1])
        return out

    @cached_property
    def laser_scans(self) -> list[LaserScan]:
        spec = self.spec.laser
        if not spec.enabled:
            return []
        angles = laser_directions(spec.beams, spec.fov_deg)
        scans = []
        for k, pose in enumerate(self.true_poses):
            x, y, heading = robot_pose(pose)
            dirs = np.stack([np.cos(angles + heading), np.sin(angles + heading), np.zeros_like(angles)], 1)
            origins = np.tile([x, y, spec.height], (len(angles), 1))
            r = self.renderer.cast(origins, dirs)
            rng = np.random.default_rng([self.spec.seed, k, 37])
            r = r + rng.normal(0, self.spec.noise.laser_std, r.shape)
            r[~np.isfinite(r) | (r > spec.range_max)] = np.inf
            reported = self.reported_poses[k]
            rx, ry, rheading = robot_pose(reported)
            scans.append(
                LaserScan(
                    self.timestamp(k),
                    float(angles[0]),
                    float(angles[1] - angles[0]),
                    r.astype(np.float32),
                    spec.range_max,
                    make_pose((rx, ry, spec.height), rheading),
                )
            )
        return scans

    @cached_property
    def lidar_scans(self) -> list[LidarScan]:
        spec = self.spec.lidar
        if not spec.enabled:
            return []
        local = lidar_directions(spec.rings, spec.vertical_fov_deg, spec.points_per_ring)
        scans = []
        for k, pose in enumerate(self.true_poses):
            x, y, heading = robot_pose(pose)
            sensor = make_pose((x, y, spec.height), heading)
            dirs = local @ sensor[:3, :3].T
            r = self.renderer.cast(np.tile(sensor[:3, 3], (len(dirs), 1)), dirs)
            rng = np.random.default_rng([self.spec.seed, k, 41])
            r = r + rng.normal(0, spec.range_std, r.shape)
            hit = np.isfinite(r) & (r < spec.range_max)
            pts = local[hit] * r[hit, None]
            rx, ry, rheading = robot_pose(self.reported_poses[k])
            scans.append(LidarScan(self.timestamp(k), pts, make_pose((rx, ry, spec.height), rheading)))
        return scans

    @cached_property
    def occupancy_band(self) -> VoxelOccupancy:
        gt = self.spec.ground_truth
        return scene_occupancy(self.scene, gt.z_min, gt.robot_height, gt.resolution)

    @cached_property
    def occupancy_laser(self) -> VoxelOccupancy:
        gt, h = self.spec.ground_truth, self.spec.laser.height
        return scene_occupancy(self.scene, h - gt.resolution / 2, h + gt.resolution / 2, gt.resolution)

    @cached_property
    def coverage(self) -> dict[str, Any]:
        """The share of each object's surface the (true) camera path sees (see core/synthetic/coverage.py)."""
        from stratamap.core.synthetic.coverage import surface_coverage

        cam, noise = self.spec.camera, self.spec.noise
        return surface_coverage(
            self.scene,
            self.renderer.cast,
            self.intrinsics,
            self.true_poses,
            noise.min_range if noise.depth == "kinect" else 0.0,
            cam.max_range,
            seed=self.spec.seed,
        )

    def ground_truth(self) -> GroundTruth:
        return GroundTruth(
            vocabulary=self.vocabulary,
            objects=self.scene.ground_truth_objects(),
            frame_labels=LazyLabels(self),
            contact_graph=self.scene.contact_graph(),
            layout={
                **self.scene.layout_info(),
                "true_poses": [p.tolist() for p in self.true_poses],
                "skipped": self.scene.skipped,
                **({"coverage": self.coverage} if self.spec.ground_truth.coverage else {}),
            },
            occupancy=OccupancyMaps(objects=self.occupancy_band.project(), laser=self.occupancy_laser.project()),
        )

    def stream(self) -> SensorStream:
        return SensorStream(
            name=f"synthetic-{self.spec.type}-seed{self.spec.seed}",
            intrinsics=self.intrinsics,
            frames=LazyFrames(self),
            laser_scans=self.laser_scans,
            lidar_scans=self.lidar_scans,
            metadata={"scene_spec": self.spec.model_dump(mode="json"), "depth_unit": "m"},
        )


class _LazySequence(Sequence):
    """A read-only view of a world's frames; pickles as the spec (re-rendered on load)."""

    def __init__(self, world: SyntheticWorld):
        self.world = world

    def __len__(self) -> int:
        return len(self.world)

    def _item(self, k: int) -> Any:
        raise NotImplementedError

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return [self._item(i) for i in range(*k.indices(len(self)))]
        if k < 0:
            k += len(self)
        return self._item(k)

    def __reduce__(self):
        return (_rebuild, (type(self), self.world.spec.model_dump(mode="json")))

    def __deepcopy__(self, memo: dict) -> list:
        return [copy.deepcopy(item, memo) for item in self]


class LazyFrames(_LazySequence):
    def _item(self, k: int) -> RGBDFrame:
        return self.world.frame(k)[0]

    @property
    def poses(self) -> list[np.ndarray]:
        """Each frame's pose as the frame reports it, without rendering the frame (where the sensor
        stood: ``core/map/sensors.sensor_viewpoints``); copies."""
        return [pose.copy() for pose in self.world.reported_poses]


class LazyLabels(_LazySequence):
    def _item(self, k: int) -> FrameSegmentation:
        return self.world.frame(k)[1]


def _rebuild(cls: type, spec: dict) -> _LazySequence:
    return cls(SyntheticWorld(SceneSpec.model_validate(spec)))


@dataclass
class SyntheticSequence:
    world: SyntheticWorld
    stream: SensorStream
    ground_truth: GroundTruth

    @property
    def scene(self) -> Scene:
        return self.world.scene


def generate_sequence(spec: SceneSpec) -> SyntheticSequence:
    """The scene, its sensor stream (lazy frames, laser and LiDAR scans) and its ground truth."""
    world = SyntheticWorld(spec)
    return SyntheticSequence(world, world.stream(), world.ground_truth())


__all__ = ["SyntheticSequence", "SyntheticWorld", "generate_sequence", "robot_pose", "yaw_of"]
