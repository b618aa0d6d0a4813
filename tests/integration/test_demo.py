"""The demo pipeline end to end (smaller images), and its outputs opened by the software robots run."""

from __future__ import annotations

import json
import sys
from importlib.metadata import EntryPoint

import numpy as np
import pytest

from stratamap.core.config import load_pipeline
from stratamap.core.io.nav2 import read_map
from stratamap.core.map.instances import naming_text
from stratamap.core.map.layers import LayeredMap
from stratamap.core.pipeline import Pipeline
from stratamap.core.registry import build_registry
from stratamap.core.simulation.kinematics import DEFAULT_MOVABLE_CLASSES
from stratamap.core.simulation.rest import rest_offsets
from stratamap.core.simulation.structure import room_structure
from tests.conftest import REPO

SMALL = ["source.params.frames=16", "source.params.scene.camera={width: 320, height: 240}"]


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    report = Pipeline(load_pipeline(REPO / "configs" / "demo.yaml", SMALL)).run(out)
    return out, report


def test_demo_writes_the_documented_layout(demo_run):
    out, report = demo_run
    for rel in ("map/manifest.json", "export/scene.urdf", "export/map.yaml", "export/map.pgm", "report.json"):
        assert (out / rel).is_file(), rel
    on_disk = json.loads((out / "report.json").read_text())
    assert on_disk["stages"][0] == {**on_disk["stages"][0], "plugin": "synthetic"}
    assert all({"name", "plugin", "seconds"} <= set(s) for s in on_disk["stages"])
    assert on_disk["layers"]["instances"]["objects"] >= 4
    det = on_disk["metrics"]["detection"]
    assert {"precision", "recall", "f1"} <= set(det)
    assert det["f1"] >= 0.9, det  # oracle labels on a clean synthetic room


def test_saved_map_loads_with_every_layer(demo_run):
    out, _ = demo_run
    m = LayeredMap.load(out / "map")
    assert m.geometry is not None and len(m.geometry) > 1000 and m.geometry.mesh is not None
    assert m.semantics is not None and len(m.semantics) == len(m.geometry)
    assert m.instances is not None and all(i.completion is not None for i in m.instances)
    assert m.contact_graph is not None and m.contact_graph.is_tree()
    assert set(m.occupancy) == {"slam", "objects", "multimap"}
    assert m.provenance["instances"] == "bbox" and m.provenance["geometry"] == "tsdf"


def test_nav2_files_round_trip_to_the_occupancy_layer(demo_run):
    out, _ = demo_run
    m = LayeredMap.load(out / "map")
    for layer, name in (("slam", "map"), ("multimap", "multimap")):
        grid = read_map(out / "export" / f"{name}.yaml")
        np.testing.assert_array_equal(grid.data, m.occupancy[layer].data)
        assert grid.origin == m.occupancy[layer].origin


def test_multimap_marks_what_the_laser_misses(demo_run):
    out, _ = demo_run
    slam = read_map(out / "export" / "map.yaml").data
    multi = read_map(out / "export" / "multimap.yaml").data
    assert ((multi == 100) & (slam == 0)).sum() > 20  # tabletops and chair seats above the laser
    assert not ((slam == 100) & (multi != 100)).any()


def test_contact_graph_puts_boxes_on_the_table(demo_run):
    out, _ = demo_run
    m = LayeredMap.load(out / "map")
    g = m.contact_graph
    for inst in m.instances:
        parent = g.parent(inst.id)
        if inst.class_name == "box":
            assert m.instances[parent].class_name == "table"
        else:
            assert parent == "floor"


