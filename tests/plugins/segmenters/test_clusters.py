"""The `clusters` segmenter, geometry first: floor, walls and ceiling of a room are stuff and never a
thing; a table (top and legs), a cup on it and a chair are separate instances; distances follow the
map's voxel size; names come from fused class votes; large maps, tabletop scans (no floor), and the
real mOSD Kinect scans (learn split; the test split is kept for the reported figure)."""

from __future__ import annotations

import resource

import numpy as np
import pytest

from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.sensors import SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersConfig, ClustersSegmenter, patch_graph
from tests.conftest import shared_data
from tests.plugins.segmenters.test_layout_planes import box_surface, room_shell, synthetic_room

VOCAB = Vocabulary.default()
STUFF = ("floor", "wall", "ceiling")


def segment(points: np.ndarray, voxel_size: float | None, votes: Semantics | None = None, **params):
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=voxel_size)
    data.map.semantics = votes
    return ClustersSegmenter(**params).run(data)


def instance_of(names: np.ndarray, out: dict, name: str) -> tuple[int, float]:
    """The instance holding most of the points named ``name``, and the share of them it holds."""
    ids = out["semantics"].instance_ids[names == name]
    best = int(np.bincount(ids).argmax())
    return best, float((ids == best).mean())


def check_room(points: np.ndarray, names: np.ndarray, out: dict) -> None:
    sem = out["semantics"]
    stuff = np.isin(names, STUFF)
    # A voxel where a leg meets the floor holds both: a point or two of stuff per object may follow the leg.
    assert (sem.instance_ids[stuff] > 0).sum() <= 3 * len(out["instances"]), "floor, wall or ceiling in a thing"
    for name in STUFF:
        assert (sem.class_ids[names == name] == VOCAB.id(name)).mean() > 0.97, name
    found = {name: instance_of(names, out, name) for name in ("table", "chair", "cup")}
    # The cup's lowest row of points lies on the table top, in the table's cells: 0.7 of it at least.
    assert all(iid > 0 and share > (0.7 if name == "cup" else 0.9) for name, (iid, share) in found.items()), found
    assert len({iid for iid, _ in found.values()}) == 3, found  # the cup is not the table's
    assert len(out["instances"]) == 3
    table = next(i for i in out["instances"] if i.id == found["table"][0])
    assert table.class_name == "table" and table.box.size[2] > 0.7  # its top and its legs


def test_room_layout_is_stuff_and_objects_are_instances():
    points, names = synthetic_room(0.02, tight=True)
    check_room(points, names, segment(points, 0.02))


@pytest.mark.slow  # clusters on two 1 cm rooms (make test runs it; make test-fast does not)
def test_the_same_room_at_two_voxel_sizes_gives_the_same_instances():
    for spacing in (0.015, 0.03):
        points, names = synthetic_room(spacing)
        out = segment(points, spacing)
        check_room(points, names, out)
        assert sorted(i.class_name for i in out["instances"]) == ["object", "object", "table"]


def test_instances_take_their_class_from_fused_votes():
    """The semantics layer a mapper fused (here: the true class, one point in ten voted wrong)."""
    points, names = synthetic_room(0.03)
    rng = np.random.default_rng(0)
    classes = np.array([VOCAB.id(n) for n in names], np.int32)
    wrong = rng.random(len(classes)) < 0.1
    classes[wrong] = rng.choice([VOCAB.id("sofa"), VOCAB.id("floor"), 0], wrong.sum())
    out = segment(points, 0.03, votes=Semantics(classes, np.zeros(len(classes), np.int32), VOCAB))
    check_room(points, names, out)
    assert sorted(i.class_name for i in out["instances"]) == ["chair", "cup", "table"]


