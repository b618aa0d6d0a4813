"""plane_crf: procedural kitchens, virtual scans with ground truth, planes, fixtures, the CRF,
hinges, Table IV metrics, and the segmenter end to end (real apartment when ../shared is there)."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from stratamap.core.evaluation.classification import kitchen_tables, per_label
from stratamap.core.furniture import faces
from stratamap.core.furniture.crf import CRF
from stratamap.core.furniture.fixtures import Fixture, fit_circle, fit_line
from stratamap.core.io.urdf import read_urdf
from stratamap.core.simulation import virtual_scan as ks
from stratamap.core.synthetic.kitchens import generate_kitchen
from stratamap.plugins.segmenters.plane_crf import fronts as fu
from stratamap.plugins.segmenters.plane_crf.planes import boundary_points, multilod_planes, region_grow
from tests.conftest import REPO

APARTMENT = REPO.parent / "shared" / "data" / "iai_apartment" / "urdf" / "apartment.urdf"


def _kitchen(seed: int, tmp_path: Path, resolution: float = 0.8):
    layout = generate_kitchen(seed)
    path = tmp_path / f"k{seed}.urdf"
    path.write_text(layout.urdf)
    scene = ks.kitchen_from_urdf(read_urdf(path))
    ks.add_room(scene, layout.room)
    scan = ks.virtual_scan(scene, layout.viewpoints, resolution_deg=resolution, seed=seed)
    return layout, scene, scan, ks.label_points(scene, scan)


def test_procedural_kitchens_are_deterministic_urdf_with_drawers_and_doors(tmp_path):
    a, b = generate_kitchen(5), generate_kitchen(5)
    assert a.urdf == b.urdf and generate_kitchen(6).urdf != a.urdf
    path = tmp_path / "k.urdf"
    path.write_text(a.urdf)
    model = read_urdf(path)
    kinds = [j.type for j in model.joints]
    assert kinds.count("prismatic") >= 2 and kinds.count("revolute") >= 2
    assert not model.warnings


def test_scan_labels_follow_the_geometry(tmp_path):
    layout, scene, scan, labels = _kitchen(1, tmp_path)
    z = scan.points[:, 2]
    floor = labels.level1 == ks.LEVEL1.index("floor")
    ceiling = labels.level1 == ks.LEVEL1.index("ceiling")
    table = labels.level1 == ks.LEVEL1.index("table")
    assert floor.sum() > 1000 and np.abs(z[floor]).max() < 0.02
    assert np.abs(z[ceiling] - layout.room[4]).max() < 0.02
    assert 0.3 < np.median(z[table]) < 1.5  # counter tops and tables
    # level-2 labels only on furniture faces, and every scanned front has a normal
    assert np.all(labels.level1[labels.level2 >= 0] == ks.LEVEL1.index("furniture"))
    seen = {int(f) for f in np.unique(labels.front[labels.front >= 0])}
    assert seen and all(scene.fronts[k].normal is not None for k in seen)


def test_door_hinges_lie_opposite_their_handles(tmp_path):
    """The generator puts a door's handle away from its hinge; the ground truth must agree."""
    _, scene, scan, labels = _kitchen(2, tmp_path)
    checked = 0
    for k, front in enumerate(scene.fronts):
        if front.hinge not in ("left", "right"):
            continue
        handle = (labels.front == k) & np.array([scene.parts[p].role == "handle" for p in scan.part])
        face = (labels.front == k) & ~handle
        if handle.sum() < 5 or face.sum() < 50:
            continue
        right = np.cross(-front.normal, [0.0, 0.0, 1.0])
        offset = (scan.points[handle].mean(0) - scan.points[face].mean(0)) @ right
        assert (offset > 0) == (front.hinge == "left"), front.name
        checked += 1
    assert checked >= 2


def _box_room(rng, step=0.01):
    """Points on the inside of a 3 x 2 x 2.5 m box: floor, ceiling and four walls."""
    g = np.arange(0, 1, step)
    faces = []
    for axis, value in itertools.product(range(3), (0, 1)):
        a, b = [x for x in range(3) if x != axis]
        u, v = np.meshgrid(g, g)
        p = np.zeros((u.size, 3))
        p[:, a], p[:, b], p[:, axis] = u.ravel(), v.ravel(), value
        faces.append(p * [3.0, 2.0, 2.5])
    pts = np.vstack(faces) + rng.normal(0, 0.002, (sum(len(f) for f in faces), 3))
    return pts


