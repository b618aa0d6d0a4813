"""LayeredMap.save/load: lossless on every layer, atomic, and clear about broken directories."""

from __future__ import annotations

import json

import networkx as nx
import numpy as np
import pytest
import trimesh

from stratamap.core.errors import MapFormatError
from stratamap.core.map.layers import (
    Completion,
    ContactGraph,
    Geometry,
    Joint,
    LayeredMap,
    ObjectInstance,
    ObjectInstances,
    OccupancyGrid,
    OccupancyMaps,
    OrientedBox,
    Part,
    Semantics,
)
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.testing import fingerprint


def full_map(seed: int = 0) -> LayeredMap:
    rng = np.random.default_rng(seed)
    vocab = Vocabulary.default()
    pts = rng.normal(size=(500, 3))
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.visual.vertex_colors = rng.integers(0, 255, (len(mesh.vertices), 4), dtype=np.uint8)
    door = trimesh.creation.box((0.4, 0.02, 0.6))
    joint = Joint("door_hinge", "revolute", "body", "door", np.eye(4), np.array([0, 0, 1.0]), -1.57, 0.0)
    completion = Completion(
        mesh=trimesh.creation.box((0.5, 0.5, 0.8)),
        pose=np.array([[0, -1, 0, 1.0], [1, 0, 0, 2.0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float),
        completer="icp_match",
        model_id="cabinet_0001",
        scale=np.array([1.0, 1.1, 0.9]),
        score=0.87,
        parts=[Part("body", trimesh.creation.box((0.5, 0.5, 0.8))), Part("door", door, np.eye(4))],
        joints=[joint],
    )
    insts = ObjectInstances(
        [
            ObjectInstance(
                3,
                "cabinet",
                pts[:50],
                OrientedBox([1, 2, 0.4], 0.3, [0.5, 0.5, 0.8]),
                colors=rng.random((50, 3)),
                completion=completion,
                attributes={"visibility": 0.4},
            ),
            ObjectInstance(7, "chair", pts[50:90], OrientedBox([0, 0, 0.4], -1.0, [0.5, 0.5, 0.9]), score=0.5),
        ]
    )
    graph = ContactGraph()
    graph.support.add_node("floor", kind="layout", class_name="floor")
    graph.support.add_edge("scene", "floor")
    graph.support.add_node(3, kind="object", class_name="cabinet")
    graph.support.add_edge("floor", 3, plane=[0.0, 0.0, 1.0, 0.0])
    graph.proximal.add_edge(3, 7, relation="proximal")
    grid = OccupancyGrid(rng.choice(np.array([-1, 0, 100], np.int8), size=(40, 30)), 0.05, (-1.0, -2.0, 0.1))
    return LayeredMap(
        vocabulary=vocab,
        occupancy=OccupancyMaps(slam=grid, multimap=OccupancyGrid(np.zeros((5, 6), np.int8), 0.1)),
        geometry=Geometry(
            points=pts, colors=rng.random((500, 3)), normals=rng.random((500, 3)), mesh=mesh, voxel_size=0.02
        ),
        semantics=Semantics(rng.integers(0, len(vocab), 500), rng.integers(0, 9, 500), vocab),
        instances=insts,
        contact_graph=graph,
        augmented=Geometry(points=pts[:100]),
        provenance={"geometry": "tsdf", "instances": "icp_match"},
        metadata={"pipeline": "demo.yaml"},
    )


def test_round_trip_is_lossless_on_every_layer(tmp_path):
    m = full_map()
    m.save(tmp_path / "map")
    loaded = LayeredMap.load(tmp_path / "map")
    for layer in ("occupancy", "geometry", "semantics", "instances", "contact_graph", "augmented"):
        assert fingerprint(getattr(loaded, layer)) == fingerprint(getattr(m, layer)), layer
    assert loaded.provenance == m.provenance and loaded.metadata == m.metadata
    assert loaded.vocabulary == m.vocabulary
    c = loaded.instances[3].completion
    assert c.joints[0].type == "revolute" and c.joints[0].lower == -1.57
    assert [p.name for p in c.parts] == ["body", "door"]
    np.testing.assert_array_equal(loaded.geometry.mesh.visual.vertex_colors, m.geometry.mesh.visual.vertex_colors)
    assert nx.utils.graphs_equal(loaded.contact_graph.support, m.contact_graph.support)
    assert loaded.instances[7].completion is None


def test_fingerprint_sees_a_change(tmp_path):
    a, b = full_map(), full_map()
    b.geometry.points[0, 0] += 1e-9
    assert fingerprint(a.geometry) != fingerprint(b.geometry)


def test_empty_map_round_trips(tmp_path):
    LayeredMap().save(tmp_path / "m")
    loaded = LayeredMap.load(tmp_path / "m")
    assert loaded.geometry is None and not loaded.occupancy


def test_crash_mid_save_keeps_the_previous_map(tmp_path, monkeypatch):
    target = tmp_path / "map"
    full_map(0).save(target)
    before = fingerprint(LayeredMap.load(target).geometry)

    import stratamap.core.map.format as persistence

    real = persistence._save_npz
    calls = {"n": 0}

    def crashing(path, arrays):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full (simulated)")
        real(path, arrays)

    monkeypatch.setattr(persistence, "_save_npz", crashing)
    with pytest.raises(OSError, match="disk full"):
        full_map(1).save(target)
    monkeypatch.undo()
    # The old map is intact, and every file its manifest lists exists.
    loaded = LayeredMap.load(target)
    assert fingerprint(loaded.geometry) == before
    manifest = json.loads((target / "manifest.json").read_text())
    for entry in manifest["layers"].values():
        assert (target / entry["file"]).is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "staging folders left behind"


def test_load_errors_name_the_problem(tmp_path):
    with pytest.raises(MapFormatError, match="no manifest"):
        LayeredMap.load(tmp_path)
    full_map().save(tmp_path / "m")
    manifest = json.loads((tmp_path / "m" / "manifest.json").read_text())
    manifest["version"] = 99
    (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(MapFormatError, match="version 99"):
        LayeredMap.load(tmp_path / "m")
    manifest["version"] = 1
    (tmp_path / "m" / "manifest.json").write_text(json.dumps(manifest))
    (tmp_path / "m" / "geometry.npz").unlink()
    with pytest.raises(MapFormatError, match="geometry.npz.*missing"):
        LayeredMap.load(tmp_path / "m")
    (tmp_path / "m" / "semantics.npz").write_bytes(b"not a zip")
    (tmp_path / "m" / "geometry.npz").write_bytes(b"")
    with pytest.raises(MapFormatError, match="geometry.npz"):
        LayeredMap.load(tmp_path / "m")