def visible_box(lo, hi, spacing: float, camera: np.ndarray) -> np.ndarray:
    """The faces of a box standing on z = lo[2] that face ``camera`` (one view, as a scan)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    faces = ""
    for face in "xXyYZ":
        axis = "xyz".index(face.lower())
        centre = (lo + hi) / 2
        centre[axis] = hi[axis] if face.isupper() else lo[axis]
        outward = np.zeros(3)
        outward[axis] = 1.0 if face.isupper() else -1.0
        if outward @ (camera - centre) > 0:
            faces += face
    pts = box_surface(lo, hi, spacing, faces)
    return pts[pts[:, 2] > lo[2] + 1e-6]


def test_a_tabletop_scan_without_floor():
    """A partial map as a raw cloud seen from one sensor (no voxel size: the grid follows the point
    spacing): the table is the support, three boxes on it are objects; no floor, wall or ceiling."""
    spacing, camera = 0.003, np.array([0.0, -1.0, 0.8])
    top = box_surface((-0.6, -0.4, 0.0), (0.6, 0.4, 0.0), spacing, "z")
    parts = {"a": ((-0.4, -0.1, 0), (-0.2, 0.1, 0.12)), "b": ((0.0, 0.0, 0), (0.1, 0.1, 0.2))}
    parts["c"] = ((0.3, -0.2, 0), (0.4, -0.05, 0.08))
    boxes = {name: visible_box(lo, hi, spacing, camera) for name, (lo, hi) in parts.items()}
    points = np.concatenate([top, *boxes.values()])
    points += np.random.default_rng(0).normal(0, 0.001, points.shape)  # a sensor's noise
    names = np.concatenate([np.full(len(top), "table")] + [np.full(len(b), n) for n, b in boxes.items()])
    pose = np.eye(4)
    pose[:3, 3] = camera
    data = PipelineData(stream=SensorStream(name="scan", points=points, metadata={"world_transform": pose.tolist()}))
    data.map.geometry = Geometry(points=points)
    out = ClustersSegmenter().run(data)
    sem = out["semantics"]
    assert not np.isin(sem.class_ids, [VOCAB.id(n) for n in STUFF]).any()
    found = {n: instance_of(names, out, n) for n in ("table", "a", "b", "c")}
    assert len({iid for iid, _ in found.values()}) == 4 and all(s > 0.85 for _, s in found.values()), found
    assert sorted(i.class_name for i in out["instances"]) == ["object", "object", "object", "table"]


def test_without_gravity_nothing_is_layout():
    points, _ = synthetic_room(0.04)
    out = segment(points, 0.04, gravity="none")
    assert not np.isin(out["semantics"].class_ids, [VOCAB.id(n) for n in STUFF]).any()


@pytest.mark.slow
def test_a_map_of_millions_of_points():
    """A 30 x 20 m hall with 600 boxes, 2.9 million points: more than 46,341 patches (their pair keys
    once overflowed int32), every box its own instance, in bounded memory."""
    spacing = 0.02
    lx, ly, lz = 30.0, 20.0, 2.6
    layout = [
        box_surface((0, 0, 0), (lx, ly, 0), spacing, "z"),
        box_surface((0, 0, 0), (0, ly, lz), spacing, "x"),
        box_surface((lx, 0, 0), (lx, ly, lz), spacing, "X"),
        box_surface((0, 0, 0), (lx, 0, lz), spacing, "y"),
        box_surface((0, ly, 0), (lx, ly, lz), spacing, "Y"),
    ]
    centres = [(1.0 + 1.2 * i, 1.0 + 0.75 * j) for i in range(24) for j in range(25)]
    boxes = [box_surface((x - 0.15, y - 0.15, 0.0), (x + 0.15, y + 0.15, 0.3), spacing, "xXyYZ") for x, y in centres]
    points = np.concatenate(layout + boxes)
    owner = np.concatenate(
        [np.zeros(sum(map(len, layout)), int)] + [np.full(len(b), k + 1) for k, b in enumerate(boxes)]
    )
    assert len(points) > 2_500_000
    out = segment(points, spacing)
    sem = out["semantics"]
    assert len(out["instances"]) == len(boxes)
    assert (sem.instance_ids[owner == 0] > 0).sum() < 1e-4 * (owner == 0).sum()  # a box's foot row shares floor cells
    on_box = sem.instance_ids[owner > 0]
    # One instance per box: each box's points share one id, and no id spans two boxes.
    pairs = np.unique(np.stack([owner[owner > 0], on_box], 1)[on_box > 0], axis=0)
    assert len(np.unique(pairs[:, 0])) == len(pairs) == len(np.unique(pairs[:, 1])) == len(boxes)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss < 8 * 1024 * 1024  # kB: under 8 GB


def test_the_support_prefilter_keeps_every_pair_whose_points_reach_over_a_hull():
    """``cut_below_supports`` tests an instance's points against a support's hull only where its box
    may reach over it: on random instances and hulls (some thin slivers with sharp corners), no pair
    with a point over the hull and above the height is left out, and most far pairs are."""
    from stratamap.plugins.segmenters.clusters.grid import hull_equations
    from stratamap.plugins.segmenters.clusters.mirrored import HULL_MARGIN, _within_reach

    rng = np.random.default_rng(7)
    centres = rng.uniform(0, 6, (40, 2))
    chunks = [c + rng.normal(0, rng.uniform(0.05, 0.4), (60, 2)) for c in centres]
    points = np.vstack([np.c_[xy, rng.uniform(0, 1.2, len(xy))] for xy in chunks])
    by_instance = [np.zeros(0, np.int64)] + [np.arange(60 * k, 60 * (k + 1)) for k in range(40)]
    surfaces, grazing = [], []
    for k in range(25):
        c, direction = rng.uniform(0, 6, 2), rng.normal(size=2)
        sliver = c + np.outer(rng.uniform(-0.8, 0.8, 6), direction) + rng.normal(0, 0.01, (6, 2))
        blob = c + rng.normal(0, 0.3, (12, 2))
        a, b = hull_equations(sliver if k % 2 else blob)
        surfaces.append((float(rng.uniform(0.2, 1.0)), a, b, 0))
        # A few points just outside one edge, within the margin: over the hull as the pass counts it.
        corners = sliver if k % 2 else blob
        edge = int(rng.integers(len(a)))
        on_edge = corners[np.argsort(np.abs(corners @ a[edge] + b[edge]))[:2]].mean(axis=0)
        on_edge -= (on_edge @ a[edge] + b[edge]) * a[edge]
        xy = on_edge + a[edge] * rng.uniform(0.6, 0.95) * HULL_MARGIN + rng.normal(0, 1e-4, (5, 2))
        grazing.append(np.c_[xy, np.full(5, 1.5)])
    points = np.vstack([points, *grazing])
    by_instance += [np.arange(2400 + 5 * k, 2400 + 5 * (k + 1)) for k in range(25)]
    reach = _within_reach(points, by_instance, surfaces, 0.02)
    assert not reach[0].any()
    assert all(reach[41 + k, k] for k in range(25))
    for iid in range(1, len(by_instance)):
        xy, z = points[by_instance[iid], :2], points[by_instance[iid], 2]
        for s, (height, a, b, _) in enumerate(surfaces):
            over = ((xy @ a.T + b) <= HULL_MARGIN).all(axis=1) & (z > height - 0.02)
            assert reach[iid, s] or not over.any(), (iid, s)
    assert reach.mean() < 0.5


def test_patch_graph_keys_do_not_overflow_on_large_maps():
    """Patch-pair keys of more than 46,341 patches do not overflow int32."""
    cfg = ClustersConfig()
    size = 0.02
    n = 60_000  # points in a row, one per patch cell, each linked to its neighbours
    points = np.zeros((n, 3))
    points[:, 0] = np.arange(n) * size * 1.01
    normals = np.tile([0.0, 0.0, 1.0], (n, 1))
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], 1)
    graph = patch_graph(points, normals, pairs, cfg, size, 0.4, 0.4)
    assert len(graph.centroid) == n and len(graph.edges) == n - 1
    assert np.array_equal(np.sort(graph.edges, axis=1), pairs)


def test_separates_objects_on_a_table_in_one_view():
    """A Kinect-like single view of a table (no floor) with a box, a cylinder and a tall box: the
    table is the support, named table; the three are objects; instance F1 1 against the truth."""
    import trimesh

    from stratamap.core.evaluation.metrics import evaluate
    from stratamap.core.map.groundtruth import GroundTruth

    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-0.6, 0.6, (20000, 2)), rng.normal(0, 0.002, 20000)]
    parts, inst = [table], [np.ones(len(table), int)]
    meshes = [
        trimesh.creation.box(extents=(0.2, 0.15, 0.1)),
        trimesh.creation.cylinder(radius=0.05, height=0.15),
        trimesh.creation.box(extents=(0.1, 0.1, 0.2)),
    ]
    offsets = [(-0.3, 0.0, 0.05), (0.1, 0.1, 0.075), (0.35, -0.2, 0.1)]
    camera = np.array([0.0, -1.2, 0.9])  # only surfaces facing the camera
    for k, (mesh, off) in enumerate(zip(meshes, offsets, strict=True)):
        pts, faces = trimesh.sample.sample_surface_even(mesh, 6000, seed=k)
        pts = pts + off
        facing = np.einsum("ij,ij->i", mesh.face_normals[faces], camera - pts) > 0
        pts = pts[facing & (pts[:, 2] > 0.002)]
        parts.append(pts)
        inst.append(np.full(len(pts), k + 2))
    points, inst = np.concatenate(parts), np.concatenate(inst)
    cls = np.where(inst == 1, VOCAB.id("table"), VOCAB.id("object")).astype(np.int32)
    pose = np.eye(4)
    pose[:3, 3] = camera
    data = PipelineData(
        stream=SensorStream(name="cloud", points=points, metadata={"world_transform": pose.tolist()}),
        ground_truth=GroundTruth(vocabulary=VOCAB, point_class_ids=cls, point_instance_ids=inst.astype(np.int32)),
    )
    data.map.geometry = Geometry(points=points)
    out = ClustersSegmenter().run(data)
    data.map.semantics, data.map.instances = out["semantics"], out["instances"]
    assert evaluate(data)["instances"]["f1"] == 1.0
    assert sorted(i.class_name for i in out["instances"]) == ["object", "object", "object", "table"]


def test_clusters_cuts_a_box_standing_flush_on_another():
    """A box on a larger box, flush on one side (one Kinect-like view): the flush faces join the two
    convexly, the crease around the upper box's foot proposes the lower box's top as a cut plane,
    and the cut separates them (creases at the stricter tolerance). Without cuts they stay one."""
    import trimesh

    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-0.6, 0.6, (30000, 2)), rng.normal(0, 0.001, 30000)]
    camera = np.array([-0.9, -1.0, 1.0])
    lower, upper = trimesh.creation.box(extents=(0.3, 0.2, 0.1)), trimesh.creation.box(extents=(0.1, 0.2, 0.1))
    parts, inst = [table], [np.ones(len(table), int)]
    for k, (mesh, off) in enumerate(((lower, (0.0, 0.0, 0.05)), (upper, (0.1, 0.0, 0.15)))):
        pts, faces = trimesh.sample.sample_surface_even(mesh, 30000, seed=k)
        pts = pts + off
        keep = (np.einsum("ij,ij->i", mesh.face_normals[faces], camera - pts) > 0) & (pts[:, 2] > 0.002)
        if k == 0:
            keep &= ~((pts[:, 2] > 0.099) & (pts[:, 0] > 0.05))  # the lower top under the upper box
        parts.append(pts[keep] + rng.normal(0, 0.001, (keep.sum(), 3)))
        inst.append(np.full(keep.sum(), k + 2))
    points, inst = np.concatenate(parts), np.concatenate(inst)
    pose = np.eye(4)
    pose[:3, 3] = camera

    def separated(**params) -> bool:
        data = PipelineData(
            stream=SensorStream(name="cloud", points=points, metadata={"world_transform": pose.tolist()})
        )
        data.map.geometry = Geometry(points=points)
        ids = ClustersSegmenter(**params).run(data)["semantics"].instance_ids
        lower_id, upper_id = (int(np.bincount(ids[inst == k]).argmax()) for k in (2, 3))
        return (
            lower_id != upper_id
            and (ids[inst == 2] == lower_id).mean() > 0.9
            and (ids[inst == 3] == upper_id).mean() > 0.9
        )

    # At the default tolerance (0.4, for the noise of fused maps) these flush faces count as convex;
    # at the stricter 0.2 their crease is seen and cut.
    assert not separated(cut_min_links=0, cut_concavity_tolerance=0.2)
    assert separated(cut_concavity_tolerance=0.2)


@pytest.mark.slow
def test_on_real_tabletop_scans_reaches_f1_095():
    """mOSD learn split (tuned on; the test split is kept for the reported figure, 0.92 -> see docs)."""
    from stratamap.core.evaluation.metrics import evaluate
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.points import PointsMapper
    from stratamap.plugins.sources.pointcloud import PointCloudSource

    folder = shared_data("mosd", "learn")
    f1 = []
    for path in sorted(folder.glob("*.pcd")):
        source = PointCloudSource(path=str(path), label_scheme="mosd", up_axis="-y", up_tolerance_deg=60)
        data = run_stages([source, PointsMapper(normals_radius=0.0), ClustersSegmenter()])
        f1.append(evaluate(data)["instances"]["f1"])
    assert len(f1) >= 5 and np.mean(f1) >= 0.95, f1


def test_a_real_scan_of_an_office_floor_has_its_floor():
    """A real Kinect view down onto an office floor with a swivel chair and a drawer unit (PCL's
    region growing tutorial scan): the furniture rises 0.5 m, and the floor far from the sensor is
    sparser than the working grid; on that grid the floor looked smaller than a floor, like a
    tabletop. Its size is measured on a 5 cm grid: most points at its height are floor."""
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.points import PointsMapper
    from stratamap.plugins.sources.pointcloud import PointCloudSource

    path = shared_data("pcl_scenes", "region_growing_rgb_tutorial.pcd")
    source = PointCloudSource(path=str(path), up_axis="-y", up_tolerance_deg=60)
    data = run_stages([source, PointsMapper(normals_radius=0.0), ClustersSegmenter()])
    sem, z = data.map.semantics, data.map.geometry.points[:, 2]
    low = np.abs(z - np.percentile(z, 5)) < 0.02
    assert (sem.class_ids[low] == sem.vocabulary.id("floor")).mean() > 0.9


@pytest.mark.slow  # the source, points and clusters on a real 640 x 480 frame (make test runs it)
@pytest.mark.parametrize("stored", ["organized", "unorganized"])
def test_a_real_kinect_frames_far_wall_is_not_shattered_into_slivers(stored, tmp_path):
    """The same real Kinect view: 3-4 m away its depth comes in 3-5 cm steps, and the bottom of the
    far wall, a door and boxes by it fell into about 70 slivers (93 instances in all). Read with the
    source's default smoothing (in inverse depth, with the camera's own step), few instances lie
    there and the whole view holds a few dozen at most; so too when the frame is stored without its
    image grid, its invalid pixels dropped."""
    from stratamap.core.geometry.transforms import apply
    from stratamap.core.io.pointcloud import read_point_cloud, write_pcd
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.points import PointsMapper
    from stratamap.plugins.sources.pointcloud import PointCloudSource

    path = shared_data("pcl_scenes", "region_growing_rgb_tutorial.pcd")
    if stored == "unorganized":
        cloud = read_point_cloud(path, "label")
        valid = np.isfinite(cloud.points).all(axis=1)
        path = write_pcd(tmp_path / "flat.pcd", cloud.points[valid], colors=cloud.colors[valid])
    source = PointCloudSource(path=str(path), up_axis="-y")
    data = run_stages([source, PointsMapper(), ClustersSegmenter(recognize=True)])
    camera = apply(np.asarray(data.notes["pointcloud"]["gravity_alignment"]["transform"]), np.zeros((1, 3)))[0]
    far = [i for i in data.map.instances if np.linalg.norm(i.box.center[:2] - camera[:2]) > 3.0]
    assert len(far) <= 12, len(far)
    assert len(data.map.instances) <= 30, len(data.map.instances)


@pytest.mark.slow  # clusters on two 1 cm rooms (make test runs it; make test-fast does not)
def test_a_cloud_holding_every_point_twice_gets_the_grid_of_its_points():
    """A raw cloud saved with each point twice (PCL's room scans): the spacing is measured between
    distinct points, so the working grid and the room's instances are those of the cloud once."""
    from stratamap.plugins.segmenters.clusters import working_voxel

    points, _ = synthetic_room(0.01)
    twice = np.concatenate([points, points])
    cfg = ClustersConfig()
    assert working_voxel(twice, None, cfg) == pytest.approx(working_voxel(points, None, cfg))
    once, doubled = segment(points, None)["semantics"], segment(twice, None)["semantics"]
    assert (doubled.class_ids[: len(points)] == once.class_ids).mean() > 0.99
    assert len(np.unique(doubled.instance_ids)) == len(np.unique(once.instance_ids)) >= 4


def test_a_bare_floor_is_floor_and_no_instance():
    """Nothing but stuff (a scan of an empty floor): no segment, no support, no instance, no error."""
    points = np.c_[np.random.default_rng(0).uniform(0, 3, (5000, 2)), np.zeros(5000)]
    out = segment(points, None)
    assert len(out["instances"]) == 0
    assert (out["semantics"].class_ids == VOCAB.id("floor")).all()


def test_a_real_360_degree_room_scan_has_its_floor_walls_and_ceiling():
    """PCL's room scan (a 360-degree scan of one room, every point stored twice, dense near the
    sensor and sparse far away): floor, walls and ceiling are found and are no things."""
    from stratamap.core.pipeline import run_stages
    from stratamap.plugins.mappers.points import PointsMapper
    from stratamap.plugins.sources.pointcloud import PointCloudSource

    path = shared_data("pcl_scenes", "room_scan1.pcd")
    data = run_stages([PointCloudSource(path=str(path)), PointsMapper(), ClustersSegmenter()])
    notes = data.notes["clusters"]["segments"]
    assert notes["floor_height"] is not None and notes["walls"] >= 3, notes
    sem, z = data.map.semantics, data.map.geometry.points[:, 2]
    for name, level in (("floor", 1), ("ceiling", 99)):
        at = np.abs(z - np.percentile(z, level)) < 0.05
        assert (sem.class_ids[at] == sem.vocabulary.id(name)).mean() > 0.8, name
        assert (sem.instance_ids[at] > 0).mean() < 0.05, name


@pytest.mark.parametrize(
    "points,params,message",
    [
        (np.zeros((0, 3)), {}, r"clusters: the geometry layer has no points"),
        (np.random.default_rng(0).random((50, 3)), {"class_rules": [{"class_name": "wall"}]}, r"names 'wall'"),
    ],
)
def test_bad_input_is_a_one_line_data_error(points, params, message):
    from stratamap.core.errors import DataError

    with pytest.raises(DataError, match=message) as err:
        segment(points, None, **params)
    assert "\n" not in str(err.value)


def test_a_cup_near_the_table_edge_is_its_own_instance():
    """A cup 2 cm from the table's edge: the top's normals bend next to the cup's foot, and the ring
    the layout's fit leaves out there runs into the table's rim, through which the cup's segment
    joined the table's. The support surface takes that ring (cells at its height, next to it, in its
    footprint); the cup's own foot goes back to the cup."""
    from tests.plugins.segmenters.test_layout_planes import room_shell, solids, table

    spacing = 0.02
    objects, names = solids(table(3.0, 2.5) + [("cup", (3.5, 2.4, 0.75), (3.58, 2.48, 0.85))], spacing)
    layout = room_shell(spacing, around=objects)
    points = np.concatenate([p for _, p in layout] + [objects])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [names])
    out = segment(points, spacing)
    (table_id, table_share), (cup_id, cup_share) = instance_of(names, out, "table"), instance_of(names, out, "cup")
    assert cup_id > 0 and cup_id != table_id, (table_id, cup_id)
    assert table_share > 0.9 and cup_share > 0.7, (table_share, cup_share)


