"""configs/rgbd.yaml on the real office clip (align3d_office, 31 Kinect frames): the photograph-trained
detector with depth segmentation finds the red chair and the round table, nothing else of furniture
size, and the floor."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.config import load_pipeline
from stratamap.core.map.layers import LayeredMap
from stratamap.core.map.priors import CLASS_SIZES
from stratamap.core.pipeline import Pipeline
from tests.conftest import REPO, shared_data

FURNITURE = {"chair", "table", "desk", "cabinet", "shelf", "counter", "sofa", "bench", "fridge", "oven"}


@pytest.fixture(scope="module")
def office_map(tmp_path_factory):
    clip = shared_data("align3d_office")
    out = tmp_path_factory.mktemp("rgbd_office")
    report = Pipeline(load_pipeline(REPO / "configs" / "rgbd.yaml", [f"source.params.path={clip}"])).run(out)
    return LayeredMap.load(out / "map"), report, out


def test_one_chair_and_one_table_where_they_stand(office_map):
    m, _, _ = office_map
    by_class = {}
    for inst in m.instances:
        by_class.setdefault(inst.class_name, []).append(inst)
    assert len(by_class.get("chair", [])) == 1 and len(by_class.get("table", [])) == 1, {
        k: len(v) for k, v in by_class.items()
    }
    chair, table = by_class["chair"][0], by_class["table"][0]
    # the chair is the red one: its points are red-dominant; the table (pale wood under white paper) is not
    r, g, b = np.median(chair.colors, axis=0)
    assert r > 1.15 * g and r > 1.15 * b, (r, g, b)
    r, g, b = np.median(table.colors, axis=0)
    assert not (r > 1.15 * g and r > 1.15 * b), (r, g, b)
    # and they are two objects, side by side, not one inside the other
    assert np.linalg.norm(chair.box.center[:2] - table.box.center[:2]) > 0.2
    # real sizes: a chair under 1.1 m tall standing on the floor; a table top at table height
    assert chair.points[:, 2].min() < 0.1 and chair.points[:, 2].max() < 1.1
    assert 0.55 < np.percentile(table.points[:, 2], 98) < 0.85
    for inst in (chair, table):
        reach = np.linalg.norm(inst.points - inst.points.mean(0), axis=1).max()
        assert reach <= CLASS_SIZES[inst.class_name].extent[1] * 1.3


def test_no_other_furniture_and_the_floor_is_floor(office_map):
    m, _, _ = office_map
    others = [
        (i.class_name, len(i.points))
        for i in m.instances
        if i.class_name in FURNITURE and i.class_name not in ("chair", "table") and len(i.points) > 500
    ]
    assert not others
    sem, pts = m.semantics, m.geometry.points
    floor = pts[:, 2] < 0.03
    assert floor.sum() > 500
    assert (sem.class_ids[floor] == sem.vocabulary.id("floor")).mean() > 0.8
    assert not np.isin(sem.class_ids, [sem.vocabulary.id(n) for n in ("floor", "wall", "ceiling")])[
        sem.instance_ids > 0
    ].any()


def test_every_export_of_the_user_pipeline_is_written(office_map):
    _, report, out = office_map
    for rel in ("scene.urdf", "scene.xml", "scene.sdf", "scene.glb", "map.yaml", "costmap.yaml", "scene_graph.json"):
        assert (out / "export" / rel).is_file(), rel
    assert report["notes"]["detector"]["model"]["detections"]["chair"] >= 31