def test_urdf_parses_with_yourdfpy_and_loads_in_pybullet(demo_run):
    yourdfpy = pytest.importorskip("yourdfpy")
    pybullet = pytest.importorskip("pybullet")
    out, _ = demo_run
    urdf_path = out / "export" / "scene.urdf"
    robot = yourdfpy.URDF.load(str(urdf_path), build_scene_graph=True, load_meshes=True)
    assert robot.validate()
    m = LayeredMap.load(out / "map")
    # One link per object, plus the world and the static floor, walls and ceiling.
    links = {link.name for link in robot.robot.links}
    objects = {f"{inst.class_name}_{inst.id}" for inst in m.instances}
    structure = links - objects - {"world"}
    assert objects <= links and "floor" in structure
    assert all(name in ("floor", "ceiling") or name.startswith("wall_") for name in structure), sorted(structure)
    # Every link's mesh, placed by the URDF's joints, sits where the map's completion is, moved by the
    # rest plan's settling (a few millimetres) if it is a free body.
    plan = rest_offsets(m.instances, m.contact_graph, DEFAULT_MOVABLE_CLASSES, room_structure(m))
    assert max(np.linalg.norm(v) for v in plan.offsets.values()) < 0.01
    for inst in m.instances:
        name = f"{inst.class_name}_{inst.id}"
        settle = np.eye(4)
        settle[:3, :3] = plan.rotations.get(inst.id, np.eye(3))
        settle[:3, 3] = plan.offsets.get(inst.id, np.zeros(3))
        np.testing.assert_allclose(robot.get_transform(name, "world"), settle @ inst.completion.pose, atol=1e-5)
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf_path), useFixedBase=True, physicsClientId=client)
        assert pybullet.getNumJoints(body, physicsClientId=client) == len(links) - 1
    finally:
        pybullet.disconnect(client)


def test_template_plugin_swaps_in_for_bbox(tmp_path, monkeypatch):
    """The example third-party package, registered by entry point, replaces bbox in the demo."""
    monkeypatch.syspath_prepend(str(REPO / "examples" / "plugin-template"))
    sys.modules.pop("stratamap_hull", None)
    eps = [EntryPoint("hull", "stratamap_hull", "stratamap.completers")]
    registry = build_registry(eps=eps, extra_modules=[], autoload=True)
    validated = load_pipeline(REPO / "configs" / "demo.yaml", [*SMALL, "stages[2].plugin=hull"], registry)
    report = Pipeline(validated, registry).run(tmp_path)
    assert [s["plugin"] for s in report["stages"]][3] == "hull"
    m = LayeredMap.load(tmp_path / "map")
    assert {i.completion.completer for i in m.instances} == {"hull"}


def test_report_html_is_self_contained_and_lists_every_object(demo_run):
    """report.html beside report.json: figures embedded (no network), one table row per object of
    the saved map, with its class and supporter, and every stage."""
    import re
    from html.parser import HTMLParser

    out, report = demo_run
    page = (out / "report.html").read_text()
    images = re.findall(r'<img[^>]*src="([^"]+)"', page)
    assert len(images) == 3 and all(src.startswith("data:image/png;base64,") for src in images)
    assert "http://" not in page and "https://" not in page

    class Rows(HTMLParser):
        def __init__(self):
            super().__init__()
            self.tables, self.table, self.cell = {}, None, None

        def handle_starttag(self, tag, attrs):
            if tag == "table":
                self.table = self.tables.setdefault(dict(attrs).get("class"), [])
            elif tag == "tr" and self.table is not None:
                self.table.append([])
            elif tag in ("td", "th"):
                self.cell = ""

        def handle_data(self, data):
            if self.cell is not None:
                self.cell += data

        def handle_endtag(self, tag):
            if tag in ("td", "th") and self.table is not None:
                self.table[-1].append(self.cell)
                self.cell = None
            elif tag == "table":
                self.table = None

    parser = Rows()
    parser.feed(page)
    header, *rows = parser.tables["objects"]
    saved = LayeredMap.load(out / "map")
    by_id = {int(r[header.index("id")]): r for r in rows}
    assert sorted(by_id) == sorted(inst.id for inst in saved.instances)
    for inst in saved.instances:
        assert by_id[inst.id][header.index("class")] == inst.class_name
        # How it got its class: the oracle's labels, fused by the TSDF, said in the saved map and the page.
        assert by_id[inst.id][header.index("named by")] == naming_text(inst)
        assert naming_text(inst) == "labels: the oracle segmenter's labels of each frame, fused in the TSDF"
    assert {r[header.index("supporter")] for r in rows} >= {"floor"}
    stage_rows = parser.tables["stages"][1:]
    assert [r[1] for r in stage_rows] == [s["plugin"] for s in report["stages"]]


def test_report_colours_every_default_class_apart():
    """The report's top-down map by class: each class of the default vocabulary has its own colour
    (with 20 colours, `object` was drawn in `floor`'s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stratamap.core.evaluation.html_report import _palette
    from stratamap.core.map.vocabulary import Vocabulary

    palette = _palette(plt)
    ids = np.arange(len(Vocabulary.default().names))
    assert len({tuple(c) for c in palette[ids % len(palette)]}) == len(ids)