@pytest.mark.parametrize("trim", [True, False])
def test_a_ring_of_table_top_a_cups_mask_took_goes_back_to_the_table(trim):
    """A detector's mask around a cup takes the table top around its foot; fused, the cup's instance
    holds a ring of the top 6 cm wide, and its box is twice the cup's width (3D box IoU under 0.25 to
    the true cup). The ring lies in the surface the cup stands on, outside the cup's body: it goes
    back to the table, and the cup's box is the cup's again. The chair's feet, under its legs, stay."""
    from tests.plugins.segmenters.test_layout_planes import chair, room_shell, solids, table

    spacing = 0.02
    cup_lo, cup_hi = (3.46, 2.46, 0.75), (3.54, 2.54, 0.85)
    objects, names = solids(table(3.0, 2.5) + chair(3.0, 3.3) + [("cup", cup_lo, cup_hi)], spacing)
    layout = room_shell(spacing, around=objects)
    points = np.concatenate([p for _, p in layout] + [objects])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [names])
    classes = np.array([VOCAB.id(n) for n in names], np.int32)
    ids = np.zeros(len(points), np.int32)
    for k, name in enumerate(("table", "chair", "cup"), start=1):
        ids[names == name] = k
    top = (names == "table") & (np.abs(points[:, 2] - 0.75) < 1e-6)
    off_centre = np.abs(points[:, :2] - (3.5, 2.5)).max(axis=1)
    ring = top & (off_centre > 0.041) & (off_centre <= 0.1)  # 6 cm of top beyond the cup's side
    classes[ring], ids[ring] = VOCAB.id("cup"), 3
    out = segment(points, spacing, votes=Semantics(classes, ids, VOCAB), keep_instances=True, trim_feet=trim)
    cup = next(i for i in out["instances"] if i.class_name == "cup")
    width = float(np.max(cup.box.size[:2]))
    given_back = out["semantics"].instance_ids[ring]
    if not trim:  # the ring stays the cup's: this is what the trimming is for
        assert width >= 0.18, cup.box.size
        return
    assert width <= 0.08 + 2 * spacing, cup.box.size
    table_id = instance_of(names, out, "table")[0]
    assert (given_back == table_id).mean() > 0.9, np.unique(given_back, return_counts=True)
    chair_id, chair_share = instance_of(names, out, "chair")
    feet = (names == "chair") & (points[:, 2] < 0.01)
    assert chair_share > 0.9 and (out["semantics"].instance_ids[feet] == chair_id).all()


