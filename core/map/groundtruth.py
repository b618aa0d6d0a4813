"""Ground truth that synthetic worlds (and annotated datasets) carry alongside the sensor data."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stratamap.core.lazy import lazy_module
from stratamap.core.map.layers import ContactGraph, Joint, OccupancyMaps, OrientedBox
from stratamap.core.map.sensors import FrameSegmentation
from stratamap.core.map.vocabulary import Vocabulary

trimesh = lazy_module("trimesh")


@dataclass
class GroundTruthObject:
    """One object as placed in the world: full mesh in its object frame, and the pose that places it."""

    id: int
    class_name: str
    mesh: trimesh.Trimesh  # object frame: origin at the bottom center, +z up, front along -y
    pose: np.ndarray  # (4, 4) object-to-world
    model_id: str = ""
    family: str = ""
    parent: int | str = "floor"  # the id of the supporting object, or a layout node name
    joints: list[Joint] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    #: The box of each moving part at joint positions 0, in the object frame: a joint's child link
    #: (its geometry and that of the links below it) -> ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
    #: Empty where the source does not say (ground truth written before 2026-12, hand labels).
    part_boxes: dict[str, list[list[float]]] = field(default_factory=dict)

    def world_mesh(self) -> trimesh.Trimesh:
        mesh = self.mesh.copy()
        mesh.apply_transform(self.pose)
        return mesh

    def box(self) -> OrientedBox:
        """The object's gravity-aligned box in the world (its model's axis-aligned box, posed)."""
        lo, hi = self.mesh.bounds
        center_local = np.append((lo + hi) / 2, 1.0)
        center = (self.pose @ center_local)[:3]
        yaw = float(np.arctan2(self.pose[1, 0], self.pose[0, 0]))
        return OrientedBox(center, yaw, hi - lo)


@dataclass
class GroundTruth:
    """Everything known about a scene: objects, per-frame labels, relations and occupancy."""

    vocabulary: Vocabulary = field(default_factory=Vocabulary.default)
    objects: list[GroundTruthObject] = field(default_factory=list)
    frame_labels: list[FrameSegmentation] = field(default_factory=list)
    contact_graph: ContactGraph | None = None
    layout: dict[str, Any] = field(default_factory=dict)  # room size, floor height, wall segments
    occupancy: OccupancyMaps = field(default_factory=OccupancyMaps)
    #: Per-point labels of a static cloud (``SensorStream.points``), when the dataset annotates points.
    point_class_ids: np.ndarray | None = None
    point_instance_ids: np.ndarray | None = None

    def object(self, object_id: int) -> GroundTruthObject:
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(f"no ground-truth object with id {object_id}")
