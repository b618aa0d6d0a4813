"""configs/scan.yaml on PCL's real 360-degree room scan (every point stored twice, dense near the
scanner, seen through a door): floor, walls and ceiling are layout and never things, and the scene is
exported for simulators and navigation."""

from __future__ import annotations

import numpy as np

from stratamap.core.config import load_pipeline
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO, shared_data


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