def test_a_few_points_floating_far_above_a_thing_are_strays():
    """A sofa-sized box with three cells of a wall corner 0.8 m above its back: the three leave it.
    A worktop's front edge seen as scraps and a swivel chair's caster past its unseen spoke stay
    (beside the rest, not above it), and so does a chair's back seen apart from its seat (a part of
    its own size)."""
    from stratamap.plugins.segmenters.clusters import stray_points

    radius, gap, smallest = 0.048, 0.08, 30
    sofa = box_surface((0.0, 0.0, 0.0), (2.1, 0.9, 0.8), 0.02)
    corner = np.array([[0.01, 0.01, 1.6], [0.01, 0.02, 1.62], [0.02, 0.01, 1.64]])
    stray = stray_points(np.concatenate([sofa, corner]), radius, gap, smallest)
    assert stray[len(sofa) :].all() and not stray[: len(sofa)].any()

    top = box_surface((0.0, 0.0, 0.88), (1.6, 0.6, 0.9), 0.02)
    edge = np.array([[x, 0.75, 0.9] for x in np.arange(0.0, 1.6, 0.2)])  # eight lone points, 15 cm out
    assert not stray_points(np.concatenate([top, edge]), radius, gap, smallest).any()

    seat = box_surface((0.0, 0.0, 0.42), (0.45, 0.45, 0.46), 0.02)
    caster = box_surface((0.6, 0.2, 0.0), (0.64, 0.24, 0.05), 0.02)  # 15 cm out, on the floor
    back = box_surface((0.0, 0.4, 0.6), (0.45, 0.44, 1.0), 0.02)  # 14 cm above the seat
    assert not stray_points(np.concatenate([seat, caster, back]), radius, gap, smallest).any()
    assert not stray_points(np.concatenate([seat, caster, back]), radius, gap, smallest, far=0.5).any()


