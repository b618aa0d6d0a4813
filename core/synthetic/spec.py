"""Scene specs: what a procedural scene contains and how it is sensed. One YAML file per scene.

Example (``configs/scenes/office.yaml``)::

    type: office
    room_size: [6.5, 5.5, 2.7]
    objects: {desk: 3, chair: 4, cabinet: 2, monitor: 3, cup: 3}
    seed: 0
    camera: {width: 640, height: 480}
    trajectory: {type: walk, frames: 120}
    noise: {depth: kinect}
    laser: {height: 0.25}
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from stratamap.core.documents import load_model
from stratamap.core.map.sensors import CameraIntrinsics

SCENE_TYPES = ("room", "office", "meeting_room", "kitchen", "lounge", "corridor")

#: Default room size (x, y, z) and object counts by class per scene type.
SCENE_DEFAULTS: dict[str, tuple[tuple[float, float, float], dict[str, int]]] = {
    "room": ((5.0, 4.0, 2.6), {"table": 1, "chair": 4, "box": 2}),
    "office": (
        (6.5, 5.5, 2.7),
        {
            "desk": 3,
            "chair": 5,
            "table": 1,
            "cabinet": 2,
            "shelf": 1,
            "monitor": 3,
            "laptop": 1,
            "cup": 3,
            "book": 3,
            "plant": 1,
        },
    ),
    "meeting_room": (
        (7.0, 5.0, 2.7),
        {"table": 1, "chair": 8, "cabinet": 1, "shelf": 1, "laptop": 2, "cup": 4, "bottle": 2, "plant": 1},
    ),
    "kitchen": (
        (6.0, 5.0, 2.6),
        {
            "counter": 2,
            "fridge": 1,
            "oven": 1,
            "cabinet": 1,
            "microwave": 1,
            "table": 1,
            "chair": 3,
            "cup": 3,
            "bottle": 2,
            "plant": 1,
        },
    ),
    "lounge": (
        (6.0, 5.0, 2.7),
        {"sofa": 1, "chair": 2, "table": 1, "shelf": 2, "cabinet": 1, "plant": 2, "book": 3, "cup": 2},
    ),
    "corridor": ((10.0, 2.4, 2.7), {"bench": 2, "cabinet": 2, "shelf": 1, "plant": 2, "box": 2, "chair": 1}),
}


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CameraSpec(_Spec):
    """The simulated RGB-D camera."""

    width: int = Field(default=640, ge=16, le=4096, description="Image width in pixels.")
    height: int = Field(default=480, ge=16, le=4096, description="Image height in pixels.")
    fov_x_deg: float = Field(
        default=62.0, gt=10, lt=170, description="Horizontal field of view, degrees (Kinect v1: ~62)."
    )
    max_range: float = Field(default=8.0, gt=0, description="Depth beyond this range reads as no measurement, metres.")
    frame_rate: float = Field(default=30.0, gt=0, description="Timestamps advance by 1/frame_rate seconds.")

    def intrinsics(self) -> CameraIntrinsics:
        fx = self.width / (2 * np.tan(np.radians(self.fov_x_deg) / 2))
        return CameraIntrinsics(self.width, self.height, fx, fx, (self.width - 1) / 2, (self.height - 1) / 2)


class TrajectorySpec(_Spec):
    """The camera path."""

    type: Literal["walk", "orbit", "fixed"] = Field(
        default="walk",
        description=(
            "walk: a loop through free space like a teleoperated robot; orbit: an ellipse looking at the room center; "
            "fixed: one viewpoint."
        ),
    )
    frames: int = Field(default=120, ge=1, le=100000, description="Number of frames along the path.")
    height: float = Field(default=1.3, gt=0.1, description="Camera height above the floor, metres (robots: 1.0-1.5).")
    look_height: float = Field(default=0.6, description="Height of the point the camera looks toward, metres.")
    clearance: float = Field(
        default=0.45, gt=0.0, description="Minimum distance from the walk's path to any obstacle, metres."
    )


class NoiseSpec(_Spec):
    """Sensor noise. ``depth: none`` renders perfect depth."""

    depth: Literal["none", "kinect"] = Field(
        default="none",
        description=(
            "kinect: axial noise growing with depth squared, disparity quantization, dropouts at grazing angles and "
            "edges."
        ),
    )
    min_range: float = Field(
        default=0.4, ge=0.0, description="Depth closer than this reads as no measurement (Kinect: 0.4 m), metres."
    )
    grazing_angle_deg: float = Field(
        default=84.0, gt=0, le=90, description="Surfaces seen at a larger incidence angle drop out."
    )
    edge_dropout: float = Field(
        default=0.5, ge=0, le=1, description="Probability that a pixel on a depth discontinuity drops out."
    )
    pose_drift: float = Field(
        default=0.0,
        ge=0.0,
        description=(
            "Std of the random walk added to reported poses per frame (metres; radians/10 for yaw). 0: exact poses."
        ),
    )
    laser_std: float = Field(default=0.01, ge=0.0, description="Std of the 2D laser's range noise, metres.")


class LaserSpec(_Spec):
    """A planar 2D laser scanner on the robot base."""

    enabled: bool = Field(default=True, description="Simulate the laser.")
    height: float = Field(
        default=0.25, gt=0.0, description="Scan plane height above the floor, metres (sees chair legs, not seats)."
    )
    beams: int = Field(default=720, ge=8, description="Number of beams.")
    fov_deg: float = Field(
        default=270.0, gt=0, le=360, description="Angular field of view, degrees, centered on the robot's heading."
    )
    range_max: float = Field(
        default=12.0, gt=0, description="Maximum range, metres; farther hits read as no return (inf)."
    )


class LidarSpec(_Spec):
    """A spinning 3D LiDAR on the robot."""

    enabled: bool = Field(default=False, description="Simulate the LiDAR.")
    rings: int = Field(default=16, ge=1, le=256, description="Number of laser rings.")
    vertical_fov_deg: tuple[float, float] = Field(
        default=(-15.0, 15.0), description="Lowest and highest ring elevation, degrees."
    )
    points_per_ring: int = Field(default=900, ge=8, description="Azimuth samples per ring.")
    height: float = Field(default=1.0, gt=0.0, description="Sensor height above the floor, metres.")
    range_max: float = Field(default=30.0, gt=0.0, description="Maximum range, metres.")
    range_std: float = Field(default=0.01, ge=0.0, description="Std of the range noise, metres.")


class GroundTruthSpec(_Spec):
    """How ground-truth occupancy is computed."""

    robot_height: float = Field(default=1.0, gt=0.0, description="Top of the obstacle band, metres.")
    z_min: float = Field(default=0.1, ge=0.0, description="Bottom of the obstacle band, metres.")
    resolution: float = Field(
        default=0.05, gt=0.005, description="Cell and voxel size of ground-truth occupancy, metres."
    )


class SceneSpec(_Spec):
    """A procedural scene: type, room, objects, seed, sensors, trajectory and noise."""

    type: Literal["room", "office", "meeting_room", "kitchen", "lounge", "corridor"] = Field(
        default="room", description="Scene type; decides default room size, furniture and placement rules."
    )
    room_size: tuple[float, float, float] | None = Field(
        default=None, description="Interior length (x), width (y), height (z) in metres; default per type."
    )
    objects: dict[str, int] | None = Field(default=None, description="Object counts by class; default per type.")
    seed: int = Field(default=0, description="Seed of every random choice: same spec and seed, same files bit for bit.")
    camera: CameraSpec = Field(default_factory=CameraSpec, description="The RGB-D camera.")
    trajectory: TrajectorySpec = Field(default_factory=TrajectorySpec, description="The camera path.")
    noise: NoiseSpec = Field(default_factory=NoiseSpec, description="Sensor noise.")
    laser: LaserSpec = Field(default_factory=LaserSpec, description="The 2D laser scanner.")
    lidar: LidarSpec = Field(default_factory=LidarSpec, description="The 3D LiDAR.")
    ground_truth: GroundTruthSpec = Field(
        default_factory=GroundTruthSpec, description="Ground-truth occupancy settings."
    )

    @field_validator("objects")
    @classmethod
    def _known_classes(cls, value: dict[str, int] | None) -> dict[str, int] | None:
        if value is None:
            return value
        from stratamap.core.synthetic.placement import PLACEMENT

        unknown = sorted(set(value) - set(PLACEMENT))
        if unknown:
            raise ValueError(f"unknown object classes {unknown}; known: {sorted(PLACEMENT)}")
        for name, count in value.items():
            if count < 0 or count > 64:
                raise ValueError(f"count of {name!r} must be between 0 and 64, got {count}")
        return value

    def resolved_room_size(self) -> tuple[float, float, float]:
        return tuple(self.room_size or SCENE_DEFAULTS[self.type][0])  # type: ignore[return-value]

    def resolved_objects(self) -> dict[str, int]:
        return dict(self.objects if self.objects is not None else SCENE_DEFAULTS[self.type][1])

    @classmethod
    def from_yaml(cls, path: str | Path) -> SceneSpec:
        return load_model(cls, path, "scene spec")
