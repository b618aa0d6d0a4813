"""The `fronts` completer: faces, fixtures and gaps on height maps, articulated bodies, and doors and
drawers that open in MuJoCo on a rendered walk past storage furniture."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.furniture.fixtures import Fixture
from stratamap.core.map.layers import OrientedBox
from stratamap.plugins.completers.fronts.body import articulated_body
from stratamap.plugins.completers.fronts.face import Face, find_faces
from stratamap.plugins.completers.fronts.fronts import (
    candidate_fronts,
    contrast_handles,
    fixtures_of,
    line_handles,
    off_edges,
)
from stratamap.plugins.completers.fronts.relief import height_map


def _face_points(relief, cell=0.01):
    """A face in the plane x = 1 (normal +x, so u runs along +y): one point per cell at the
    given height out of it, with a little noise."""
    rng = np.random.default_rng(0)
    nz, nu = relief.shape
    zz, uu = np.mgrid[0:nz, 0:nu]
    u, z = (uu.ravel() + 0.5) * cell, (zz.ravel() + 0.5) * cell + 0.1
    h = relief.ravel() + rng.normal(0.0, 0.001, u.size)
    return np.stack([1.0 + h, u, z], axis=1)


def _face(width, height):
    return Face(np.array([1.0, 0.0, 0.0]), -1.0, (0.0, width, 0.1, 0.1 + height), 1.0, 0.0, 0, 1.0)


def test_a_handle_and_a_gap_on_a_height_map_make_two_fronts():
    relief = np.zeros((60, 100))  # 1.0 m wide, 0.6 m high, 1 cm cells
    relief[40, 10:35] = 0.03  # a horizontal bar handle on the left front
    relief[29:32, 70:73] = 0.025  # a knob 3 cm across on the right front
    relief[:, 50] = -0.02  # the gap between the two fronts
    face = _face(1.0, 0.6)
    hm = height_map(_face_points(relief), face, 0.01)
    fixtures = fixtures_of(hm, face, (0.012, 0.07))
    kinds = sorted(f.kind for f in fixtures)
    assert kinds == ["handle", "knob"]
    handle = next(f for f in fixtures if f.kind == "handle")
    assert abs(handle.direction[2]) < 0.2 and 0.2 < handle.length < 0.3  # horizontal, 25 cm
    fronts = candidate_fronts(face, hm, floor_z=0.0, standoff=(0.012, 0.07), gap_depth=(0.008, 0.06), min_front=0.06)
    assert len(fronts) == 2
    cut = sorted(f.u_range for f in fronts)[0][1]
    assert abs(cut - 0.5) < 0.03


def test_a_flush_handle_is_found_in_the_colour_images():
    relief = np.zeros((60, 100))
    points = _face_points(relief)
    shade = np.full(len(points), 0.6)
    u, z = points[:, 1], points[:, 2]
    shade[(np.abs(z - 0.5) < 0.012) & (u > 0.3) & (u < 0.6)] = 0.1  # a dark bar, flush with the face
    face = _face(1.0, 0.6)
    hm = height_map(np.column_stack([points, shade]), face, 0.01)
    assert fixtures_of(hm, face, (0.012, 0.07)) == []  # the depth shows nothing
    handles = contrast_handles(hm, face, [])
    assert len(handles) == 1 and abs(handles[0].direction[2]) < 0.2 and 0.25 < handles[0].length < 0.35
    # Without colour, no contrast handle; with one already found by depth there, no second one.
    assert contrast_handles(height_map(points, face, 0.01), face, []) == []
    assert contrast_handles(hm, face, handles) == []


def _lined_face(bars, width=1.6, height=0.7):
    """A flat face with thin-line marks (light share 0.25 per cell) on ``bars``: (u0, u1, z) each."""
    points = _face_points(np.zeros((int(round(height * 100)), int(round(width * 100)))))
    u, z = points[:, 1], points[:, 2]
    light = np.zeros(len(points))
    for u0, u1, zb in bars:
        light[(np.abs(z - zb) < 0.011) & (u > u0) & (u < u1)] = 0.25
    columns = [points, np.full(len(points), 0.5), light, np.zeros(len(points))]
    face = _face(width, height)
    return face, height_map(np.column_stack(columns), face, 0.01)


def test_a_row_of_bars_seen_only_as_thin_lines_in_the_frames_is_a_row_of_handles():
    # Four doors' steel bars, 20 cm long, level, 40 cm apart: only the frames' thin lines show them.
    face, hm = _lined_face([(c - 0.1, c + 0.1, 0.65) for c in (0.2, 0.6, 1.0, 1.4)])
    assert fixtures_of(hm, face, (0.012, 0.07)) == [] and contrast_handles(hm, face, []) == []
    handles = line_handles(hm, face, [])
    assert len(handles) == 4 and all(h.kind == "handle" and 0.17 < h.length < 0.23 for h in handles)
    assert sorted(round(float(h.center[1]), 1) for h in handles) == [0.2, 0.6, 1.0, 1.4]
    fronts = candidate_fronts(face, hm, floor_z=0.0, standoff=(0.012, 0.07), gap_depth=(0.008, 0.06), min_front=0.06)
    assert len(fronts) == 4  # cut between the handles


def test_a_lone_bar_an_edge_in_pieces_and_bars_of_unlike_rows_are_no_handles():
    # One bar alone: a run of fronts repeats its handle, one line is as likely a reflection.
    face, hm = _lined_face([(0.5, 0.7, 0.65)])
    assert line_handles(hm, face, []) == []
    # An edge's line broken into pieces: the pieces' ends meet the line going on.
    face, hm = _lined_face([(0.1, 0.4, 0.65), (0.42, 0.7, 0.65), (0.72, 1.0, 0.65)])
    assert line_handles(hm, face, []) == []
    # Two bars at heights 10 cm apart, or one twice the other's length, are not one row.
    face, hm = _lined_face([(0.2, 0.4, 0.65), (0.8, 1.0, 0.55)])
    assert line_handles(hm, face, []) == []
    face, hm = _lined_face([(0.2, 0.3, 0.65), (0.8, 1.05, 0.65)])
    assert line_handles(hm, face, []) == []
    # Without the frames' line marks (a static cloud), none.
    face, _ = _lined_face([])
    plain = height_map(_face_points(np.zeros((70, 160))), face, 0.01)
    assert line_handles(plain, face, []) == []


def test_a_worktops_lip_in_pieces_is_an_edge_not_a_row_of_handles():
    # 1.6 m of doors under a worktop whose lip stands 2 cm proud along the top, broken in three
    # by the sensor's gaps; two real bars, 20 cm, stand out below it.
    relief = np.zeros((70, 160))
    for a, b in ((2, 50), (56, 110), (116, 158)):
        relief[64:67, a:b] = 0.02
    relief[55, 30:50] = relief[55, 110:130] = 0.02
    face = _face(1.6, 0.7)
    hm = height_map(_face_points(relief), face, 0.01)
    found = fixtures_of(hm, face, (0.012, 0.07))
    on_lip = [f for f in found if f.center[2] > 0.7]
    assert len(on_lip) >= 2  # the lip's pieces alone look like handles
    kept = off_edges(hm, face, found, (0.012, 0.07))
    assert sorted(round(float(f.center[1]), 1) for f in kept) == [0.4, 1.2]
    # A handle as long as the face is wide is no edge unless longer than any handle.
    short = _face(0.5, 0.4)
    bar = np.zeros((40, 50))
    bar[20, 5:45] = 0.02
    hm = height_map(_face_points(bar), short, 0.01)
    assert len(off_edges(hm, short, fixtures_of(hm, short, (0.012, 0.07)), (0.012, 0.07))) == 1


def test_noise_alone_makes_no_fixture():
    rng = np.random.default_rng(1)
    relief = rng.normal(0.0, 0.006, (60, 100))
    face = _face(1.0, 0.6)
    hm = height_map(_face_points(relief), face, 0.01)
    assert fixtures_of(hm, face, (0.012, 0.07)) == []


def test_the_face_ends_where_its_fronts_stop_spanning_it_not_at_what_stands_on_the_worktop():
    rng = np.random.default_rng(3)
    box = OrientedBox(np.array([0.0, 0.0, 0.6]), 0.0, np.array([2.0, 0.6, 1.2]))
    # Fronts on the -y side from the floor to 0.9 m; picture stands 0.2 m wide at the worktop's
    # front edge, in the same plane, up to 1.15 m.
    fronts = np.stack([rng.uniform(-1.0, 1.0, 20000), np.full(20000, -0.3), rng.uniform(0.05, 0.9, 20000)], 1)
    stand = np.stack([rng.uniform(-0.5, -0.3, 1500), np.full(1500, -0.3), rng.uniform(0.9, 1.15, 1500)], 1)
    faces = find_faces(box, np.vstack([fronts, stand]), np.array([[0.0, -2.0, 1.2]]), 0.35, floor_z=0.0)
    face = faces[0][0]
    assert abs(face.rect[3] - 0.9) <= 0.05  # the 99.5th percentile of its points would say 1.14


def test_the_face_is_a_side_the_sensor_stood_in_front_of():
    rng = np.random.default_rng(2)
    box = OrientedBox(np.array([0.0, 0.0, 0.4]), 0.0, np.array([1.0, 0.6, 0.8]))
    # Points on the -y side (the front) and the +x side; the sensor stands in front of -y only.
    front = np.stack([rng.uniform(-0.5, 0.5, 4000), np.full(4000, -0.3), rng.uniform(0.0, 0.8, 4000)], 1)
    side = np.stack([np.full(3000, 0.5), rng.uniform(-0.3, 0.3, 3000), rng.uniform(0.0, 0.8, 3000)], 1)
    faces = find_faces(box, np.vstack([front, side]), np.array([[0.0, -2.0, 1.2]]), 0.35, floor_z=-1.0)
    assert len(faces) == 1
    assert np.allclose(faces[0][0].normal, [0.0, -1.0, 0.0], atol=0.02)


def test_an_articulated_body_opens_its_doors_about_the_edge_opposite_the_handle():
    size = np.array([1.0, 0.6, 0.8])
    fixture = Fixture("handle", np.array([0.25, -0.33, 0.64]), np.array([1.0, 0.0, 0.0]), 0.2)
    fronts = [
        ((-0.5, 0.0, 0.05, 0.78), "cupboard", "left", []),
        ((0.0, 0.5, 0.5, 0.78), "drawer", None, [fixture]),
        ((0.0, 0.5, 0.05, 0.5), "panel", None, []),
    ]
    completion = articulated_body(size, fronts, np.eye(4), np.eye(4), "fronts", 1.0)
    assert [p.name for p in completion.parts][0] == "body" and len(completion.parts) == 3
    door, drawer = completion.joints
    assert door.type == "revolute" and np.allclose(door.axis, [0, 0, -1]) and door.upper >= np.pi / 2
    assert np.allclose(door.origin[:3, 3][:2], [-0.5 + 0.0015, -0.3])  # the left edge, on the face
    assert drawer.type == "prismatic" and np.allclose(drawer.axis, [0, -1, 0])
    assert 0.2 < drawer.upper < 0.6  # most of its box's depth
    lo, hi = completion.mesh.bounds
    assert np.all(lo >= [-0.5 - 1e-6, -0.3 - 0.031, -1e-6]) and np.all(hi <= [0.5 + 1e-6, 0.3 + 1e-6, 0.8 + 1e-6])
    # The drawer's box fits inside the carcass: it neither pokes through the back nor the sides.
    part = next(p for p in completion.parts if p.name.startswith("front_1"))
    vertices = np.asarray(part.mesh.vertices) + drawer.origin[:3, 3]
    inside = vertices[vertices[:, 1] > -0.3 + 0.019 + 1e-6]
    assert len(inside) and inside[:, 1].max() < 0.3 - 0.018
    assert inside[:, 0].min() > -0.5 + 0.018 and inside[:, 0].max() < 0.5 - 0.018


def test_no_moving_front_no_articulated_body():
    fronts = [((-0.5, 0.5, 0.05, 0.78), "panel", None, [])]
    assert articulated_body(np.array([1.0, 0.6, 0.8]), fronts, np.eye(4), np.eye(4), "fronts", 1.0) is None


@pytest.fixture(scope="module")
def kitchen_run(tmp_path_factory):
    """A rendered walk through a procedural kitchen, mapped, its storage furniture given fronts,
    exported to MJCF."""
    from stratamap.core.pipeline import run_stages
    from stratamap.core.stages import PipelineData
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.plugins.completers.fronts import FrontsCompleter
    from stratamap.plugins.exporters.mjcf import MJCFExporter
    from stratamap.plugins.mappers.tsdf import TSDFMapper
    from stratamap.plugins.segmenters.oracle import OracleSegmenter

    spec = SceneSpec.model_validate(
        {
            "type": "kitchen",
            "seed": 3,
            "camera": {"width": 320, "height": 240},
            "trajectory": {"type": "walk", "frames": 40, "height": 1.3, "look_height": 0.6},
        }
    )
    world = SyntheticWorld(spec)
    data = PipelineData(stream=world.stream(), ground_truth=world.ground_truth())
    data = run_stages([OracleSegmenter(), TSDFMapper(voxel_size=0.02), FrontsCompleter()], data)
    out = tmp_path_factory.mktemp("fronts")
    MJCFExporter().run(data, out)
    return data, out / "scene.xml"


@pytest.mark.slow
def test_doors_and_drawers_of_a_rendered_kitchen_are_found_and_open(kitchen_run):
    from stratamap.core.evaluation.articulation import evaluate_articulation, opening_check

    data, scene = kitchen_run
    joints = [j for inst in data.map.instances if inst.completion is not None for j in inst.completion.joints]
    fronted = [inst for inst in data.map.instances if inst.completion and inst.completion.completer == "fronts"]
    assert fronted and {j.type for inst in fronted for j in inst.completion.joints} <= {"revolute", "prismatic"}
    assert len(joints) >= 3
    scores = evaluate_articulation(data.map.instances, data.ground_truth.objects)
    assert scores["matched_joints"] >= 2
    opened = opening_check(scene)
    assert opened["joints_checked"] >= 3 and opened["opens_clean_share"] >= 0.9
    note = data.notes["fronts"]["fronts"]
    assert note["articulated"] == len(fronted)
    # report.html draws every storage object's face with its fronts and hinge sides.
    from stratamap.core.evaluation.html_report import fronts_figure

    assert all(inst.attributes.get("fronts") for inst in fronted)
    assert fronts_figure(data).startswith("data:image/png")


def test_every_object_but_seating_is_looked_at():
    """Seating is not looked at, unless the segmenter measured a solid body without a seat (a run of
    drawers a detector voted "chair"): the shape is the evidence, the name only a vote."""
    from stratamap.core.map.layers import Geometry, ObjectInstance, ObjectInstances
    from stratamap.core.stages import PipelineData
    from stratamap.plugins.completers.fronts import FrontsCompleter

    rng = np.random.default_rng(3)
    pts = rng.uniform([0.0, 0.0, 0.0], [1.0, 0.6, 0.8], (2000, 3))
    box = OrientedBox(np.array([0.5, 0.3, 0.4]), 0.0, np.array([1.0, 0.6, 0.8]))
    data = PipelineData()
    data.map.geometry = Geometry(pts)
    data.map.instances = ObjectInstances(
        [
            ObjectInstance(1, "chair", pts, box),
            ObjectInstance(2, "object", pts, box),
            ObjectInstance(3, "cup", pts, box),
            ObjectInstance(4, "chair", pts, box, attributes={"shape": {"solid": True, "seat": False}}),
            ObjectInstance(5, "chair", pts, box, attributes={"shape": {"solid": True, "seat": True}}),
            ObjectInstance(6, "sofa", pts, box, attributes={"shape": {"solid": False, "seat": False}}),
        ]
    )
    FrontsCompleter().run(data)
    assert sorted(data.notes["fronts"]["fronts"]["per_object"]) == [2, 3, 4]
    FrontsCompleter(classes=["cup"]).run(data)
    assert sorted(data.notes["fronts"]["fronts"]["per_object"]) == [3]


def test_runs_of_a_sorted_array_are_what_unique_gives():
    from stratamap.plugins.completers.fronts.relief import _runs

    rng = np.random.default_rng(3)
    for n in (1, 2, 50, 5000):
        ordered = np.sort(rng.integers(0, max(1, n // 7), n))
        values, starts, counts = _runs(ordered)
        expected = np.unique(ordered, return_index=True, return_counts=True)
        for got, want in zip((values, starts, counts), expected, strict=True):
            assert np.array_equal(got, want)


@pytest.mark.slow
def test_an_object_too_shallow_for_a_drawer_box_gets_no_joint(kitchen_run):
    """min_depth: the same faces and fronts, but an object shallower behind its face than min_depth
    (a backsplash, a leaflet rack) opens nothing; the notes say why where a front would have opened."""
    from stratamap.plugins.completers.fronts import FrontsCompleter

    data, _ = kitchen_run
    FrontsCompleter(min_depth=5.0).run(data)
    note = data.notes["fronts"]["fronts"]
    assert note["articulated"] == 0 and note["joints"] == {"revolute": 0, "prismatic": 0}
    looked = [o for o in note["per_object"].values() if o.get("face", True) is not None]
    would_open = [o for o in looked if set(o["fronts"]) - {"panel"}]
    assert would_open and all(o["opens"].startswith("nothing:") for o in would_open)
    assert all("opens" not in o for o in looked if o not in would_open)


def test_depth_behind_a_face_is_what_the_points_reach_else_the_box():
    from stratamap.plugins.completers.fronts.body import depth_behind
    from stratamap.plugins.completers.fronts.face import Face

    face = Face(np.array([0.0, -1.0, 0.0]), 0.0, (-0.5, 0.5, 0.0, 0.8), 1.0, 0.0, 1, -1.0)  # y = 0, facing -y
    box = OrientedBox(np.array([0.0, 0.25, 0.4]), 0.0, np.array([1.0, 0.5, 0.8]))
    rng = np.random.default_rng(0)
    pts = rng.uniform([-0.5, 0.0, 0.0], [0.5, 0.12, 0.8], (500, 3))  # a 12 cm deep rack
    assert depth_behind(face, box, pts) == pytest.approx(0.12, abs=0.01)
    assert depth_behind(face, box, pts[:10]) == pytest.approx(0.5)  # too few points: the box's depth


def test_the_body_ends_a_worktop_over_its_face_not_at_the_top_of_its_box():
    """A counter's box on a real kitchen held the backsplash and what stood on a worktop the sensor
    never saw, 1.44 m high over a face 0.9 m high; a carcass that tall held those things, and the
    physical check threw its doors away. The body ends TOP_OVER_FACE over the face's top; a box no
    taller than that keeps its height."""
    from stratamap.plugins.completers.fronts.body import TOP_OVER_FACE, object_frame

    face = Face(np.array([0.0, -1.0, 0.0]), 0.0, (-1.0, 1.0, 0.05, 0.89), 1.0, 0.0, 1, -1.0)  # y = 0, facing -y
    tall = OrientedBox(np.array([0.0, 0.3, 0.72]), 0.0, np.array([2.0, 0.6, 1.44]))
    pose, size = object_frame(face, tall, 0.6)
    assert size[2] == pytest.approx(0.89 + TOP_OVER_FACE)
    assert pose[2, 3] == pytest.approx(0.0)  # still standing on the box's bottom
    fronts = [((-1.0, 0.0, 0.05, 0.89), "cupboard", "left", []), ((0.0, 1.0, 0.05, 0.89), "cupboard", "right", [])]
    body = articulated_body(size, fronts, np.eye(4), pose, "fronts", 1.0)
    assert body.world_mesh().bounds[1][2] <= 0.89 + TOP_OVER_FACE + 1e-6
    low = OrientedBox(np.array([0.0, 0.3, 0.45]), 0.0, np.array([2.0, 0.6, 0.9]))
    assert object_frame(face, low, 0.6)[1][2] == pytest.approx(0.9)


def test_the_front_is_the_side_whose_back_stands_against_a_wall_not_the_better_seen_one():
    """A fridge at the end of a run: its exposed side is seen whole, its front only in part, and the
    front is the face whose opposite side stands against the room's wall. With no wall behind it (none,
    one a metre away, one running behind a tenth of its width) the better seen side wins, as before."""
    from stratamap.core.geometry.transforms import make_pose
    from stratamap.core.simulation.structure import StaticBox
    from stratamap.plugins.completers.fronts.fronts import FaceParams, observe_front

    rng = np.random.default_rng(3)
    box = OrientedBox(np.array([0.0, 0.0, 0.85]), 0.0, np.array([0.6, 0.6, 1.7]))
    n = 6000
    # The front (-y) seen over its lower 60 %, the side (+x) whole.
    front = np.stack([rng.uniform(-0.3, 0.3, n), np.full(n, -0.3), rng.uniform(0.0, 1.0, n)], 1)
    side = np.stack([np.full(n, 0.3), rng.uniform(-0.3, 0.3, n), rng.uniform(0.0, 1.7, n)], 1)
    cloud = np.vstack([front, side]) + rng.normal(0.0, 0.001, (2 * n, 3))
    views = np.array([[0.0, -2.5, 1.3], [2.5, 0.0, 1.3]])
    params = FaceParams(max_frames=0)

    def chosen(walls):
        face, _, _ = observe_front(box, cloud, views, None, -0.05, params, walls)
        return np.round(face.normal, 1).tolist()

    def wall(y, x=0.0, length=4.0):
        # Parallel to the fridge's back (+y side), its surface at y: local x along it, local -y out of the room.
        return StaticBox("wall", "wall", make_pose((x, y + 0.05, 1.3), np.pi), np.array([length, 0.1, 2.6]))

    assert chosen([]) == [1.0, 0.0, 0.0]
    assert chosen([wall(0.32)]) == [0.0, -1.0, 0.0]
    assert chosen([wall(1.3)]) == [1.0, 0.0, 0.0]
    assert chosen([wall(0.32, x=-1.27, length=2.0)]) == [1.0, 0.0, 0.0]


@pytest.mark.parametrize("n_cells", [50, 70_000])  # cells as 16-bit integers, and too many for them
def test_cells_then_values_orders_each_cells_values_as_lexsort_does(n_cells):
    """The height map's per-cell medians come from this order: within every cell the values must run
    as ``np.lexsort`` sorts them, ties and repeated values included."""
    from stratamap.plugins.completers.fronts.relief import _by_cell_then_value

    rng = np.random.default_rng(3)
    cells = rng.integers(0, n_cells, 20_000)
    values = np.round(rng.normal(0.0, 0.01, cells.size), 3)  # rounded: many ties
    order = _by_cell_then_value(cells, values, n_cells)
    expected = np.lexsort((values, cells))
    assert np.array_equal(cells[order], cells[expected])
    assert np.array_equal(values[order], values[expected])


def test_a_faces_filled_cells_are_counted_as_unique_rows_of_cells_count_them():
    """The face plane's RANSAC scores a line by the 4 cm cells its inliers fill: one integer key per
    cell must count exactly what unique (u, z) rows of cell indices count, negative cells included."""
    from stratamap.plugins.completers.fronts.face import _cells_filled

    rng = np.random.default_rng(5)
    for n in (1, 7, 3000):
        u, z = rng.uniform(-1.3, 2.1, n), rng.uniform(-0.2, 1.9, n)
        rows = np.stack([np.floor(u / 0.04), np.floor(z / 0.04)], 1)
        assert _cells_filled(u, z, 0.04) == len(np.unique(rows, axis=0))