def test_multilod_planes_find_the_six_faces_of_a_room():
    rng = np.random.default_rng(0)
    pts = _box_room(rng)
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.1, max_nn=30))
    planes = multilod_planes(pts, np.asarray(pcd.normals), threshold=0.02, min_points=50)
    big = [p for p in planes if len(p.indices) > 500]
    assert len(big) == 6
    normals = np.abs(np.array([p.normal for p in big])).round(2)
    assert sorted(map(tuple, normals)) == sorted([(1.0, 0.0, 0.0)] * 2 + [(0.0, 1.0, 0.0)] * 2 + [(0.0, 0.0, 1.0)] * 2)


def test_boundary_points_are_the_rim_and_stop_region_growing():
    g = np.arange(0, 1, 0.02)
    u, v = np.meshgrid(g, g)
    square = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    rim = boundary_points(square, np.array([0, 0, 1.0]), radius=0.05)
    on_edge = (square[:, 0] < 0.01) | (square[:, 0] > 0.97) | (square[:, 1] < 0.01) | (square[:, 1] > 0.97)
    assert rim[on_edge].mean() > 0.9 and rim[~on_edge].mean() < 0.05
    two = np.vstack([square, square + [1.2, 0, 0]])
    labels = region_grow(two, boundary_points(two, np.array([0, 0, 1.0]), 0.05), radius=0.05)
    assert len(np.unique(labels)) == 2 and len(np.unique(labels[: len(square)])) == 1


def test_line_and_circle_fits_recover_handles_and_knobs():
    rng = np.random.default_rng(1)
    d = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    t = rng.uniform(-0.1, 0.1, 200)
    pts = np.array([0.3, 0.1, 0.9]) + t[:, None] * d + rng.normal(0, 0.002, (200, 3))
    pts = np.vstack([pts, rng.uniform(-0.2, 0.2, (20, 3)) + [0.3, 0.1, 0.9]])  # outliers
    p0, direction, inl = fit_line(pts, threshold=0.008)
    assert abs(abs(direction @ d) - 1) < 1e-3 and inl[:200].mean() > 0.95
    assert np.linalg.norm(np.cross(p0 - [0.3, 0.1, 0.9], d)) < 0.003
    a = rng.uniform(0, 2 * np.pi, 100)
    uv = np.c_[0.2 + 0.018 * np.cos(a), -0.4 + 0.018 * np.sin(a)] + rng.normal(0, 0.0005, (100, 2))
    c, r, rms = fit_circle(uv)
    assert np.allclose(c, [0.2, -0.4], atol=1e-3) and abs(r - 0.018) < 1e-3 and rms < 1e-3


def test_crf_learns_pairwise_agreement_and_bp_is_exact_on_a_chain():
    rng = np.random.default_rng(0)
    graphs = []
    for _ in range(40):
        y = np.repeat(rng.integers(0, 3, 4), 5)
        X = np.c_[np.eye(3)[y] * 0.6 + rng.normal(0, 0.5, (20, 3)), np.ones(20)]
        graphs.append((X, np.c_[np.arange(19), np.arange(1, 20)], np.zeros(19, int), y))
    crf = CRF(("a", "b", "c"), 4, 1).fit(graphs[:30], l2=0.1, edge_l2=0.1)
    unary = np.mean([(crf.node_scores(X).argmax(1) == y).mean() for X, _, _, y in graphs[30:]])
    joint = np.mean([(crf.predict(X, E, r) == y).mean() for X, E, r, y in graphs[30:]])
    assert np.all(np.diag(crf.edge_weights[0]) > 0) and joint > unary + 0.05
    # max-product BP on a tree finds the exact maximum (brute force on 6 nodes)
    X, E, r = graphs[30][0][:6], np.c_[np.arange(5), np.arange(1, 6)], np.zeros(5, int)

    def score(y):
        return crf.node_scores(X)[np.arange(6), y].sum() + sum(crf.edge_weights[0, y[a], y[b]] for a, b in E)

    best = max(itertools.product(range(3), repeat=6), key=lambda y: score(np.array(y)))
    assert np.isclose(score(crf.predict(X, E, r, iterations=50)), score(np.array(best)))


