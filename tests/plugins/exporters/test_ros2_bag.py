"""The ROS 2 bag exporter, read back with rosbags: every message deserialises, the grids equal the
map's layers cell for cell, the cloud has a point per geometry point with its class and instance,
objects come as markers and tf frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from stratamap.core.io.nav2 import costmap_values
from stratamap.core.stages import PipelineData
from stratamap.core.testing import example_data
from stratamap.plugins.exporters.ros2_bag import (
    Ros2BagExporter,
    object_frame,
    occupancy_from_costs,
)


def _read(bag: Path) -> dict[str, tuple[str, object]]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    messages = {}
    with Reader(bag) as reader:
        for connection, _, raw in reader.messages():
            assert connection.topic not in messages, f"{connection.topic} written twice"
            messages[connection.topic] = (connection.msgtype, typestore.deserialize_cdr(raw, connection.msgtype))
    return messages


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    data = example_data()
    out = tmp_path_factory.mktemp("ros2")
    files = Ros2BagExporter().run(data, out)
    return data, out / "ros2_bag", files


def test_bag_is_a_folder_ros2_bag_play_takes(exported):
    _, bag, files = exported
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "ros2_bag.db3"]
    assert sorted(files) == sorted(bag.iterdir())
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "sqlite3" and meta["relative_file_paths"] == ["ros2_bag.db3"]
    for topic in meta["topics_with_message_count"]:
        qos = yaml.safe_load(topic["topic_metadata"]["offered_qos_profiles"])
        assert qos[0]["durability"] == 1 and qos[0]["reliability"] == 1  # transient local, reliable: latched


def test_every_message_deserialises_with_its_type(exported):
    _, bag, _ = exported
    types = {topic: msgtype for topic, (msgtype, _) in _read(bag).items()}
    assert types == {
        "/map": "nav_msgs/msg/OccupancyGrid",
        "/multimap": "nav_msgs/msg/OccupancyGrid",
        "/costmap": "nav_msgs/msg/OccupancyGrid",
        "/stratamap/cloud": "sensor_msgs/msg/PointCloud2",
        "/stratamap/objects": "visualization_msgs/msg/MarkerArray",
        "/tf_static": "tf2_msgs/msg/TFMessage",
    }


def test_occupancy_grids_equal_the_layers_cell_for_cell(exported):
    data, bag, _ = exported
    messages = _read(bag)
    for topic, layer in (("/map", "slam"), ("/multimap", "multimap")):
        grid, msg = data.map.occupancy[layer], messages[topic][1]
        assert (msg.info.width, msg.info.height) == (grid.width, grid.height)
        assert msg.info.resolution == pytest.approx(grid.resolution)
        assert (msg.info.origin.position.x, msg.info.origin.position.y) == pytest.approx(grid.origin[:2])
        assert msg.header.frame_id == "map"
        np.testing.assert_array_equal(msg.data.reshape(grid.height, grid.width), grid.data)
    grid = data.map.occupancy["multimap"]
    costmap = messages["/costmap"][1].data.reshape(grid.height, grid.width)
    np.testing.assert_array_equal(costmap, occupancy_from_costs(costmap_values(grid, 0.2, 0.55, 10.0)))
    assert set(np.unique(costmap)) <= set(range(-1, 101)) and (costmap == 100).any()


def test_costs_translate_as_nav2_publishes_them():
    costs = np.array([0, 1, 128, 252, 253, 254, 255], np.uint8)
    assert occupancy_from_costs(costs).tolist() == [0, 1, 50, 98, 99, 100, -1]


def test_point_cloud_has_a_point_per_geometry_point_with_class_and_instance(exported):
    data, bag, _ = exported
    cloud = _read(bag)["/stratamap/cloud"][1]
    geometry, semantics = data.map.geometry, data.map.semantics
    assert cloud.width * cloud.height == len(geometry)
    fields = {f.name: (f.offset, f.datatype) for f in cloud.fields}
    assert fields == {"x": (0, 7), "y": (4, 7), "z": (8, 7), "rgb": (12, 7), "class": (16, 6), "instance": (20, 5)}
    dtype = np.dtype(
        {
            "names": list(fields),
            "formats": ["<f4", "<f4", "<f4", "<u4", "<u4", "<i4"],
            "offsets": [o for o, _ in fields.values()],
            "itemsize": cloud.point_step,
        }
    )
    rows = np.frombuffer(cloud.data.tobytes(), dtype=dtype)
    np.testing.assert_allclose(np.c_[rows["x"], rows["y"], rows["z"]], geometry.points, atol=1e-5)
    np.testing.assert_array_equal(rows["class"], semantics.class_ids)
    np.testing.assert_array_equal(rows["instance"], semantics.instance_ids)
    red = (rows["rgb"] >> 16) & 0xFF
    np.testing.assert_array_equal(red, np.round(geometry.colors[:, 0].astype(np.float64) * 255).astype(np.uint32))


def test_objects_are_boxes_models_labels_and_tf_frames(exported):
    data, bag, _ = exported
    messages = _read(bag)
    markers = messages["/stratamap/objects"][1].markers
    instances = list(data.map.instances)
    by_ns: dict[str, dict[int, object]] = {}
    for marker in markers:
        by_ns.setdefault(marker.ns, {})[marker.id] = marker
    assert set(by_ns["boxes"]) == set(by_ns["labels"]) == {o.id for o in instances}
    for obj in instances:
        box = by_ns["boxes"][obj.id]
        assert box.type == 1 and box.header.frame_id == "map"  # CUBE
        assert (box.scale.x, box.scale.y, box.scale.z) == pytest.approx(tuple(obj.box.size))
        assert (box.pose.position.x, box.pose.position.y, box.pose.position.z) == pytest.approx(tuple(obj.box.center))
        assert by_ns["labels"][obj.id].type == 9 and by_ns["labels"][obj.id].text == f"{obj.class_name} {obj.id}"
    completed = data.map.instances.completed()
    assert completed and set(by_ns["completions"]) == {o.id for o in completed}
    for obj in completed:
        model = by_ns["completions"][obj.id]
        assert model.type == 11 and len(model.points) == 3 * len(obj.completion.mesh.faces)  # TRIANGLE_LIST
    transforms = messages["/tf_static"][1].transforms
    assert {t.child_frame_id for t in transforms} == {object_frame(o) for o in instances}
    assert {t.header.frame_id for t in transforms} == {"map"}


def test_missing_layers_are_warnings_and_an_empty_map_writes_nothing(tmp_path):
    data = example_data(["geometry"])
    files = Ros2BagExporter().run(data, tmp_path)
    assert [p.name for p in files] == ["metadata.yaml", "ros2_bag.db3"]
    assert set(_read(tmp_path / "ros2_bag")) == {"/stratamap/cloud"}
    assert any("'slam'" in w for w in data.warnings) and any("costmap" in w for w in data.warnings)
    empty = PipelineData()
    assert Ros2BagExporter().run(empty, tmp_path / "empty") == [] and "no bag written" in empty.warnings[-1]
    assert not (tmp_path / "empty" / "ros2_bag").exists()


def test_folder_must_stay_inside_the_export_folder():
    for folder in ("../up", "/abs/bag", " "):
        with pytest.raises(ValidationError, match="inside the export folder"):
            Ros2BagExporter(folder=folder)
