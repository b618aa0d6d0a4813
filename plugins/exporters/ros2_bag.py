"""Exporter ``ros2_bag``: the map as a ROS 2 bag that ``ros2 bag play`` replays into RViz 2, written
with ``rosbags`` (no ROS install needed).

Topics (ROS 2 Humble message definitions, every one published once, with transient-local QoS so
that displays started after the replay still receive it; frame ``map``):

======================  =====================================  ===================================
topic                   type                                   content
======================  =====================================  ===================================
``/map`` (and more)     ``nav_msgs/msg/OccupancyGrid``         occupancy layers, -1 unknown, 0..100
``/costmap``            ``nav_msgs/msg/OccupancyGrid``         the inflated costmap, Nav2's values
``/stratamap/cloud``    ``sensor_msgs/msg/PointCloud2``        x y z, rgb, class, instance
``/stratamap/objects``  ``visualization_msgs/msg/MarkerArray``  boxes, completed models, labels
``/tf_static``          ``tf2_msgs/msg/TFMessage``             ``map`` -> one frame per object
======================  =====================================  ===================================

The bag is a folder (``metadata.yaml`` + one sqlite3 file), written beside the other exports and
swapped in whole.
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field, field_validator

from stratamap.core import Exporter, PipelineData, StageConfig, hookimpl
from stratamap.core.atomic import atomic_directory
from stratamap.core.geometry.transforms import matrix_to_quat_xyzw
from stratamap.core.io.nav2 import COST_INSCRIBED, COST_LETHAL, COST_UNKNOWN, costmap_values
from stratamap.core.map.colors import id_colors
from stratamap.core.stages import warn_renamed
from stratamap.plugins.exporters._sections import (
    RENAMED_INFLATION,
    Inflation,
    inflation_section,
)

#: rosbag2 metadata version rosbags writes (8 is the oldest it offers; Humble's player reads it).
BAG_VERSION = 8
#: PointField datatypes (sensor_msgs/msg/PointField).
FLOAT32, INT32, UINT32 = 7, 5, 6
#: One point of /stratamap/cloud: x y z, rgb packed into a float as RViz expects, class, instance.
CLOUD_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4"), ("class", "<u4"), ("instance", "<i4")]
)
CLOUD_FIELDS = (
    ("x", FLOAT32),
    ("y", FLOAT32),
    ("z", FLOAT32),
    ("rgb", FLOAT32),
    ("class", UINT32),
    ("instance", INT32),
)
LABEL_HEIGHT = 0.12  # metres, the text of object labels


def occupancy_from_costs(costs: np.ndarray) -> np.ndarray:
    """Nav2 cost values as the int8 cells Nav2's costmap publisher sends: 0 free, 99 inscribed,
    100 lethal, -1 unknown, and 1 + 97 * (cost - 1) // 251 in between."""
    costs = np.asarray(costs, dtype=np.int64)
    cells = 1 + (97 * (costs - 1)) // 251
    cells[costs == 0] = 0
    cells[costs == COST_INSCRIBED] = 99
    cells[costs == COST_LETHAL] = 100
    cells[costs == COST_UNKNOWN] = -1
    return cells.astype(np.int8)


def packed_rgb(colors: np.ndarray) -> np.ndarray:
    """(N, 3) colours in [0, 1] as 0x00RRGGBB integers (the bits of PointCloud2's float ``rgb``)."""
    c = np.clip(np.round(np.asarray(colors, dtype=np.float64) * 255), 0, 255).astype(np.uint32)
    return (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]


class Ros2BagConfig(StageConfig):
    folder: str = Field(
        default="ros2_bag", description="Bag folder in the export folder (metadata.yaml + sqlite3 file)."
    )
    grids: dict[str, str] = Field(
        default_factory=lambda: {"slam": "/map", "multimap": "/multimap"},
        description="Occupancy layer -> topic of its nav_msgs/OccupancyGrid (a missing layer is a warning).",
    )
    costmap_layer: str | None = Field(
        default="multimap", description="Occupancy layer inflated into the costmap; null: no costmap topic."
    )
    costmap_topic: str = Field(default="/costmap", description="Topic of the costmap (nav_msgs/OccupancyGrid).")
    inflation: Inflation = inflation_section()
    cloud_topic: str = Field(default="/stratamap/cloud", description="Topic of the map's points (PointCloud2).")
    objects_topic: str = Field(
        default="/stratamap/objects", description="Topic of the objects' boxes, models and labels (MarkerArray)."
    )
    frame_id: str = Field(default="map", description="Frame of every message, the parent of the object frames.")

    renamed: ClassVar[Mapping[str, str]] = RENAMED_INFLATION

    @field_validator("folder")
    @classmethod
    def _inside_export_folder(cls, folder: str) -> str:
        if not folder.strip() or Path(folder).is_absolute() or ".." in Path(folder).parts:
            raise ValueError(f"must be a folder name inside the export folder, got {folder!r}")
        return folder