def _front(u, z, fixtures, face=None):
    return faces.FrontCandidate(0, 0, np.arange(10), np.array([1.0, 0, 0]), -0.5, u, z, face or u, fixtures)


def test_hinge_opposite_the_handle_and_flaps_hinge_on_top():
    # face normal +x: facing it, +y is to the right
    right_handle = Fixture("handle", np.array([0.52, 0.55, 0.8]), np.array([0, 0, 1.0]), 0.15)
    assert faces.hinge_side(_front((0.0, 0.6), (0.1, 0.9), [right_handle])) == "left"
    left_handle = Fixture("handle", np.array([0.52, 0.05, 0.8]), np.array([0, 0, 1.0]), 0.15)
    assert faces.hinge_side(_front((0.0, 0.6), (0.1, 0.9), [left_handle])) == "right"
    top_centre = Fixture("handle", np.array([0.52, 0.3, 0.85]), np.array([0, 1.0, 0]), 0.3)
    assert faces.hinge_side(_front((0.0, 0.6), (0.1, 0.9), [top_centre])) == "bottom"  # a dishwasher
    assert faces.hinge_side(_front((0.0, 1.0), (1.5, 1.9), [])) == "top"  # a flap without handle
    assert faces.hinge_side(_front((0.4, 0.8), (0.1, 0.9), [], face=(0.0, 0.8))) == "right"  # at the face's right end


def test_a_cupboard_door_with_a_centred_handle_hinges_on_a_side_an_appliance_door_at_the_bottom():
    """A centred handle near the top of a tall front: the oven's or dishwasher's door the CRF labels
    an appliance hinges at the bottom; a cupboard door with such a handle (the real kitchen's base
    units) on a side, where its face ends, not at the bottom, where it would swing 0.7 m out."""
    top_centre = Fixture("handle", np.array([0.52, 0.225, 0.85]), np.array([0, 1.0, 0]), 0.12)
    appliance = _front((0.0, 0.45), (0.1, 0.9), [top_centre])
    appliance.label = "appliance"
    assert faces.hinge_side(appliance) == "bottom"
    door = _front((0.0, 0.45), (0.1, 0.9), [top_centre])
    door.label = "cupboard"
    assert faces.hinge_side(door) == "left"
    centred = Fixture("handle", np.array([0.52, 0.575, 0.85]), np.array([0, 1.0, 0]), 0.12)
    door_at_the_right_end = _front((0.35, 0.8), (0.1, 0.9), [centred], face=(0.0, 0.8))
    door_at_the_right_end.label = "cupboard"
    assert faces.hinge_side(door_at_the_right_end) == "right"
    # Square and wide cupboard fronts keep the handle's word: a flap with its handle centred below.
    flap = _front((0.0, 0.8), (1.5, 1.9), [Fixture("handle", np.array([0.52, 0.4, 1.55]), np.array([0, 1.0, 0]), 0.2)])
    flap.label = "cupboard"
    assert faces.hinge_side(flap) == "top"


def test_table_iv_counts_segments_and_fronts():
    t = per_label(["floor", "table", "table", "ceiling"], ["floor", "table", "floor", "ceiling"], ks.LEVEL1_HORIZONTAL)
    assert t["table"]["precision"] == 0.5 and t["floor"]["recall"] == 0.5 and t["ceiling"]["f1"] == 1.0
    # two segments (floor, wall) and one drawer front, predicted right; one door hinge wrong
    n = 300
    t1 = np.r_[np.zeros(n), np.full(n, 3), np.full(n, 4)].astype(int)
    seg = np.r_[np.zeros(n), np.ones(n), np.full(n, 2)].astype(int)
    t2 = np.r_[np.full(2 * n, -1), np.full(n, 1)]
    tf = np.r_[np.full(2 * n, -1), np.zeros(n)].astype(int)
    tables = kitchen_tables(
        t1,
        seg,
        t2,
        tf,
        {0: "left"},
        t1,
        t2,
        tf,
        [{"name": "d", "kind": "drawer", "joint_type": "prismatic", "hinge": None}],
    )
    assert tables["horizontal"]["floor"]["f1"] == 1.0 and tables["vertical"]["macro_f1"] == 1.0
    assert tables["furniture"]["drawer"]["f1"] == 1.0 and tables["hinge"]["doors"] == 0