def test_a_few_points_far_from_a_thing_at_its_own_height_are_strays():
    """Two points a frame's mask caught 2 m past a counter run's end, at its plinth's height, stretched
    its box from 2.7 m to 4.9 m on a real kitchen: they are strays at any height once ``far`` away;
    without ``far`` (and below the rest) they stay, as before."""
    from stratamap.plugins.segmenters.clusters import stray_points

    radius, gap, smallest = 0.048, 0.08, 30
    run = box_surface((0.0, 0.0, 0.0), (2.7, 0.6, 0.9), 0.02)
    caught = np.array([[4.7, 0.3, 0.12], [4.72, 0.3, 0.14]])
    points = np.concatenate([run, caught])
    assert not stray_points(points, radius, gap, smallest).any()
    stray = stray_points(points, radius, gap, smallest, far=0.5)
    assert stray[len(run) :].all() and not stray[: len(run)].any()


@pytest.mark.parametrize("square_to_walls", [0.0, 0.1])
def test_a_unit_seen_from_its_corner_stands_square_to_the_walls(square_to_walls):
    # A 1.8 m tall unit in a room (walls at 3 degrees), seen only on its front and one side (its top
    # above the sensor, its back to nobody): an L whose smallest rectangle runs diagonally.
    from stratamap.core.map.instances import instances_from_semantics
    from stratamap.plugins.segmenters.clusters.layout import find_layout, wall_yaws

    turn = np.radians(3.0)
    rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
    rng = np.random.default_rng(0)
    front = np.c_[rng.uniform(2.0, 2.6, 200), rng.normal(2.0, 0.01, 200), rng.uniform(0, 1.8, 200)]
    side = np.c_[rng.normal(2.0, 0.01, 200), rng.uniform(2.0, 2.7, 200), rng.uniform(0, 1.8, 200)]
    unit = np.concatenate([front, side])  # a few hundred points a face, 1 cm of depth noise across it
    room = np.concatenate([p for _, p in room_shell(0.05)])  # 5 cm: the walls' yaws need no finer map
    layout = find_layout(room @ rot.T, 0.05)
    assert layout.walls == 4
    yaws = wall_yaws(layout)
    assert np.allclose(yaws, turn, atol=np.radians(0.5))
    ids = np.ones(len(unit), np.int32)
    sem = Semantics(np.full(len(unit), VOCAB.id("cabinet"), np.int32), ids, VOCAB)
    (inst,) = instances_from_semantics(unit @ rot.T, None, sem, 1, axes=yaws, axes_slack=square_to_walls)
    off = abs((inst.box.yaw - turn + np.pi / 4) % (np.pi / 2) - np.pi / 4)
    if square_to_walls:
        assert off < np.radians(0.5) and np.allclose(sorted(inst.box.size[:2]), [0.6, 0.7], atol=0.05)
    else:
        assert off > np.radians(20)  # the smallest rectangle, as without walls