def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _latched_qos() -> Any:
    """Reliable, transient local, last message kept: what map_server offers for /map."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    never = QosTime(sec=0, nsec=0)  # 0: the middleware default, no deadline or lease
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1,
        reliability=QosReliability.RELIABLE,
        durability=QosDurability.TRANSIENT_LOCAL,
        deadline=never,
        lifespan=never,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=never,
        avoid_ros_namespace_conventions=False,
    )


class _Messages:
    """Builders of the ROS 2 messages the bag holds, from one typestore."""

    def __init__(self, typestore: Any, frame_id: str):
        self.ts = typestore
        self.T = typestore.types
        self.frame_id = frame_id

    def header(self) -> Any:
        # stamp 0: "the latest transform" to tf lookups, so RViz shows the replay at any clock
        return self.T["std_msgs/msg/Header"](
            stamp=self.T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=self.frame_id
        )

    def point(self, xyz: Any) -> Any:
        return self.T["geometry_msgs/msg/Point"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2]))

    def pose(self, matrix: np.ndarray) -> Any:
        q = matrix_to_quat_xyzw(np.asarray(matrix, dtype=np.float64)[:3, :3])
        quaternion = self.T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))
        return self.T["geometry_msgs/msg/Pose"](position=self.point(matrix[:3, 3]), orientation=quaternion)

    def color(self, rgb: Any, alpha: float) -> Any:
        return self.T["std_msgs/msg/ColorRGBA"](r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=float(alpha))

    def occupancy_grid(self, grid: Any, cells: np.ndarray) -> Any:
        ox, oy, yaw = grid.origin
        origin = np.eye(4)
        origin[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        origin[:2, 3] = (ox, oy)
        info = self.T["nav_msgs/msg/MapMetaData"](
            map_load_time=self.T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
            resolution=float(grid.resolution),
            width=grid.width,
            height=grid.height,
            origin=self.pose(origin),
        )
        data = np.ascontiguousarray(cells, dtype=np.int8).reshape(-1)  # row-major, row 0 the lowest y, as ROS
        return self.T["nav_msgs/msg/OccupancyGrid"](header=self.header(), info=info, data=data)

    def cloud(self, rows: np.ndarray) -> Any:
        fields = [
            self.T["sensor_msgs/msg/PointField"](name=name, offset=CLOUD_DTYPE.fields[name][1], datatype=kind, count=1)
            for name, kind in CLOUD_FIELDS
        ]
        return self.T["sensor_msgs/msg/PointCloud2"](
            header=self.header(),
            height=1,
            width=len(rows),
            fields=fields,
            is_bigendian=False,
            point_step=CLOUD_DTYPE.itemsize,
            row_step=CLOUD_DTYPE.itemsize * len(rows),
            data=np.frombuffer(rows.tobytes(), dtype=np.uint8),
            is_dense=True,
        )

    def marker(self, ns: str, marker_id: int, kind: int, pose: np.ndarray, scale: Any, color: Any, **extra: Any) -> Any:
        T = self.T
        values = {
            "points": [],
            "colors": [],
            "text": "",
            "texture_resource": "",
            "texture": T["sensor_msgs/msg/CompressedImage"](
                header=self.header(), format="", data=np.zeros(0, np.uint8)
            ),
            "uv_coordinates": [],
            "mesh_resource": "",
            "mesh_file": T["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            "mesh_use_embedded_materials": False,
            **extra,
        }
        return T["visualization_msgs/msg/Marker"](
            header=self.header(),
            ns=ns,
            id=int(marker_id),
            type=kind,
            action=T["visualization_msgs/msg/Marker"].ADD,
            pose=self.pose(pose),
            scale=T["geometry_msgs/msg/Vector3"](x=float(scale[0]), y=float(scale[1]), z=float(scale[2])),
            color=color,
            lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),  # 0: forever
            frame_locked=False,
            **values,
        )

    def transform(self, child: str, pose: np.ndarray) -> Any:
        T = self.T
        q = matrix_to_quat_xyzw(np.asarray(pose, dtype=np.float64)[:3, :3])
        transform = T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )
        return T["geometry_msgs/msg/TransformStamped"](header=self.header(), child_frame_id=child, transform=transform)


def object_frame(instance: Any) -> str:
    """The tf frame of an object: its class and id (``chair_3``)."""
    return f"{instance.class_name}_{instance.id}"


class Ros2BagExporter(Exporter[Ros2BagConfig]):
    """A ROS 2 bag for RViz 2: occupancy grids, costmap, the map as PointCloud2 (class, instance), markers, tf."""

    name = "ros2_bag"
    Config = Ros2BagConfig
    optional = frozenset({"occupancy", "geometry", "semantics", "instances"})

    def export(self, data: PipelineData, out_dir: Path) -> list[Path]:
        cfg = self.config
        warn_renamed(self)
        messages = _Messages(_typestore(), cfg.frame_id)
        topics = self._topics(data, messages)
        if not topics:
            self.warn("the map has no occupancy, geometry or instances: no bag written")
            return []
        bag = out_dir / cfg.folder
        from rosbags.rosbag2 import Writer

        with atomic_directory(bag) as staging:
            inside = staging / bag.name  # rosbags creates the bag folder itself and names its file after it
            with Writer(inside, version=BAG_VERSION) as writer:
                for topic, msgtype, message in topics:
                    connection = writer.add_connection(
                        topic, msgtype, typestore=messages.ts, offered_qos_profiles=[_latched_qos()]
                    )
                    writer.write(connection, 0, messages.ts.serialize_cdr(message, msgtype))
            for entry in sorted(inside.iterdir()):
                shutil.move(str(entry), staging / entry.name)
            inside.rmdir()
        return sorted(p for p in bag.iterdir() if p.is_file())

    def _topics(self, data: PipelineData, messages: _Messages) -> list[tuple[str, str, Any]]:
        """(topic, message type, message) of everything the map has, in the order they are written."""
        cfg = self.config
        grid_type = "nav_msgs/msg/OccupancyGrid"
        topics: list[tuple[str, str, Any]] = []
        for layer, topic in cfg.grids.items():
            grid = data.map.occupancy.get(layer)
            if grid is None:
                self.warn(f"no occupancy layer {layer!r} (have: {sorted(data.map.occupancy)}); {topic} not written")
                continue
            topics.append((topic, grid_type, messages.occupancy_grid(grid, grid.data)))
        if cfg.costmap_layer is not None:
            grid = data.map.occupancy.get(cfg.costmap_layer)
            if grid is None:
                self.warn(f"no occupancy layer {cfg.costmap_layer!r} for the costmap; {cfg.costmap_topic} not written")
            else:
                inflation = cfg.inflation
                costs = costmap_values(
                    grid, inflation.inscribed_radius, inflation.inflation_radius, inflation.cost_scaling_factor
                )
                topics.append(
                    (cfg.costmap_topic, grid_type, messages.occupancy_grid(grid, occupancy_from_costs(costs)))
                )
        if data.map.geometry is not None and len(data.map.geometry):
            topics.append((cfg.cloud_topic, "sensor_msgs/msg/PointCloud2", messages.cloud(self._cloud_rows(data))))
        instances = data.map.instances
        if instances is not None and len(instances):
            topics.append((cfg.objects_topic, "visualization_msgs/msg/MarkerArray", self._markers(data, messages)))
            transforms = [messages.transform(object_frame(inst), self._object_pose(inst)) for inst in instances]
            topics.append(("/tf_static", "tf2_msgs/msg/TFMessage", messages.T["tf2_msgs/msg/TFMessage"](transforms)))
        return topics

    def _cloud_rows(self, data: PipelineData) -> np.ndarray:
        geometry, semantics = data.map.geometry, data.map.semantics
        assert geometry is not None
        rows = np.zeros(len(geometry), dtype=CLOUD_DTYPE)
        for axis, name in enumerate("xyz"):
            rows[name] = geometry.points[:, axis]
        labelled = semantics is not None and len(semantics) == len(geometry)
        if labelled:
            rows["class"] = semantics.class_ids
            rows["instance"] = semantics.instance_ids
        if geometry.colors is not None:
            rows["rgb"] = packed_rgb(geometry.colors)
        else:
            rows["rgb"] = packed_rgb(id_colors(rows["class"]))
        return rows

    @staticmethod
    def _object_pose(instance: Any) -> np.ndarray:
        """An object's frame: its completed model's pose, or its box's centre and yaw."""
        return instance.completion.pose if instance.completion is not None else instance.box.pose

    def _markers(self, data: PipelineData, messages: _Messages) -> Any:
        T, Marker = messages.T, messages.T["visualization_msgs/msg/Marker"]
        vocabulary = data.map.semantics.vocabulary if data.map.semantics is not None else data.map.vocabulary
        markers = []
        for inst in data.map.instances or []:
            class_id = vocabulary.id(inst.class_name) if inst.class_name in vocabulary else 0
            rgb = id_colors(np.array([class_id]))[0]
            box = inst.box
            markers.append(
                messages.marker("boxes", inst.id, Marker.CUBE, box.pose, box.size, messages.color(rgb, 0.35))
            )
            above = box.pose.copy()
            above[2, 3] = box.top_z + LABEL_HEIGHT
            markers.append(
                messages.marker(
                    "labels",
                    inst.id,
                    Marker.TEXT_VIEW_FACING,
                    above,
                    (0.0, 0.0, LABEL_HEIGHT),
                    messages.color((1.0, 1.0, 1.0), 1.0),
                    text=f"{inst.class_name} {inst.id}",
                )
            )
            if inst.completion is not None:
                mesh = inst.completion.world_mesh()
                corners = np.asarray(mesh.vertices)[np.asarray(mesh.faces).reshape(-1)]
                markers.append(
                    messages.marker(
                        "completions",
                        inst.id,
                        Marker.TRIANGLE_LIST,
                        np.eye(4),
                        (1.0, 1.0, 1.0),
                        messages.color(rgb, 1.0),
                        points=[messages.point(p) for p in corners],
                    )
                )
        return T["visualization_msgs/msg/MarkerArray"](markers=markers)


@hookimpl
def stratamap_register_exporters():
    return [Ros2BagExporter]