@pytest.mark.slow
def test_plane_crf_on_a_held_out_synthetic_kitchen(tmp_path):
    """The shipped CRFs on a kitchen never trained on (seed 3; training used 100+)."""
    from stratamap.core.config import validate
    from stratamap.core.pipeline import Pipeline

    doc = {
        "source": {"plugin": "urdf_scan", "params": {"synthetic_seed": 3, "resolution_deg": 0.5}},
        "stages": [{"plugin": "points", "params": {"normals_radius": 0.0}}, {"plugin": "plane_crf"}],
        "output": {"save_map": True},
    }
    pipeline = Pipeline(validate(doc))
    report = pipeline.run(tmp_path)
    data = pipeline.data
    t = report["metrics"]["classification"]
    assert t["horizontal"]["macro_f1"] >= 0.8 and t["vertical"]["macro_f1"] >= 0.8
    assert t["furniture"]["fronts"] >= 10 and t["hinge"]["doors"] >= 4
    drawers = [i for i in data.map.instances if i.class_name == "drawer"]
    assert drawers and all(i.attributes["joint"] == "prismatic" for i in drawers)
    assert data.map.semantics.plane_ids is not None and (data.map.semantics.plane_ids >= 0).mean() > 0.5
    from stratamap.core.map.layers import LayeredMap

    again = LayeredMap.load(tmp_path / "map")  # plane ids survive the map on disk
    assert np.array_equal(again.semantics.plane_ids, data.map.semantics.plane_ids)


def test_shipped_plane_crf_model_is_small_and_documented():
    path = REPO / "core" / "furniture" / "models" / "plane_crf.json"
    doc = json.loads(path.read_text())
    assert path.stat().st_size < 200_000
    assert doc["trained_on"].startswith("virtual laser scans") and "held_out" in doc
    assert (
        fu.level1_feature_count() == doc["level1"]["n_features"]
        and faces.level2_feature_count() == doc["level2"]["n_features"]
    )


@pytest.mark.skipif(not APARTMENT.exists(), reason="../shared/data/iai_apartment not available")
def test_apartment_kitchen_ground_truth_from_the_urdf():
    scene = ks.kitchen_from_urdf(read_urdf(APARTMENT), root_link="kitchen_root")
    kinds = {f.name: f.kind for f in scene.fronts}
    assert (
        kinds["cabinet5_drawer_top"] == "drawer"
        and kinds["cabinet1_door_top_left"] == "cupboard"
        and kinds["oven"] == "appliance"
    )
    ks.add_room(scene, (0.0, 0.0, 4.2, 5.0, 2.6))
    scan = ks.virtual_scan(scene, [[1.45, 2.6, 1.4]], resolution_deg=1.0)
    labels = ks.label_points(scene, scan)
    hinges = {f.name: f.hinge for f in scene.fronts}
    assert hinges["cabinet1_door_top_left"] == "left" and hinges["cabinet4_door_bottom"] == "top"
    assert (labels.level2 == ks.LEVEL2.index("drawer")).sum() > 1000


@pytest.mark.slow
@pytest.mark.skipif(not APARTMENT.exists(), reason="../shared/data/iai_apartment not available")
def test_plane_crf_on_the_real_apartment_kitchen(tmp_path):
    """configs/kitchen_planes.yaml as shipped: Table IV against the apartment's URDF."""
    from stratamap.core.config import load_pipeline
    from stratamap.core.pipeline import Pipeline

    report = Pipeline(load_pipeline(REPO / "configs" / "kitchen_planes.yaml", [f"source.params.path={APARTMENT}"])).run(
        tmp_path
    )
    t = report["metrics"]["classification"]
    assert t["horizontal"]["macro_f1"] >= 0.85 and t["vertical"]["macro_f1"] >= 0.85, t
    assert t["furniture"]["macro_f1"] >= 0.7 and t["hinge"]["accuracy"] >= 0.8, (t["furniture"], t["hinge"])
    assert (tmp_path / "export").is_dir()
