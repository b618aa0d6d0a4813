"""Mapping: panoptic TSDF fusion, Bayesian semantic fusion, instance post-processing, occupancy, metrics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
import trimesh
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.errors import ConfigError
from stratamap.core.evaluation.panoptic import panoptic_quality
from stratamap.core.evaluation.trajectory import ate, rpe, umeyama
from stratamap.core.geometry.transforms import make_pose
from stratamap.core.map.layers import Geometry, LayeredMap, Semantics
from stratamap.core.map.sensors import CameraIntrinsics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.pipeline import Pipeline
from stratamap.core.stages import PipelineData
from stratamap.plugins.mappers.instance_clusters import InstanceClustersMapper
from stratamap.plugins.mappers.tsdf import vote_stride
from tests.conftest import REPO, shared_data


def office_pipeline(tmp_path: Path, noise: str, mapper: list[dict]) -> dict:
    spec = yaml.safe_load((REPO / "configs" / "scenes" / "office.yaml").read_text())
    spec["noise"]["depth"] = noise
    spec["camera"].update(width=320, height=240)
    spec["seed"] = 3
    spec["trajectory"]["frames"] = 60
    doc = {
        "source": {"plugin": "synthetic", "params": {"scene": spec}},
        "stages": [{"plugin": "oracle"}, *mapper],
        "output": {"save_map": True},
    }
    path = tmp_path / "pipe.yaml"
    path.write_text(yaml.safe_dump(doc))
    return Pipeline(load_pipeline(path)).run(tmp_path / "out")


@pytest.mark.slow
@pytest.mark.parametrize(("noise", "minimum"), [("none", 0.8), ("kinect", 0.7)])
def test_panoptic_fusion_quality_with_the_oracle(tmp_path, noise, minimum):
    report = office_pipeline(tmp_path, noise, [{"plugin": "tsdf"}])
    pq = report["metrics"]["panoptic"]
    assert {"pq", "sq", "rq", "pq_things", "pq_stuff", "by_class"} <= set(pq)
    assert pq["pq"] >= minimum, pq
    assert report["metrics"]["instances"]["f1"] >= 0.7
    assert report["layers"]["instances"]["objects"] >= 15


@pytest.mark.slow
def test_mask_instances_lose_nothing_with_the_oracle(tmp_path):
    """The 'masks' extraction rebuilds the objects from ground-truth masks as 'labels' does."""
    report = office_pipeline(tmp_path, "kinect", [{"plugin": "tsdf", "params": {"instances": "masks"}}])
    assert report["metrics"]["panoptic"]["pq"] >= 0.7, report["metrics"]["panoptic"]
    assert report["metrics"]["instances"]["f1"] >= 0.7
    assert report["layers"]["instances"]["objects"] >= 15


@pytest.mark.parametrize(
    ("fx", "voxel_size", "depth_max"), [(532.6, 0.02, 5.0), (525.0, 0.01, 4.0), (1050.0, 0.02, 3.0), (300.0, 0.05, 8.0)]
)
def test_vote_stride_gives_every_voxel_in_range_a_vote(fx, voxel_size, depth_max):
    """'masks' counts one class vote per voxel per frame, so the sampling stride may be as wide as
    the voxels at depth_max allow, and no wider: a wall at that range is sampled in every voxel."""
    width, height = 320, 240
    intr = CameraIntrinsics(width, height, fx, fx, (width - 1) / 2, (height - 1) / 2)
    stride = vote_stride(None, intr, voxel_size, depth_max)
    assert stride * depth_max / fx <= voxel_size
    assert stride == 1 or (stride + 1) * depth_max / fx > voxel_size
    assert vote_stride(3, intr, voxel_size, depth_max) == 3

    wall = np.full((height, width), 0.999 * depth_max)

    def voxels(step):
        pts, _ = intr.backproject(wall, stride=step)
        return set(map(tuple, np.floor(pts[:, :2] / voxel_size).astype(int)))

    every, sampled = voxels(1), voxels(stride)
    # The strided grid stops up to stride - 1 pixels before the far image edges: ignore that rim.
    lo = np.min(list(every), axis=0) + 1
    hi = np.max(list(every), axis=0) - 1
    inner = {v for v in every if np.all(v >= lo) and np.all(v <= hi)}
    assert inner <= sampled
    if stride > 1:  # one pixel wider and whole columns of voxels go without a sample
        assert not inner <= voxels(stride + 1)


@pytest.mark.slow
def test_size_prior_names_a_misspelt_class_before_integrating(tmp_path):
    def masks(**pieces):
        return [{"plugin": "tsdf", "params": {"instances": "masks", "pieces": pieces}}]

    with pytest.raises(ConfigError, match=r"pieces\.max_length\.cupp"):
        office_pipeline(tmp_path, "none", masks(max_length={"cupp": 0.15}))
    with pytest.raises(ConfigError, match=r"pieces\.stacked_classes: 'chiar'"):
        office_pipeline(tmp_path, "none", masks(stacked_classes=["chair", "chiar"]))
    with pytest.raises(ConfigError, match=r"pieces\.min_points_by_class\.cupp"):
        office_pipeline(tmp_path, "none", masks(min_points_by_class={"cupp": 30}))
    with pytest.raises(ConfigError, match=r"pieces\.max_length"):
        office_pipeline(tmp_path, "none", masks(max_length={"cup": -0.15}))


@pytest.mark.slow
def test_semantic_tsdf_then_clusters_maps_objects(tmp_path):
    report = office_pipeline(tmp_path, "none", [{"plugin": "semantic_tsdf"}, {"plugin": "instance_clusters"}])
    assert report["metrics"]["panoptic"]["pq_stuff"] > 0.9
    assert report["metrics"]["panoptic"]["pq"] > 0.6
    m = LayeredMap.load(tmp_path / "out" / "map")
    assert m.provenance["semantics"] == "instance_clusters" and len(m.instances) >= 12


@pytest.mark.slow  # a whole pipeline run (make test runs it; make test-fast does not)
def test_geometry_of_the_real_office_is_gravity_aligned(tmp_path):
    seq = shared_data("align3d_office")
    report = Pipeline(load_pipeline(REPO / "configs" / "map_geometry.yaml", [f"source.params.path={seq}"])).run(
        tmp_path
    )
    mesh = trimesh.load(tmp_path / "export" / "geometry.ply")
    pts = np.asarray(mesh.vertices)
    low = pts[np.abs(pts[:, 2]) < 0.15]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(low))
    o3d.utility.random.seed(0)
    (a, b, c, d), inliers = pc.segment_plane(0.01, 3, 2000)
    n = np.array([a, b, c]) * np.sign(c)
    assert np.degrees(np.arccos(n[2] / np.linalg.norm(n))) < 3.0
    assert abs(d * np.sign(c) / np.linalg.norm([a, b, c])) < 0.02
    assert len(inliers) > 0.3 * len(low)
    assert report["notes"]["tum"]["gravity_alignment"]["realigned"] is True
    assert any("re-aligned" in w for w in report["warnings"])


@pytest.mark.slow
def test_laser_map_misses_seats_the_multimap_has(tmp_path):
    doc = {
        "source": {
            "plugin": "synthetic",
            "params": {
                "scene": {
                    "type": "room",
                    "seed": 5,
                    "camera": {"width": 160, "height": 120},
                    "trajectory": {"type": "orbit", "frames": 30},
                }
            },
        },
        "stages": [{"plugin": "oracle"}, {"plugin": "tsdf", "params": {"voxel_size": 0.03}}, {"plugin": "occupancy"}],
        "output": {"save_map": True},
    }
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    report = Pipeline(load_pipeline(tmp_path / "p.yaml")).run(tmp_path / "out")
    assert "log-odds" in report["notes"]["occupancy"]["slam_source"]
    m = LayeredMap.load(tmp_path / "out" / "map")
    slam, multi = m.occupancy["slam"], m.occupancy["multimap"]
    seats = [i for i in m.instances if i.class_name == "chair"]
    assert seats
    missed = 0
    for chair in seats:
        rc = slam.world_to_cell(chair.box.center[None, :2])[0]
        missed += slam.data[rc[0], rc[1]] == 0 and multi.data[rc[0], rc[1]] == 100
    assert missed >= 1  # the laser passes under the seat; the multimap does not


def test_panoptic_quality_on_hand_made_labels():
    vocab = Vocabulary.default()
    floor, chair = vocab.id("floor"), vocab.id("chair")
    gt_c = np.array([floor] * 10 + [chair] * 10 + [chair] * 10)
    gt_i = np.array([0] * 10 + [1] * 10 + [2] * 10)
    pred_c = gt_c.copy()
    pred_i = gt_i.copy() + 5  # ids need not agree, only segments
    res = panoptic_quality(pred_c, pred_i, gt_c, gt_i, vocab)
    assert res["pq"] == pytest.approx(1.0)
    pred_i[20:30] = 6  # two chairs predicted as one: IoU 0.5 -> no match, 1 FP, 2 FN
    res = panoptic_quality(pred_c, pred_i, gt_c, gt_i, vocab)
    assert (
        res["by_class"]["chair"]["tp"] == 0
        and res["by_class"]["chair"]["fn"] == 2
        and res["by_class"]["chair"]["fp"] == 1
    )
    assert res["by_class"]["floor"]["pq"] == pytest.approx(1.0)
    pred_i = gt_i + 5
    pred_i[10:12] = 9  # a sliver split off chair 1: IoU 0.8 still matches; the sliver is a false positive
    res = panoptic_quality(pred_c, pred_i, gt_c, gt_i, vocab)
    chair_stats = res["by_class"]["chair"]
    assert chair_stats["tp"] == 2 and chair_stats["fp"] == 1
    assert chair_stats["pq"] == pytest.approx((0.8 + 1.0) / (2 + 0.5))


def test_trajectory_errors():
    rng = np.random.default_rng(0)
    gt = [make_pose(rng.normal(size=3), rng.uniform(-3, 3)) for _ in range(20)]
    offset = make_pose((1.0, -2.0, 0.5), 0.7)
    moved = [offset @ p for p in gt]  # the same trajectory in another world frame
    assert ate(moved, gt)["ate_rmse_m"] < 1e-9
    assert rpe(moved, gt)["rpe_trans_rmse_m"] < 1e-9
    noisy = [p.copy() for p in moved]
    noisy[5][:3, 3] += [0.1, 0, 0]
    assert 0.01 < ate(noisy, gt)["ate_rmse_m"] < 0.1
    src = rng.normal(size=(30, 3))
    T = make_pose((0.3, 0.2, 0.1), 1.0)
    np.testing.assert_allclose(umeyama(src, src @ T[:3, :3].T + T[:3, 3]), T, atol=1e-9)


def test_shape_filter_rejects_planes_and_wrong_extents():
    vocab = Vocabulary.default()
    rng = np.random.default_rng(0)
    from stratamap.core.synthetic.models import make_model

    chair = trimesh.sample.sample_surface_even(make_model("four_leg_chair", 0, 0).mesh(), 4000, seed=0)[0]
    wall_bleed = np.c_[rng.uniform(2, 3, 800), np.full(800, 3.0), rng.uniform(0, 1, 800)]  # a flat patch of "chair"
    big_box = trimesh.creation.box((3.0, 3.0, 1.0), transform=make_pose((6.5, 6.5, 0.5)))
    huge = trimesh.sample.sample_surface_even(big_box, 20000, seed=0)[0]  # far too big to be a chair
    pts = np.vstack([chair, wall_bleed, huge])
    sem = Semantics(np.full(len(pts), vocab.id("chair")), np.zeros(len(pts), np.int32), vocab)
    data = PipelineData()
    data.map.geometry, data.map.semantics = Geometry(points=pts), sem
    out = InstanceClustersMapper().run(data)
    assert len(out["instances"]) == 1
    kept = out["instances"].ids()[0]
    assert (out["semantics"].instance_ids[: len(chair)] == kept).all()
    assert (out["semantics"].class_ids[len(chair) :] == 0).all()
    assert data.notes["instance_clusters"]["rejected"] == {"planar": 1, "extent": 1}


@pytest.mark.slow
def test_tum_pipeline_reports_panoptic_metrics(tmp_path):
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.core.synthetic.writer import write_sequence

    spec = SceneSpec.model_validate(
        {"type": "office", "seed": 2, "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 20}}
    )
    seq = write_sequence(SyntheticWorld(spec), tmp_path / "seq")
    report = Pipeline(load_pipeline(REPO / "configs" / "map_tum.yaml", [f"source.params.path={seq}"])).run(
        tmp_path / "out"
    )
    assert {"pq", "sq", "rq"} <= set(report["metrics"]["panoptic"])
    assert report["layers"]["instances"]["objects"] > 5
    assert (tmp_path / "out" / "export" / "geometry.ply").is_file()
    saved = json.loads((tmp_path / "out" / "report.json").read_text())
    assert saved["metrics"]["panoptic"]["pq"] == report["metrics"]["panoptic"]["pq"]


@pytest.mark.slow
def test_multimap_paths_avoid_what_laser_paths_hit(tmp_path):
    """A* for a 0.4 m robot: on the laser-only map some paths cross chairs' and tables' 3D
    footprints; on the multimap none does (first paper, section V-C)."""
    from stratamap.core.evaluation.navigation import evaluate_navigation

    report = office_pipeline(tmp_path, "none", [{"plugin": "tsdf"}, {"plugin": "occupancy"}])
    nav = report["metrics"]["navigation"]
    assert nav["paths"] >= 8
    m = LayeredMap.load(tmp_path / "out" / "map")
    truth = None
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld

    spec = yaml.safe_load((REPO / "configs" / "scenes" / "office.yaml").read_text())
    spec.update(seed=3)
    truth = SyntheticWorld(SceneSpec.model_validate(spec)).ground_truth().occupancy["objects"]
    full = evaluate_navigation(m.occupancy["slam"], m.occupancy["multimap"], truth, pairs=30)
    assert full["colliding_laser_only"] >= 1
    assert full["colliding_multimap"] == 0
    assert full["colliding_multimap"] < full["colliding_laser_only"]


def test_panoptic_fusion_keeps_instances_of_different_classes_apart():
    """A table segment reaching over a chair's voxels (a segmenter's class border off by a few
    pixels) must not take the chair's instance, and a label voted chair of one instance and table
    of another links neither (eq. 5 counts instance votes per class)."""
    from collections import Counter

    from stratamap.plugins.mappers.tsdf.panoptic_fusion import PanopticParams, PanopticState

    vocab = Vocabulary.default()
    chair, table = vocab.id("chair"), vocab.id("table")
    state = PanopticState(PanopticParams(), vocab)
    labels, conf = np.zeros(512, np.int32), np.zeros(512, np.int32)
    for _ in range(3):
        state.fuse_frame(
            labels, conf, np.arange(40), np.array([chair] * 30 + [table] * 10), np.array([1] * 30 + [2] * 10)
        )
    chair_inst = state.best_instance(int(labels[0]))
    table_inst = state.best_instance(int(labels[35]))
    # A new view: a table segment over ten chair voxels and five unseen voxels. It starts a label
    # of its own or joins the chair's; either way its instance is not the chair's.
    state.fuse_frame(
        labels, conf, np.concatenate([np.arange(20, 30), np.arange(100, 105)]), np.full(15, table), np.full(15, 7)
    )
    new_label = int(labels[100])
    assert all(pp != chair_inst for (c, pp) in state.phi[state.resolve(new_label)] if c == table)

    state.phi[90] = Counter({(chair, chair_inst): 3, (table, table_inst): 2})
    assert state.merge_instances() == {}
    state.phi[91] = Counter({(chair, chair_inst): 3, (chair, 99): 2})
    assert state.merge_instances() == {99: chair_inst}  # within one class, split votes still merge
    classes, instances = state.label_table()
    assert classes[labels[0]] == chair and classes[labels[35]] == table
    assert instances[labels[0]] == chair_inst and instances[labels[35]] == table_inst != chair_inst


@pytest.mark.parametrize("instances", ["labels", "masks"])
def test_a_frame_its_segmenter_labelled_nothing_is_still_integrated(instances):
    """A frame with valid depth and no label at all (a detector that found nothing, no plane in view)
    adds its depth and no votes; it must not stop the mapping."""
    from stratamap.core.map.sensors import FrameLabels
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.segmenters.oracle import OracleSegmenter
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "office", "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 8}}
    data = run_stages([SyntheticSource(scene=scene), OracleSegmenter()])
    points_when_labelled = len(run_stages([TSDFMapper(voxel_size=0.05, instances=instances)], data).map.geometry.points)
    frames = list(data.frame_labels.frames)
    frames[3].class_ids[:] = 0
    frames[3].instance_ids[:] = 0
    data.frame_labels = FrameLabels(data.frame_labels.segmenter, frames, data.frame_labels.tracked_instances)
    mapped = run_stages([TSDFMapper(voxel_size=0.05, instances=instances)], data)
    assert len(mapped.map.geometry.points) == points_when_labelled
    assert (mapped.map.semantics.class_ids > 0).mean() > 0.9


@pytest.mark.parametrize("frames", [1, 2, 3])
def test_a_sequence_of_fewer_frames_than_min_frames_still_makes_a_map(frames):
    """Open3D keeps voxels whose weight exceeds its threshold (3 by default: seen by 4 frames or more),
    which left a single RGB-D frame, or a clip of three, with an empty map. Fewer frames than
    ``min_frames`` keep what all of them saw."""
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "office", "camera": {"width": 160, "height": 120}, "trajectory": {"frames": frames}}
    data = run_stages([SyntheticSource(scene=scene), TSDFMapper(voxel_size=0.05)])
    geometry = data.map.geometry
    # The walk moves: what all three frames saw is less than one frame's view.
    assert len(geometry.points) > 300 and len(geometry.mesh.faces) > 300
    floor = np.abs(geometry.points[:, 2]) < 0.06
    assert floor.mean() > 0.1


@pytest.mark.parametrize("instances", ["labels", "masks"])
def test_a_clip_its_segmenter_labelled_nothing_in_maps_its_geometry(instances):
    """No frame has a label (a detector that found nothing in a tiny image, no plane in view): the map
    has its surfaces and no instance, and mapping does not stop."""
    from stratamap.core.map.sensors import FrameLabels
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.segmenters.oracle import OracleSegmenter
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "office", "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 6}}
    data = run_stages([SyntheticSource(scene=scene), OracleSegmenter()])
    frames = list(data.frame_labels.frames)
    for frame in frames:
        frame.class_ids[:] = 0
        frame.instance_ids[:] = 0
    data.frame_labels = FrameLabels(data.frame_labels.segmenter, frames, data.frame_labels.tracked_instances)
    mapped = run_stages([TSDFMapper(voxel_size=0.05, instances=instances)], data)
    assert len(mapped.map.geometry.points) > 500
    assert len(mapped.map.instances) == 0


def test_a_clip_whose_surfaces_no_min_frames_frames_saw_is_a_one_line_error():
    """Four tiny frames of a moving camera see no voxel four times: with min_frames alone
    (min_view_share 0) the map would be empty, and every stage after it would fail on that; tsdf says
    why instead, naming the setting. By default no more views are asked of a voxel than the typical
    surface voxel had, so the same clip makes a map, and the note says how many views it asked."""
    from stratamap.core.errors import DataError
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "meeting_room", "camera": {"width": 48, "height": 36}, "trajectory": {"frames": 4}}
    data = run_stages([SyntheticSource(scene=scene)])
    with pytest.raises(DataError, match=r"tsdf: no surface of .* was seen by 4 of its 4 frames \(min_frames\)") as err:
        run_stages([TSDFMapper(voxel_size=0.02, min_view_share=0.0)], data)
    assert "\n" not in str(err.value)
    assert len(run_stages([TSDFMapper(voxel_size=0.02, min_frames=1)], data).map.geometry.points) > 0
    mapped = run_stages([TSDFMapper(voxel_size=0.02)], data)
    assert len(mapped.map.geometry.points) > 0 and mapped.notes["tsdf"]["surface_views_needed"] < 4


@pytest.mark.slow
def test_a_sparse_walk_keeps_the_surfaces_its_frames_saw():
    """A walk of 8 frames through an office sees its typical surface about twice: min_frames (4) alone
    kept little of its map; asking no more views than the typical surface had keeps most of it. The
    same walk in 40 frames asks min_frames, and keeps the same map as before."""
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "office", "seed": 4, "camera": {"width": 120, "height": 90}, "trajectory": {"frames": 8}}
    sparse = run_stages([SyntheticSource(scene=scene)])
    everything = len(run_stages([TSDFMapper(min_frames=1)], sparse).map.geometry.points)
    alone = len(run_stages([TSDFMapper(min_view_share=0.0)], sparse).map.geometry.points)
    mapped = run_stages([TSDFMapper()], sparse)
    assert alone < 0.3 * everything
    assert len(mapped.map.geometry.points) > 0.5 * everything
    assert mapped.notes["tsdf"]["surface_views_needed"] < 4
    dense = run_stages([SyntheticSource(scene={**scene, "trajectory": {"frames": 40}})])
    default = run_stages([TSDFMapper()], dense)
    assert default.notes["tsdf"]["surface_views_needed"] == 4
    np.testing.assert_array_equal(
        default.map.geometry.points, run_stages([TSDFMapper(min_view_share=0.0)], dense).map.geometry.points
    )


def test_points_thins_a_long_lidar_recording_as_it_grows(monkeypatch):
    """With a voxel size, accumulated sweeps are thinned whenever they pass COMPACT_POINTS: the map
    never holds many points per voxel, and it covers what thinning once at the end covers."""
    from scipy.spatial import cKDTree

    from stratamap.core.map.sensors import SensorStream
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.plugins.mappers import points

    spec = {"type": "room", "seed": 2, "trajectory": {"type": "orbit", "frames": 12}}
    world = SyntheticWorld(SceneSpec.model_validate({**spec, "lidar": {"enabled": True}}))
    stream = SensorStream(name="lidar", lidar_scans=world.lidar_scans)
    mapper = points.PointsMapper(voxel_size=0.1, normals_radius=0.0)
    once = mapper.map(PipelineData(stream=stream))["geometry"].points
    sweep = len(world.lidar_scans[0].points)
    monkeypatch.setattr(points, "COMPACT_POINTS", 3 * sweep)
    seen: list[int] = []
    original = points.o3d.geometry.PointCloud.voxel_down_sample
    monkeypatch.setattr(
        points.o3d.geometry.PointCloud,
        "voxel_down_sample",
        lambda self, size: seen.append(len(self.points)) or original(self, size),
    )
    grown = mapper.map(PipelineData(stream=stream))["geometry"].points
    assert len(seen) > 2 and max(seen) < len(world.lidar_scans) * sweep / 2  # thinned as it grew, never the whole pile
    assert 0.8 * len(once) < len(grown) < 1.5 * len(once)
    assert cKDTree(once).query(grown)[0].max() < 0.1 * np.sqrt(3)
    assert cKDTree(grown).query(once)[0].max() < 0.1 * np.sqrt(3)


def test_occupancy_maps_a_lidar_recording_from_its_sweeps():
    """A 3D LiDAR recording's laser map comes from its sweeps, as planar scans of the obstacle band
    (pointcloud_to_laserscan): free where the beams crossed, occupied where they ended. It knows most
    of what the same room's 2D laser knows, and what it calls free the 2D laser does too (the band
    holds the laser's plane). The geometry's thin slice at the laser height knew little of it."""
    from stratamap.core.map.sensors import SensorStream
    from stratamap.core.pipeline import run_stages
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.plugins.mappers.occupancy import OccupancyMapper
    from stratamap.plugins.mappers.points import PointsMapper

    spec = {"type": "room", "seed": 2, "trajectory": {"type": "orbit", "frames": 12}}
    world = SyntheticWorld(SceneSpec.model_validate({**spec, "lidar": {"enabled": True}}))
    lidar = run_stages(
        [PointsMapper(voxel_size=0.02, normals_radius=0.0), OccupancyMapper()],
        PipelineData(stream=SensorStream(name="lidar", lidar_scans=world.lidar_scans)),
    )
    assert "LiDAR sweeps as planar scans" in lidar.notes["occupancy"]["slam_source"]
    laser = run_stages(
        [OccupancyMapper()], PipelineData(stream=SensorStream(name="laser", laser_scans=world.laser_scans))
    )

    def cells(data: PipelineData) -> dict[tuple[int, int], int]:
        grid = data.map.occupancy["slam"]
        rows, cols = np.nonzero(grid.data >= 0)
        centres = (np.c_[cols, rows] + 0.5) * grid.resolution + np.asarray(grid.origin[:2])
        keys = np.floor(centres / grid.resolution)  # cells of both maps on one world grid
        return {(int(x), int(y)): int(grid.data[r, c]) for (x, y), r, c in zip(keys, rows, cols, strict=True)}

    seen_by_lidar, seen_by_laser = cells(lidar), cells(laser)
    both = [key for key in seen_by_lidar if key in seen_by_laser]
    assert len(both) > 0.6 * len(seen_by_laser)
    lidar_free = [key for key in both if seen_by_lidar[key] == 0]
    assert len(lidar_free) > 0.5 * len(both)
    assert np.mean([seen_by_laser[key] == 0 for key in lidar_free]) > 0.95


@pytest.mark.slow
def test_the_surface_is_the_same_whatever_open3ds_threads():
    """The points and the mesh are extracted on all of Open3D's threads, which emit points, vertices
    and triangles in an order (and the mesh's duplicates at block borders) that depend on their
    number; the sorted points and the canonical mesh must not."""
    from stratamap.core.parallel import open3d_threads
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers._volume import TSDFVolume, position_order
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.sources.synthetic import SyntheticSource

    scene = {"type": "office", "seed": 2, "camera": {"width": 160, "height": 120}, "trajectory": {"frames": 12}}
    stream = run_stages([SyntheticSource(scene=scene)]).stream
    volume = TSDFVolume(TSDFMapper().config, stream.intrinsics)
    for frame in stream.frames:
        depth, _ = volume.usable_depth(frame)
        volume.integrate(depth, frame.rgb, frame.pose)
    surfaces = []
    for threads in (1, 2, 4):
        with open3d_threads(threads):
            surfaces.append(volume.surface())
    first = surfaces[0]
    assert len(first.mesh.faces) > 1000
    for other in surfaces[1:]:
        np.testing.assert_array_equal(first.points, other.points)
        np.testing.assert_array_equal(first.colors, other.colors)
        np.testing.assert_array_equal(first.mesh.vertices, other.mesh.vertices)
        np.testing.assert_array_equal(first.mesh.faces, other.mesh.faces)
        np.testing.assert_array_equal(first.mesh.visual.vertex_colors, other.mesh.visual.vertex_colors)
    # Any order the threads could emit the points in sorts to the same cloud.
    cloud = volume.grid.extract_point_cloud(volume.views_needed - 0.5)
    points, colors = cloud.point.positions.numpy().astype(np.float64), cloud.point.colors.numpy()
    for seed in range(3):
        shuffle = np.random.default_rng(seed).permutation(len(points))
        order = position_order(points[shuffle], colors[shuffle])
        np.testing.assert_array_equal(points[shuffle][order], first.points)
        np.testing.assert_array_equal(np.clip(colors[shuffle][order], 0, 1), first.colors)


def test_points_in_one_grid_cell_sort_by_their_values_not_their_order():
    """Two points a hair apart (a surface crossing a voxel's corner, found from two voxels) share a
    10 um cell and often a colour: their order must come from their exact positions."""
    from stratamap.plugins.mappers._volume import QUANTUM, position_order

    rng = np.random.default_rng(0)
    cells = np.rint(rng.uniform(-3, 3, (300, 3)) / QUANTUM) * QUANTUM
    twins = cells[:100] + rng.uniform(-0.3, 0.3, (100, 3)) * QUANTUM  # in their cell's 10 um
    points = np.concatenate([cells, twins])
    colors = rng.uniform(0, 1, (300, 3)).astype(np.float32)
    colors = np.concatenate([colors, colors[:100]])
    for cols in (colors, None):
        clouds = []
        for seed in range(5):
            shuffle = np.random.default_rng(seed).permutation(len(points))
            shuffled = None if cols is None else cols[shuffle]
            order = position_order(points[shuffle], shuffled)
            clouds.append((points[shuffle][order], None if cols is None else shuffled[order]))
        for other in clouds[1:]:
            np.testing.assert_array_equal(other[0], clouds[0][0])
            np.testing.assert_array_equal(other[1], clouds[0][1])
    keys = np.rint(clouds[0][0] / QUANTUM)
    assert all(tuple(a) <= tuple(b) for a, b in zip(keys[:-1], keys[1:], strict=True))  # x, then y, then z


def test_the_canonical_mesh_averages_merged_colours_and_sorts_faces():
    from stratamap.plugins.mappers._volume import QUANTUM, canonical_mesh

    rng = np.random.default_rng(1)
    grid = np.rint(rng.uniform(0, 1, (400, 3)) / QUANTUM) * QUANTUM
    vertices = np.concatenate([grid, grid[:150] + rng.uniform(-0.3, 0.3, (150, 3)) * QUANTUM])
    colors = rng.integers(0, 256, (550, 3), dtype=np.uint8)
    faces = rng.integers(0, 550, (900, 3))
    unique, sorted_faces, merged = canonical_mesh(vertices, faces, colors)
    # The plain way: np.unique on the grid positions, colour sums by bincount, faces by lexsort.
    expected, inverse = np.unique(np.rint(vertices / QUANTUM).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    np.testing.assert_array_equal(unique, expected * QUANTUM)
    count = np.bincount(inverse)[:, None]
    sums = np.stack([np.bincount(inverse, weights=colors[:, k]).astype(np.int64) for k in range(3)], axis=1)
    np.testing.assert_array_equal(merged, ((2 * sums + count) // (2 * count)).astype(np.uint8))
    remapped = inverse[faces]
    np.testing.assert_array_equal(sorted_faces, remapped[np.lexsort(remapped.T[::-1])])


def test_first_of_each_is_numpys_unique_with_first_indices():
    from stratamap.plugins.mappers.tsdf import first_of_each

    rng = np.random.default_rng(2)
    for values in (
        rng.integers(0, 50, 1000),
        rng.integers(0, 2**40, 300),
        np.zeros(0, np.int64),
        np.array([7]),
        rng.integers(-5, 5, 40),
    ):
        expected = np.unique(values, return_index=True)
        got = first_of_each(values)
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])
