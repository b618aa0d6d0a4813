"""configs/scan.yaml on PCL's real 360-degree room scan (every point stored twice, dense near the
scanner, seen through a door): floor, walls and ceiling are layout and never things, and the scene is
exported for simulators and navigation."""

from __future__ import annotations

import numpy as np

from stratamap.core.config import load_pipeline
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO, low_poly_room, shared_data


def test_a_real_room_scan_through_configs_scan_yaml(tmp_path):
    scan = shared_data("pcl_scenes", "room_scan1.pcd")
    out = tmp_path / "room"
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", [f"source.params.path={scan}"])).run(out)
    notes = report["notes"]["clusters"]["segments"]
    assert notes["floor_height"] is not None and notes["walls"] >= 4, notes
    m = LayeredMap.load(out / "map")
    vocab, z = m.semantics.vocabulary, m.geometry.points[:, 2]
    for name, at in (("floor", np.abs(z - notes["floor_height"]) < 0.05), ("ceiling", z > np.percentile(z, 99))):
        assert (m.semantics.class_ids[at] == vocab.id(name)).mean() > 0.8, name
    # No thing is a wall: each is at most 3 m long and 2.5 m high (the room is about 4.6 x 4.6 x 2.9 m;
    # before doors and windows counted, a wall and the desk before it were one 6.4 m thing).
    for inst in m.instances:
        assert max(inst.box.size[:2]) < 3.0 and inst.box.size[2] < 2.5, (inst.class_name, inst.box.size)
    for name in ("scene.urdf", "scene.glb", "map.yaml", "map.pgm", "scene_graph.json"):
        assert (out / "export" / name).is_file(), name


def test_a_low_poly_room_mesh_through_configs_scan_yaml(tmp_path):
    """A room mesh whose floor, walls and ceiling are two triangles each (72 vertices), stored as glTF
    (y up) with its origin outside the room: sampled on its surface, its floor is floor at z = 0, its
    four walls are found (looked at from the origin, as a scanner's cloud is, two were, and the rest of
    the room was one 5 m "object"), and its table is one table of its size; the scene is exported."""
    import trimesh

    mesh = low_poly_room()
    mesh.apply_translation((1.0, 1.0, 0.0))  # where a modeller put it: the file's origin is no viewpoint
    mesh.apply_transform([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
    path = tmp_path / "room.glb"
    trimesh.Scene([mesh]).export(path)
    out = tmp_path / "room"
    sets = [f"source.params.path={path}", "source.params.mesh_spacing=0.03"]  # 3 cm: half the points, same room
    report = Pipeline(load_pipeline(REPO / "configs" / "scan.yaml", sets)).run(out)
    notes = report["notes"]["clusters"]["segments"]
    assert notes["walls"] == 4 and abs(notes["floor_height"]) < 0.01, notes
    m = LayeredMap.load(out / "map")
    z = m.geometry.points[:, 2]
    assert (m.semantics.class_ids[np.abs(z) < 0.02] == m.semantics.vocabulary.id("floor")).mean() > 0.95
    tables = [inst for inst in m.instances if inst.class_name == "table"]
    assert len(tables) == 1 and np.allclose(sorted(tables[0].box.size), [0.72, 0.8, 1.2], atol=0.05)
    assert (out / "export" / "scene.urdf").is_file()
