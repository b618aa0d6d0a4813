"""The scene-graph exporter's Hydra format: spark_dsg loads it and finds every object with its
class and box, and the support relations between objects; the default output is unchanged."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from stratamap.core.errors import PluginError
from stratamap.core.testing import example_data
from stratamap.plugins.exporters.scene_graph import SceneGraphExporter

spark_dsg = pytest.importorskip("spark_dsg")


def test_default_writes_only_the_json_graph(tmp_path):
    files = SceneGraphExporter().run(example_data(), tmp_path)
    assert [p.name for p in files] == ["scene_graph.json"]


@pytest.mark.parametrize("filename", ["dsg.json", "dsg.sparkdsg"])
def test_spark_dsg_finds_every_object_with_class_and_box(tmp_path, filename):
    data = example_data()
    files = SceneGraphExporter(formats=["json", "hydra"], hydra_filename=filename).run(data, tmp_path)
    assert [p.name for p in files] == ["scene_graph.json", filename]
    graph = spark_dsg.DynamicSceneGraph.load(tmp_path / filename)
    layer = graph.get_layer_key(spark_dsg.DsgLayers.OBJECTS)
    labelspace = graph.get_labelspace(layer.layer, layer.partition)
    vocabulary = data.map.semantics.vocabulary
    instances = list(data.map.instances)
    assert graph.num_nodes() == len(instances)
    for obj in instances:
        node = graph.get_node(spark_dsg.NodeSymbol("O", obj.id))
        attrs = node.attributes
        assert attrs.name == obj.class_name
        assert attrs.semantic_label == vocabulary.id(obj.class_name)
        assert labelspace.get_category(attrs.semantic_label) == obj.class_name
        box = attrs.bounding_box
        assert box.type == spark_dsg.BoundingBoxType.OBB
        np.testing.assert_allclose(box.dimensions, obj.box.size, atol=1e-5)
        np.testing.assert_allclose(box.world_P_center, obj.box.center, atol=1e-5)
        np.testing.assert_allclose(box.world_R_center, obj.box.pose[:3, :3], atol=1e-5)
        np.testing.assert_allclose(attrs.position, obj.box.center)
        assert attrs.metadata.get()["instance_id"] == obj.id

    support = {
        (int(a), int(b))
        for a, b in data.map.contact_graph.support.edges()
        if isinstance(a, (int, np.integer)) and isinstance(b, (int, np.integer))
    }
    assert support  # the reference scene has an object standing on another
    edges = {
        (spark_dsg.NodeSymbol(e.source).category_id, spark_dsg.NodeSymbol(e.target).category_id): e.info.metadata.get()
        for e in graph.edges
    }
    found = {pair for pair, meta in edges.items() if meta["relation"] == "support"}
    assert found == support
    for parent, child in support:  # and the supported object names its supporter
        meta = graph.get_node(spark_dsg.NodeSymbol("O", child)).attributes.metadata.get()
        assert meta["supported_by"] == str(parent)


def test_hydra_graph_is_deterministic(tmp_path):
    params = {"formats": ["hydra"]}
    a = SceneGraphExporter(**params).run(example_data(), tmp_path / "a")
    b = SceneGraphExporter(**params).run(example_data(), tmp_path / "b")
    assert a[0].read_bytes() == b[0].read_bytes()


def test_missing_spark_dsg_is_an_install_hint(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "spark_dsg", None)
    with pytest.raises(PluginError, match=r"pip install 'stratamap\[hydra\]'"):
        SceneGraphExporter(formats=["hydra"]).run(example_data(), tmp_path)


def test_without_instances_the_hydra_graph_is_a_warning(tmp_path):
    data = example_data(["contact_graph"])
    assert SceneGraphExporter(formats=["hydra"]).run(data, tmp_path) == []
    assert "no instances layer" in data.warnings[-1]
