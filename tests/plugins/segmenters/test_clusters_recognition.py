"""Geometry-first instances on a mapper's masks (``keep_instances``) and recognition by class size
priors and support context (``recognize``): the detector pipeline's objects that no box covered, and
labels a detector without 'counter' or 'cabinet' gives them (issue 28)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.map.instances import SHAPE_FLAGS, naming_text
from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.parts import join_parts
from stratamap.plugins.segmenters.clusters.shapes import (
    Shape,
    describe_shape,
    fits_class,
    on_a_support,
    prior_class,
    typical_rather,
)
from stratamap.plugins.segmenters.clusters.units import split_at_step
from tests.plugins.segmenters.test_layout_planes import ROOM, chair, room_shell, solids, table

VOCAB = Vocabulary.default()


def shape(**kw) -> Shape:
    base = dict(
        length=0.5, depth=0.4, height=0.5, bottom=0.0, reach=0.4, against_wall=False, flat_top=False, solid=False
    )
    return Shape(**{**base, **kw})


def test_size_priors_veto_impossible_labels():
    assert not fits_class("box", shape(length=1.7, depth=0.7, height=0.9, reach=1.0))  # a 1.7 m box
    assert not fits_class("table", shape(length=0.12, depth=0.1, height=0.09, bottom=0.7, reach=0.08))
    assert not fits_class("chair", shape(length=0.3, depth=0.1, height=0.2, bottom=0.45, reach=0.18))  # in the air
    assert not fits_class("counter", shape(length=0.4, depth=0.4, height=0.9, reach=0.55))  # shorter than any run
    assert fits_class("cabinet", shape(length=0.6, depth=0.6, height=2.1, reach=1.1))  # a tall unit
    assert fits_class("cup", shape(length=0.1, depth=0.08, height=0.1, bottom=0.75, reach=0.07))
    # Heights: a 1.7 m "chair" is a tall unit, a 10 cm "monitor" on a worktop is none; a counter may
    # carry a coffee machine.
    assert not fits_class("chair", shape(length=0.78, depth=0.6, height=1.68, reach=0.99))
    assert fits_class("chair", shape(length=0.6, depth=0.55, height=1.2, reach=0.7))
    assert not fits_class("monitor", shape(length=0.5, depth=0.3, height=0.1, bottom=0.9, reach=0.3))
    assert fits_class("counter", shape(length=1.5, depth=0.6, height=1.35, reach=0.95, solid=True))


def test_support_context_names_units_tables_and_cups():
    unit = dict(bottom=0.0, against_wall=True, flat_top=True, solid=True)
    assert prior_class(shape(length=1.6, depth=0.6, height=0.9, reach=0.9, **unit), VOCAB)[0] == "counter"
    assert prior_class(shape(length=0.6, depth=0.4, height=0.85, reach=0.6, **unit), VOCAB)[0] == "cabinet"
    tall = shape(length=0.6, depth=0.6, height=2.0, reach=1.05, against_wall=True, solid=True)
    assert prior_class(tall, VOCAB)[0] == "cabinet"  # its top above the camera, unseen
    legs = shape(length=1.2, depth=0.8, height=0.75, reach=0.8, flat_top=True)
    assert prior_class(legs, VOCAB)[0] == "table"
    assert prior_class(shape(length=0.1, depth=0.08, height=0.1, bottom=0.75, reach=0.07), VOCAB)[0] == "cup"
    hung = shape(length=0.8, depth=0.35, height=0.7, bottom=1.4, reach=0.55, against_wall=True, solid=True)
    assert prior_class(hung, VOCAB)[0] == "cabinet"
    assert prior_class(shape(length=0.6, depth=0.6, height=0.08, reach=0.4), VOCAB)[0] == "object"  # a chair's base
    # A solid 0.9 m unit against a wall that a detector called a table: worktop height, not table height.
    counter = shape(length=2.4, depth=0.7, height=0.9, reach=1.3, **unit)
    assert typical_rather("counter", "table", counter) and not typical_rather("table", "table", counter)
    assert not typical_rather("counter", "table", shape(length=1.6, depth=0.8, height=0.74, reach=0.9, **unit))


def test_a_unit_below_worktop_height_is_no_counter():
    """Worktops stand 0.85 m high or more (a map measures them a few centimetres higher): a closed
    0.8 m display cube or sideboard, long and deep enough for a counter, is a cabinet."""
    unit = dict(bottom=0.0, against_wall=True, flat_top=True, solid=True)
    cube = shape(length=0.95, depth=0.9, height=0.8, reach=0.85, **unit)
    assert not fits_class("counter", cube) and prior_class(cube, VOCAB)[0] == "cabinet"
    worktop = shape(length=0.95, depth=0.62, height=0.88, reach=0.75, **unit)
    assert prior_class(worktop, VOCAB)[0] == "counter"


def test_a_long_low_unit_is_a_cabinet_and_a_long_tall_one_is_several():
    """A TV bench or a lowboard comes up to 3 m long as one piece; a 2.9 m unit of worktop height is
    a run of units (a counter) and of a sideboard's height several cabinets, not one."""
    unit = dict(bottom=0.0, against_wall=True, flat_top=True, solid=True)
    bench = shape(length=2.9, depth=0.62, height=0.52, reach=1.5, **unit)
    assert fits_class("cabinet", bench) and prior_class(bench, VOCAB)[0] == "cabinet"
    assert not fits_class("cabinet", shape(length=2.9, depth=0.45, height=0.8, reach=1.55, **unit))
    assert not fits_class("cabinet", shape(length=3.5, depth=0.62, height=0.52, reach=1.8, **unit))


def test_a_small_piece_on_no_support_is_no_cup():
    """A cup, a bottle or a box stands on a support surface: a small piece off the floor resting on
    none (a fragment of a chair's base in a real floor scan) is named by no rule."""
    small = shape(length=0.1, depth=0.08, height=0.1, bottom=0.2, reach=0.07)
    assert prior_class(small, VOCAB)[0] == "cup"
    assert prior_class(small, VOCAB, on_support=False)[0] == "object"
    supports = np.array([0.75])
    assert on_a_support(0.76, supports, 0.03) and not on_a_support(small.bottom, supports, 0.03)
    assert not on_a_support(0.76, np.array([]), 0.03)


def test_shape_tells_a_solid_unit_from_a_table_on_legs():
    unit, _ = solids([("counter", (0.0, 0.0, 0.0), (1.6, 0.6, 0.9))], 0.02)
    legs, _ = solids(table(3.0, 2.5), 0.02)
    s_unit, s_table = describe_shape(unit, 0.0, []), describe_shape(legs, 0.0, [])
    assert s_unit.solid and s_unit.flat_top and abs(s_unit.height - 0.9) < 0.03
    assert s_table.flat_top and not s_table.solid


def writing_desk(pedestals: bool = False) -> list:
    """A 1.2 x 0.6 m top at 0.75 m on four legs, drawers hanging under the top from 0.45 m along its
    whole length, or two drawer pedestals down to the floor at its ends (knee space between)."""
    parts = [("desk", (0.0, 0.0, 0.72), (1.2, 0.6, 0.75))]
    if pedestals:
        return parts + [("desk", (0.0, 0.02, 0.0), (0.4, 0.58, 0.72)), ("desk", (0.8, 0.02, 0.0), (1.2, 0.58, 0.72))]
    parts.append(("desk", (0.03, 0.02, 0.45), (1.17, 0.58, 0.72)))
    return parts + [("desk", (x, y, 0.0), (x + 0.04, y + 0.04, 0.45)) for x in (0.03, 1.13) for y in (0.02, 0.54)]


def test_a_unit_over_knee_space_is_a_desk_and_one_closed_to_the_floor_is_not():
    """Knee space: nothing of a desk's body below 0.4 m across the middle of its length (legs or
    pedestals at its ends, drawers above). A sideboard's front reaches the floor, and a night stand's
    body on short legs comes down to 0.2 m: units, not desks."""
    for desk in (writing_desk(), writing_desk(pedestals=True)):
        points, _ = solids(desk, 0.02)
        found = describe_shape(points, 0.0, [])
        assert found.knee_space and found.flat_top, found
        assert prior_class(found._replace(solid=True), VOCAB)[0] == "desk"
    sideboard, _ = solids([("cabinet", (0.0, 0.0, 0.0), (1.2, 0.6, 0.75))], 0.02)
    assert not describe_shape(sideboard, 0.0, []).knee_space
    legs = [("cabinet", (x, y, 0.0), (x + 0.04, y + 0.04, 0.2)) for x in (0.0, 1.16) for y in (0.0, 0.56)]
    on_legs, _ = solids([("cabinet", (0.0, 0.0, 0.2), (1.2, 0.6, 0.75))] + legs, 0.02)
    shape_on_legs = describe_shape(on_legs, 0.0, [])
    assert not shape_on_legs.knee_space
    assert prior_class(shape_on_legs._replace(solid=True), VOCAB)[0] != "desk"


def kitchen_room(spacing: float, tight: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A room with a table (a cup on it), a chair, and a counter unit against the x=0 wall; its
    walls 1 m around them (``tight``) or the whole ROOM's."""
    parts = table(3.0, 2.5) + [("cup", (3.2, 2.4, 0.75), (3.28, 2.48, 0.85))] + chair(3.0, 3.35)
    parts.append(("counter", (0.02, 1.0, 0.0), (0.62, 2.6, 0.9)))  # its back 2 cm off the wall
    objects, names = solids(parts, spacing)
    layout = room_shell(spacing, around=objects if tight else None)
    # Nothing of an object is seen where it stands on the floor, nor the counter's back on the wall.
    keep = (objects[:, 2] > 1e-6) & ~((names == "counter") & (objects[:, 0] < 0.03))
    points = np.concatenate([p for _, p in layout] + [objects[keep]])
    labels = np.concatenate([np.full(len(p), n) for n, p in layout] + [names[keep]])
    return points, labels


def test_keep_instances_adds_what_no_mask_covered_and_names_it():
    """A mapper's masks: the table's top only (its box also over the cup), the chair; no box on the
    counter (a detector without that label), its frames' guesses 'wall' on its front."""
    points, names = kitchen_room(0.02)
    classes = np.zeros(len(points), np.int32)
    instances = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    top = (names == "table") & (points[:, 2] > 0.7)
    masked = top | (names == "cup")
    classes[masked], instances[masked] = VOCAB.id("table"), 1
    classes[names == "chair"], instances[names == "chair"] = VOCAB.id("chair"), 2
    front = (names == "counter") & (points[:, 0] > 0.61)
    classes[front] = VOCAB.id("wall")
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    sem = out["semantics"]
    by_class = {}
    for inst in out["instances"]:
        by_class.setdefault(inst.class_name, []).append(inst)
    assert sorted(by_class) == ["chair", "counter", "cup", "table"], {k: len(v) for k, v in by_class.items()}
    assert all(len(v) == 1 for v in by_class.values())
    # The table's unmasked legs joined it; the cup in its mask is an object of its own.
    assert by_class["table"][0].box.size[2] > 0.7
    assert (sem.instance_ids[names == "cup"] == by_class["cup"][0].id).mean() > 0.7
    assert (sem.instance_ids[names == "counter"] == by_class["counter"][0].id).mean() > 0.9
    stuff = np.isin(names, ["floor", "wall", "ceiling"])
    assert (sem.instance_ids[stuff] > 0).sum() <= 3 * len(out["instances"])
    # What was measured of each object's shape travels with it (fronts reads it, not the class).
    assert by_class["counter"][0].attributes["shape"]["solid"]
    assert not by_class["counter"][0].attributes["shape"]["seat"]
    assert not by_class["table"][0].attributes["shape"]["solid"]
    assert all(set(inst.attributes["shape"]) == set(SHAPE_FLAGS) for inst in out["instances"])


def test_a_frame_with_no_box_leaves_objects_things_though_their_feet_were_voted_floor():
    """A detector that boxed nothing: the frames voted only floor, wall and ceiling, and the floor's
    votes spilled onto the bottom 4 cm of the counter and the chair's legs. Those objects stay things
    (named by their shape), while a thin bump of floor the layout left out, voted floor, is floor."""
    points, names = kitchen_room(0.02, tight=False)  # the mat lies beyond a tight room's wall
    mat = (points[:, 0] > 4.5) & (points[:, 0] < 5.5) & (points[:, 1] > 0.5) & (points[:, 1] < 1.5)
    mat &= names == "floor"
    points = points.copy()
    points[mat, 2] += 0.06 * (points[mat, 0] - 4.5)  # a ramp rising 6 cm, 3.4 deg: off the floor's level
    classes = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    spilled = np.isin(names, ["counter", "chair"]) & (points[:, 2] < 0.04)
    classes[spilled] = VOCAB.id("floor")
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, np.zeros(len(points), np.int32), VOCAB)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    sem = out["semantics"]
    for name in ("counter", "chair", "table"):
        on = names == name
        assert (sem.instance_ids[on] > 0).mean() > 0.9, name
        assert (sem.class_ids[on] == VOCAB.id("floor")).mean() < 0.1, name
    assert (sem.class_ids[mat] == VOCAB.id("floor")).mean() > 0.9
    assert (sem.instance_ids[mat] > 0).mean() < 0.1


@pytest.mark.slow  # a whole pipeline run (make test runs it; make test-fast does not)
def test_clusters_takes_the_floor_where_the_rgbd_source_found_it():
    """A sequence source's gravity alignment put the floor at z = 0; the single frame's floor bends
    down at range. clusters labels the near floor floor, and the table stays a table on it."""
    from stratamap.core.map.sensors import SensorStream
    from tests.plugins.segmenters.test_layout_planes import bent_floor_room

    points, names = bent_floor_room(0.02)
    classes = {}
    for hint in (False, True):
        data = PipelineData()
        data.map.geometry = Geometry(points=points, voxel_size=0.02)
        data.stream = SensorStream("frame", metadata={"gravity_alignment": {"floor_inliers": 5000}} if hint else {})
        sem = ClustersSegmenter(recognize=True).run(data)["semantics"]
        classes[hint] = sem.class_ids
    near = (names == "floor") & (points[:, 1] < 3.0)
    assert (classes[True][near] == VOCAB.id("floor")).mean() > 0.95
    assert (classes[False][near] == VOCAB.id("floor")).mean() < 0.5


def test_without_keep_instances_nothing_changes_by_default():
    """Both options are off by default: clusters alone, as configs/bench/completion.yaml runs it."""
    points, names = kitchen_room(0.03)
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.03)
    out = ClustersSegmenter().run(data)
    assert "counter" not in {i.class_name for i in out["instances"]}


def test_a_piece_nothing_holds_up_joins_the_chair_it_lies_within():
    """The frames' boxes took the middle of the chair's backrest for a monitor: an instance of its
    own, of a monitor's size, but off the floor, off the walls and within the chair (not rising
    above it, as a cup does above a table). It is part of the chair."""
    points, names = kitchen_room(0.02)
    classes = np.zeros(len(points), np.int32)
    instances = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    classes[names == "table"], instances[names == "table"] = VOCAB.id("table"), 1
    chair_points = names == "chair"
    classes[chair_points], instances[chair_points] = VOCAB.id("chair"), 2
    backrest_top = chair_points & (points[:, 2] > 0.7) & (np.abs(points[:, 0] - 3.0) < 0.12)  # between the posts
    classes[backrest_top], instances[backrest_top] = VOCAB.id("monitor"), 3
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    assert "monitor" not in {inst.class_name for inst in out["instances"]}
    sem = out["semantics"]
    chair_id = np.bincount(sem.instance_ids[chair_points]).argmax()
    assert chair_id > 0 and (sem.instance_ids[backrest_top] == chair_id).mean() > 0.9


def unit_row(
    spacing: float, with_tall_unit: bool = True, machine: bool = False, microwave: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Against the x=0 wall: a 1.5 m counter (0.9 m) and, beside it, a 0.6 m tall unit (2.0 m, 0.6 m
    deep like the counter, their fronts in one plane, no gap); optionally a coffee machine standing back
    on the worktop, or a microwave at its front edge. Neither back nor the floor under them is seen."""
    parts = [("counter", (0.0, 1.0, 0.0), (0.6, 2.5, 0.9))]
    if with_tall_unit:
        parts.append(("cabinet", (0.0, 2.5, 0.0), (0.6, 3.1, 2.0)))
    if machine:
        parts.append(("machine", (0.05, 2.1, 0.9), (0.4, 2.45, 1.35)))
    if microwave:
        parts.append(("microwave", (0.2, 1.95, 0.9), (0.6, 2.45, 1.22)))
    points, names = solids(parts, spacing)
    keep = (points[:, 2] > 1e-6) & (points[:, 0] > 1e-6)
    return points[keep], names[keep]


def test_units_side_by_side_are_split_where_the_top_steps():
    points, names = unit_row(0.02)
    tall = split_at_step(points, 0.0)
    assert tall is not None
    off_seam = np.abs(points[:, 1] - 2.5) > 0.03  # the side faces where the units meet go either way
    assert (tall == (names == "cabinet"))[off_seam].mean() > 0.99
    # A worktop alone, or with a coffee machine standing back on it, is one unit.
    points, _ = unit_row(0.02, with_tall_unit=False)
    assert split_at_step(points, 0.0) is None
    points, _ = unit_row(0.02, with_tall_unit=False, machine=True)
    assert split_at_step(points, 0.0) is None
    # An appliance at the worktop's front edge rises less than any tall unit.
    points, _ = unit_row(0.02, with_tall_unit=False, microwave=True)
    assert split_at_step(points, 0.0) is None


def in_room(*parts: tuple[np.ndarray, np.ndarray], whole_room: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A room shell 1 m around objects' (points, names), or the whole ROOM's, with them in it."""
    layout = room_shell(0.02, around=None if whole_room else np.concatenate([p for p, _ in parts]))
    points = np.concatenate([p for _, p in layout] + [p for p, _ in parts])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [n for _, n in parts])
    return points, names


def recognized(points: np.ndarray, names: np.ndarray, masks: list[tuple[np.ndarray, str]], **params) -> dict:
    """clusters {keep_instances, recognize, and ``params``} on a map whose frames voted the room's
    stuff and, as instances 1, 2, ..., each mask with its class."""
    classes = np.zeros(len(points), np.int32)
    instances = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    for iid, (mask, class_name) in enumerate(masks, start=1):
        classes[mask], instances[mask] = VOCAB.id(class_name), iid
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    return ClustersSegmenter(keep_instances=True, recognize=True, **params).run(data)


@pytest.mark.parametrize("front_vote", ["chair", "monitor"])
def test_a_detector_box_over_two_units_gives_a_counter_and_a_cabinet(front_vote):
    """The frames' detector framed the counter and the tall unit beside it as one "box" (their
    fronts are one plane: no depth edge parts them), and the counter's upper front as a chair or a
    monitor. Recognition splits the row at the step; the piece off the floor within the counter,
    no small thing on a support, joins it."""
    points, names = in_room(unit_row(0.02))
    units = np.isin(names, ["counter", "cabinet"])
    upper_front = (names == "counter") & (points[:, 2] > 0.35) & (points[:, 1] < 2.2)
    out = recognized(points, names, [(units & ~upper_front, "box"), (upper_front, front_vote)])
    named = sorted(inst.class_name for inst in out["instances"])
    assert named == ["cabinet", "counter"], named
    sem = out["semantics"]
    counter_id = np.bincount(sem.instance_ids[names == "counter"]).argmax()
    assert (sem.instance_ids[upper_front] == counter_id).mean() > 0.9
    assert (sem.instance_ids[names == "cabinet"] != counter_id).mean() > 0.95


def test_a_mug_voted_table_on_a_worktop_stays_a_mug():
    """A mug the frames voted "table" (off the floor, a floor-standing class) stands on a counter whose
    coffee machine rises above it: it lies within the counter's height and footprint, yet it is a
    thing on a support by its size, not a piece of the counter."""
    mug, mug_names = solids([("mug", (0.3, 1.4, 0.9), (0.38, 1.48, 1.0))], 0.02)
    above = mug[:, 2] > 0.9 + 1e-6
    points, names = in_room(unit_row(0.02, with_tall_unit=False, machine=True), (mug[above], mug_names[above]))
    out = recognized(points, names, [(np.isin(names, ["counter", "machine"]), "box"), (names == "mug", "table")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["counter", "cup"]


def test_a_coffee_table_is_a_table():
    """A coffee table 0.4 m high, its top on four legs (coffee tables stand 0.35-0.5 m, far below a
    dining table's 0.72-0.76 m): a table by its shape, not an ``object`` too low for the class."""
    points, _ = solids(table(3.0, 2.5, size=(1.0, 0.55), height=0.4), 0.02)
    shape = describe_shape(points[points[:, 2] > 1e-6], 0.0, [])
    assert fits_class("table", shape)
    assert prior_class(shape, VOCAB)[0] == "table"


def test_a_mug_flush_with_a_tables_edge_is_a_mug():
    """A mug standing at a table's front edge, its front in the plane of the table's apron: the
    two meet smoothly, so convexity alone leaves them one segment, and the table's mask took the mug
    along. What rises above the top within its footprint, far narrower than the top, stands on it: a
    mug of its own; the table stays one table."""
    top, x, y, (w, d) = 0.72, 3.0, 2.5, (1.0, 0.6)
    front = y - d / 2
    parts = table(x, y, size=(w, d), height=top) + [
        ("table", (x - w / 2, front, top - 0.1), (x + w / 2, front + 0.02, top))
    ]
    table_points, table_names = solids(parts, 0.02)
    mug, mug_names = solids([("mug", (x + 0.1, front, top), (x + 0.19, front + 0.09, top + 0.1))], 0.02)
    above = mug[:, 2] > top + 1e-6
    points, names = in_room((table_points, table_names), (mug[above], mug_names[above]))
    out = recognized(points, names, [(np.isin(names, ["table", "mug"]), "table")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["cup", "table"]
    cup = next(inst for inst in out["instances"] if inst.class_name == "cup")
    # Its lowest centimetres lie within the top's plane tolerance and stay the table's, as on any table.
    assert (out["semantics"].instance_ids[names == "mug"] == cup.id).mean() > 0.6
    assert max(cup.box.size[:2]) < 0.15 and cup.box.size[2] > 0.07


def test_a_mug_voted_table_on_a_tables_top_is_no_piece_of_the_table():
    """The frames voted a mug on a table's top "table" (a coffee table's box covers what stands on it),
    and the table's own instance holds something as high as the mug (a second mug its mask took along):
    the mug lies within the table's height and footprint. Yet it stands at the top's height, of a mug's
    size: a thing on the table, not a piece of it (``join_parts``)."""
    top = 0.75
    table_points, _ = solids(table(3.0, 2.5) + [("table", (2.6, 2.3, top), (2.7, 2.4, top + 0.12))], 0.02)
    mug, _ = solids([("mug", (3.1, 2.5, top), (3.18, 2.58, top + 0.1))], 0.02)
    mug = mug[mug[:, 2] > top + 1e-6]
    points = np.concatenate([table_points, mug])
    class_ids = np.full(len(points), VOCAB.id("table"), np.int32)
    instance_ids = np.r_[np.ones(len(table_points)), np.full(len(mug), 2)].astype(np.int32)
    config = ClustersSegmenter(keep_instances=True, recognize=True).config
    lab = Labelling.of_labels(config, points, VOCAB, class_ids, instance_ids, 0.02, np.array([top]))
    join_parts(lab)
    assert (lab.instance_ids[len(table_points) :] == 2).all()


def test_seating_is_no_table():
    """A table's top view is one level; an armchair's is a seat with arms or a back above it. A
    detector's "table" over an armchair open below its seat does not fit."""
    armchair = shape(length=0.92, depth=0.81, height=0.72, reach=0.7, seat=True)
    assert not fits_class("table", armchair)
    assert fits_class("table", armchair._replace(seat=False, flat_top=True))
    assert fits_class("chair", armchair)


def test_a_mug_a_counter_detection_took_along_is_a_mug():
    """A detector without a 'counter' label framed the counter (with its coffee machine) as a "box",
    and that mask took the mug on the worktop along. A class the counter's own size rules out names
    neither object: the mug, standing on the worktop within the counter's height, is a cup."""
    mug, mug_names = solids([("mug", (0.3, 1.4, 0.9), (0.38, 1.48, 1.0))], 0.02)
    above = mug[:, 2] > 0.9 + 1e-6
    points, names = in_room(unit_row(0.02, with_tall_unit=False, machine=True), (mug[above], mug_names[above]))
    out = recognized(points, names, [(np.isin(names, ["counter", "machine", "mug"]), "box")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["counter", "cup"]


def test_a_mug_framed_with_a_strip_of_worktop_is_a_mug():
    """A frame's mask voted "table" holds a mug standing on the worktop and a strip of the counter's
    front below the worktop's far end (the mask spilled as the camera moved): more of it is the mug
    than the strip, so the mug is no small part of a larger mask. A thing of a mug's size standing on
    a support is an object of its own inside any other thing's mask."""
    mug, mug_names = solids([("mug", (0.3, 1.4, 0.9), (0.38, 1.48, 1.0))], 0.02)
    above = mug[:, 2] > 0.9 + 1e-6
    points, names = in_room(unit_row(0.02, with_tall_unit=False), (mug[above], mug_names[above]))
    strip = (names == "counter") & (points[:, 0] > 0.59) & (points[:, 1] > 2.42) & (points[:, 2] > 0.75)
    assert strip.sum() < (names == "mug").sum()
    out = recognized(points, names, [((names == "counter") & ~strip, "box"), ((names == "mug") | strip, "table")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["counter", "cup"]
    cup = next(inst for inst in out["instances"] if inst.class_name == "cup")
    assert cup.box.size[2] < 0.15


def test_a_table_top_over_part_of_a_chair_stays_a_table():
    """A table top whose legs went unseen, voted "table", off the floor, over part of a chair's
    footprint (the real office clip's round table beside its chair): only a piece lying wholly within
    the chair would be part of it; this one stays a table."""
    objects, object_names = solids(chair(3.0, 3.35) + [("table", (2.9, 3.2, 0.6), (3.5, 3.45, 0.63))], 0.02)
    keep = (objects[:, 2] > 1e-6) & ~((object_names == "table") & (objects[:, 2] < 0.6 + 1e-6))
    points, names = in_room((objects[keep], object_names[keep]))
    out = recognized(points, names, [(names == "chair", "chair"), (names == "table", "table")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["chair", "table"]


def test_a_table_is_open_below_its_top():
    """A detector without cabinet labels calls a bedside cabinet or a sideboard a table: a body closed
    along its length at mid-height is a unit, not a table on legs or a pedestal; a table top seen in
    the air (legs unseen) is judged as before."""
    closed = shape(length=0.35, depth=0.34, height=0.48, reach=0.41, against_wall=True, flat_top=True, solid=True)
    assert not fits_class("table", closed)
    assert fits_class("table", closed._replace(solid=False))
    assert fits_class(
        "table", shape(length=1.2, depth=0.8, height=0.1, bottom=0.65, reach=0.7, flat_top=True, solid=True)
    )
    assert fits_class("desk", shape(length=1.4, depth=0.7, height=0.74, reach=0.8, flat_top=True, solid=True))
    # A bedside cabinet is a cabinet, not something no rule names (it was below a cabinet's typical heights).
    assert prior_class(closed, VOCAB)[0] == "cabinet"
    assert prior_class(closed._replace(height=0.2, reach=0.3), VOCAB)[0] != "cabinet"  # a crate on the floor


def test_a_bedside_cabinet_voted_table_becomes_a_cabinet():
    """In a room: a 0.48 m closed cube the frames voted "table" is a cabinet; a table on legs voted
    "table" stays one."""
    unit, unit_names = solids([("bedside", (0.02, 1.0, 0.0), (0.37, 1.35, 0.48))], 0.02)
    legs, leg_names = solids(table(2.5, 2.0), 0.02)
    keep = (unit[:, 2] > 1e-6) & (unit[:, 0] > 0.02 + 1e-6)  # its bottom on the floor and its back on the wall unseen
    points, names = in_room((unit[keep], unit_names[keep]), (legs, leg_names))
    out = recognized(points, names, [(names == "bedside", "table"), (names == "table", "table")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["cabinet", "table"]


def test_a_chair_cut_at_its_seat_is_one_chair():
    """The frames' masks parted a chair at its seat: the seat's underside on its legs (a flat top on
    legs, voted "table") and, above it, the seat with the backrest (voted "chair", off the floor).
    Chairs stand on no other object, and the lower piece lies wholly under the upper one: one chair."""
    x, y, s = 2.5, 2.0, 0.23
    parts = [
        ("seat", (x - s, y - s, 0.45), (x + s, y + s, 0.5)),
        ("back", (x - s, y + s - 0.04, 0.5), (x + s, y + s, 1.0)),
    ]
    parts += [
        ("leg", (x + sx * s - 0.02, y + sy * s - 0.02, 0.0), (x + sx * s + 0.02, y + sy * s + 0.02, 0.45))
        for sx in (-1, 1)
        for sy in (-1, 1)
    ]
    chair_points, _ = solids(parts, 0.02)
    keep = chair_points[:, 2] > 1e-6
    points, names = in_room((chair_points[keep], np.full(int(keep.sum()), "chair")))
    upper = (names == "chair") & (points[:, 2] >= 0.49)
    out = recognized(points, names, [((names == "chair") & ~upper, "table"), (upper, "chair")])
    assert [inst.class_name for inst in out["instances"]] == ["chair"]


def test_seating_and_worktops_have_their_sizes():
    """A 1.6 m "chair" is no chair; a sideboard (low or shallow) is a cabinet, a 0.62 m deep unit at
    worktop height a counter."""
    assert not fits_class("chair", shape(length=1.61, depth=0.51, height=0.67, reach=1.0, flat_top=True, solid=True))
    unit = dict(bottom=0.0, against_wall=True, flat_top=True, solid=True)
    assert prior_class(shape(length=1.6, depth=0.5, height=0.66, reach=0.9, **unit), VOCAB)[0] == "cabinet"
    assert prior_class(shape(length=1.4, depth=0.45, height=0.85, reach=0.85, **unit), VOCAB)[0] == "cabinet"
    assert prior_class(shape(length=1.4, depth=0.62, height=0.9, reach=0.85, **unit), VOCAB)[0] == "counter"


def test_a_long_sideboard_as_the_map_measures_it_is_a_cabinet():
    """The map makes a unit deeper and longer than it is: a 1.7 x 0.49 m sideboard at worktop height
    measured 1.83 x 0.53 m on a tuning walk. It is one cabinet (sideboards reach 2 m), not a counter
    (0.55 m deep at least) and not an unnamed object; the worktop run it resembles stays a counter."""
    unit = dict(bottom=0.0, against_wall=True, flat_top=True, solid=True)
    sideboard = shape(length=1.83, depth=0.53, height=0.88, reach=0.98, **unit)
    assert prior_class(sideboard, VOCAB)[0] == "cabinet"
    assert prior_class(sideboard._replace(depth=0.56), VOCAB)[0] == "counter"
    assert not fits_class("cabinet", sideboard._replace(length=2.7, reach=1.4))  # a run of units


def test_a_sliver_within_a_cabinet_joins_it():
    """The frames' masks took a sliver of a sideboard's top for an object of its own: off the floor and
    lying within a floor-standing cabinet (not a class that never stands on another), it joins it."""
    unit, unit_names = solids([("sideboard", (0.02, 1.0, 0.0), (0.47, 2.4, 0.8))], 0.02)
    keep = (unit[:, 2] > 1e-6) & (unit[:, 0] > 0.02 + 1e-6)
    points, names = in_room((unit[keep], unit_names[keep]))
    sliver = (names == "sideboard") & (points[:, 2] > 0.8 - 1e-6) & (points[:, 1] > 1.6) & (points[:, 1] < 1.9)
    out = recognized(points, names, [((names == "sideboard") & ~sliver, "cabinet"), (sliver, "box")])
    assert [inst.class_name for inst in out["instances"]] == ["cabinet"]


def desk_scene(on_desk: list[tuple[str, tuple, tuple]]) -> tuple[np.ndarray, np.ndarray]:
    """A 1.6 x 0.8 m desk (top at 0.75 m) in the room with ``on_desk`` boxes standing on its top; what
    stands on the floor or on the top is unseen where it touches them."""
    objects, names = solids(table(3.0, 2.5, name="desk", size=(1.6, 0.8)) + on_desk, 0.02)
    keep = objects[:, 2] > 1e-6
    keep &= ~((names != "desk") & (objects[:, 2] < 0.75 + 1e-6))
    return in_room((objects[keep], names[keep]))


def test_a_unit_on_a_desk_that_a_chair_box_framed_is_no_chair():
    """A real frame's weak "chair" box took a shelf unit standing on a desk (TUM's double desk): chairs
    stand on no other object, and this one's foot lies on the desk's top, over it. It is no chair."""
    points, names = desk_scene([("unit", (2.5, 2.6, 0.75), (3.3, 2.85, 1.2))])
    out = recognized(points, names, [(names == "desk", "desk"), (names == "unit", "chair")])
    classes = sorted(inst.class_name for inst in out["instances"])
    assert "chair" not in classes and "desk" in classes


def test_a_chair_seen_over_a_desks_far_edge_stays_a_chair():
    """A chair behind a desk, seen only above the desk's top (its seat and legs hidden): its foot is at
    the desk top's height and touches its far edge, but lies beyond it, not on it. It stays a chair."""
    hidden_chair = [("chair", (2.7, 2.95, 0.75), (3.2, 3.0, 1.1))]  # the backrest above the desk's top
    points, names = desk_scene(hidden_chair)
    out = recognized(points, names, [(names == "desk", "desk"), (names == "chair", "chair")])
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1 and chairs[0].box.size[2] > 0.3


def test_a_chair_pushed_under_a_table_stays_a_chair():
    """A chair pushed under a desk, seen from above: only its backrest shows, rising from the desk
    top's edge (its back 3 cm inside the edge, its seat and legs hidden under the top). Its foot is on
    the top's edge, not well inside it: it stays a chair."""
    points, names = desk_scene([("chair", (2.75, 2.1, 0.75), (3.25, 2.13, 1.05))])  # the desk's front edge: y = 2.1
    out = recognized(points, names, [(names == "desk", "desk"), (names == "chair", "chair")])
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1 and chairs[0].box.size[2] > 0.25


def test_a_chairs_back_above_a_table_tops_height_joins_its_chair_and_the_cup_on_the_table_stays():
    """The frames boxed the top of one half of a chair's back, rising from the height of the table top
    beside it, as a "box": of a box's size, its foot at a support's height. But no support surface lies under
    it, the chair holds none at that height, and it lies within the chair's box: it is part of the
    chair (``join_enclosed``). The cup on the table's top stands on a support surface: an object of
    its own."""
    points, names = kitchen_room(0.02)
    back_top = (names == "chair") & (points[:, 2] > 0.76) & (points[:, 0] > 2.95)  # one post and half the back
    assert points[back_top, 1].min() > 2.9  # beside the table's top, not over it
    out = recognized(
        points,
        names,
        [
            (names == "table", "table"),
            (names == "cup", "cup"),
            ((names == "chair") & ~back_top, "chair"),
            (back_top, "box"),
        ],
    )
    assert sorted(inst.class_name for inst in out["instances"]) == ["chair", "counter", "cup", "table"]
    sem = out["semantics"]
    chair_id = np.bincount(sem.instance_ids[(names == "chair") & ~back_top]).argmax()
    assert (sem.instance_ids[back_top] == chair_id).all()


def armchair(x: float, y: float) -> list:
    """A 0.8 x 0.8 m armchair: a seat block, two arms and a back, standing on the floor."""
    return [
        ("armchair", (x - 0.3, y - 0.4, 0.0), (x + 0.3, y + 0.25, 0.42)),
        ("arm", (x - 0.4, y - 0.4, 0.0), (x - 0.3, y + 0.4, 0.62)),
        ("armchair", (x + 0.3, y - 0.4, 0.0), (x + 0.4, y + 0.4, 0.62)),
        ("armchair", (x - 0.3, y + 0.25, 0.0), (x + 0.3, y + 0.4, 0.85)),
    ]


def test_an_armchairs_arm_boxed_as_a_chair_of_its_own_joins_it():
    """The frames boxed an armchair's arm apart, as a "chair": a chair's size by the priors and on the
    floor, but it lies within the armchair's box, and one chair does not stand within another. One
    chair."""
    objects, names = solids(armchair(3.0, 2.5), 0.02)
    keep = objects[:, 2] > 1e-6
    points, names = in_room((objects[keep], names[keep]))
    out = recognized(points, names, [(names == "armchair", "chair"), (names == "arm", "chair")])
    assert [inst.class_name for inst in out["instances"]] == ["chair"]


def test_a_chair_pushed_under_a_table_is_a_chair_of_its_own():
    """A chair pushed under a table lies (all but its back's top) within the table's box: furniture
    standing on the floor, of a class its shape fits, under furniture with room below its top. It is
    no piece of the table."""
    objects, names = solids(table(3.0, 2.5) + chair(3.0, 2.62), 0.02)
    keep = objects[:, 2] > 1e-6
    keep &= ~((names == "chair") & (objects[:, 2] > 0.72) & (objects[:, 2] < 0.75 + 1e-6))  # under the top
    points, names = in_room((objects[keep], names[keep]))
    seat_and_legs = (names == "chair") & (points[:, 2] < 0.8)
    assert seat_and_legs.sum() >= 0.8 * (names == "chair").sum()  # within the table's box grown by 5 cm
    out = recognized(points, names, [(names == "table", "table"), (names == "chair", "chair")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["chair", "table"]


def test_a_chair_holding_a_desk_top_is_no_chair():
    """A weak "chair" box's mask took a desk's top, its legs unseen (a desk top seen in the air is as
    high as a chair's back): a chair's seat is no 1.0 x 0.8 m level surface (``max_top_area``). The
    chair beside the desk stays a chair."""
    objects, names = solids(table(2.4, 2.5, name="desk", size=(1.0, 0.8)) + chair(3.6, 2.5), 0.02)
    keep = (objects[:, 2] > 1e-6) & ((names != "desk") | (objects[:, 2] > 0.7))
    points, names = in_room((objects[keep], names[keep]))
    out = recognized(points, names, [(names == "desk", "chair"), (names == "chair", "chair")])
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1 and chairs[0].box.center[0] > 3.2


def test_a_chair_whose_mask_took_the_floor_below_it_stays_a_chair():
    """A corner seen in a few frames: 1.2 m^2 of floor and a wall, too little for the layout to call
    it a floor, so the floor is a support surface. The chair's mask took the floor between its legs
    (a cantilever chair's runners frame a metre of it). What its foot stands on is no level surface the
    chair holds: it stays a chair."""
    from tests.plugins.segmenters.test_layout_planes import box_surface

    floor = box_surface((0.0, 0.0, 0.0), (1.2, 1.0, 0.0), 0.02, "z")
    wall = box_surface((0.0, 0.0, 0.0), (0.0, 1.0, 1.3), 0.02, "x")
    objects, names = solids(chair(0.7, 0.5), 0.02)
    objects, names = objects[objects[:, 2] > 1e-6], names[objects[:, 2] > 1e-6]
    points = np.concatenate([floor, wall, objects])
    names = np.concatenate([np.full(len(floor), "floor"), np.full(len(wall), "wall"), names])
    under = (names == "floor") & (np.abs(points[:, 0] - 0.7) < 0.45) & (np.abs(points[:, 1] - 0.5) < 0.45)
    out = recognized(points, names, [((names == "chair") | under, "chair")])
    assert [inst.class_name for inst in out["instances"]] == ["chair"], out["instances"]


def test_a_swivel_chairs_seat_joins_the_back_above_it():
    """A swivel chair whose post went unseen, as its seat and backrest apart: the seat (no class of
    its own) under the backrest (voted "chair", off the floor). A chair stands on no other object, so
    the seat under its back is part of it. One chair, down to the seat."""
    x, y, s = 2.5, 2.0, 0.23
    parts = [
        ("seat", (x - s, y - s, 0.42), (x + s, y + s, 0.48)),
        ("back", (x - s, y + s - 0.05, 0.56), (x + s, y + s, 0.95)),
    ]
    objects, object_names = solids(parts, 0.02)
    keep = objects[:, 2] > 0.42 + 1e-6  # the seat's underside unseen
    points, names = in_room((objects[keep], object_names[keep]))
    out = recognized(points, names, [(names == "back", "chair")])
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1 and chairs[0].points[:, 2].min() < 0.45
    seat = np.flatnonzero(names == "seat")
    assert (out["semantics"].instance_ids[seat] == chairs[0].id).mean() > 0.9


def test_a_piece_that_would_make_a_chair_too_large_does_not_join_it():
    """Floor clutter under a chair whose legs' lower part went unseen (a block under its seat with a 1.1 m strip
    running off it), apart from the chair: most of it lies within the chair's footprint, but joined it
    would make a 1.5 m "chair". It stays apart, and the chair stays a chair."""
    x, y, s = 2.5, 2.0, 0.22
    chair_parts = chair(x, y)
    clutter = [
        ("clutter", (x - s, y - s, 0.0), (x + s, y + s, 0.15)),
        ("clutter", (x + s, y - 0.03, 0.0), (x + 1.3, y + 0.03, 0.1)),
    ]
    objects, names = solids(chair_parts + clutter, 0.02)
    keep = (objects[:, 2] > 1e-6) & ((names != "chair") | (objects[:, 2] > 0.25))  # its legs' lower part unseen
    points, names = in_room((objects[keep], names[keep]))
    inside = (names == "clutter") & (np.abs(points[:, 0] - x) <= s + 0.05) & (np.abs(points[:, 1] - y) <= s + 0.05)
    assert inside.sum() > 0.5 * (names == "clutter").sum()
    out = recognized(points, names, [(names == "chair", "chair")])
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1 and max(chairs[0].box.size[:2]) < 1.0


def pedestal_chair(x: float, y: float) -> list[tuple[str, tuple, tuple]]:
    """A chair on a closed pedestal as a map sees it: the pedestal (0-0.3 m), a seat (0.4-0.5 m) and a
    back rising from the seat's rear edge (to 1.1 m), the post between pedestal and seat lost."""
    return [
        ("base", (x - 0.22, y - 0.22, 0.0), (x + 0.22, y + 0.22, 0.3)),
        ("seat", (x - 0.25, y - 0.25, 0.4), (x + 0.25, y + 0.25, 0.5)),
        ("back", (x - 0.22, y + 0.2, 0.5), (x + 0.22, y + 0.25, 1.1)),
    ]


def test_a_chair_seen_in_stacked_pieces_is_one_chair():
    """The frames' boxes took a chair's seat for a table and its back for a cabinet, and none covered
    its pedestal (a real office walk's swivel chair came out so): three pieces one over another in one
    footprint, together a chair's size with no flat top. One chair, even against a wall; a cabinet
    with a lamp on it stays a cabinet and a lamp."""
    objects, names = solids(pedestal_chair(2.5, 0.3), 0.02)
    lamp = [("cabinet", (4.0, 0.05, 0.0), (4.5, 0.45, 0.7)), ("lamp", (4.2, 0.2, 0.75), (4.3, 0.3, 1.1))]
    more, more_names = solids(lamp, 0.02)
    keep = objects[:, 2] > 1e-6
    keep_more = more[:, 2] > 1e-6
    points, names = in_room((objects[keep], names[keep]), (more[keep_more], more_names[keep_more]))
    masks = [(names == "seat", "table"), (names == "back", "cabinet"), (names == "cabinet", "cabinet")]
    out = recognized(points, names, masks)
    classes = sorted(inst.class_name for inst in out["instances"])
    assert classes.count("chair") == 1 and "cabinet" in classes
    chair = next(inst for inst in out["instances"] if inst.class_name == "chair")
    assert chair.points[:, 2].min() < 0.05 and chair.points[:, 2].max() > 1.0
    assert (out["semantics"].instance_ids[np.isin(names, ["base", "seat", "back"])] == chair.id).mean() > 0.9


def test_a_back_behind_a_seat_that_a_table_box_named_makes_one_chair():
    """A swivel chair seen as two pieces (a tuning office walk's): its seat, 0.5 m high, which a
    "table" box named and which alone fits a coffee table, and its back at the seat's rear, reaching
    15 cm below the seat's top, voted "cabinet". A back may reach below its seat's top, and a whole
    object on the floor takes such a piece when the two are seating seen from above: one chair. A
    coffee table of the same height with an unnamed thing standing on it (a lamp, a plant: it does not
    reach below the top) stays a table with a thing on it."""
    from tests.plugins.segmenters.test_layout_planes import table

    x, y = 2.5, 0.8
    parts = table(x, y, name="seat", size=(0.5, 0.5), height=0.5)
    parts.append(("back", (x - 0.23, y + 0.17, 0.35), (x + 0.23, y + 0.22, 1.1)))
    parts += table(4.3, 0.8, name="coffee_table", size=(0.6, 0.5), height=0.5)
    parts.append(("thing", (4.15, 0.65, 0.5), (4.45, 0.95, 0.85)))
    objects, names = solids(parts, 0.02)
    keep = (objects[:, 2] > 1e-6) & ~((names == "thing") & (objects[:, 2] < 0.5 + 1e-6))
    points, names = in_room((objects[keep], names[keep]))
    masks = [(names == "seat", "table"), (names == "back", "cabinet")]
    masks += [(names == "coffee_table", "table"), (names == "thing", "object")]
    out = recognized(points, names, masks)
    chairs = [inst for inst in out["instances"] if inst.class_name == "chair"]
    assert len(chairs) == 1, sorted(inst.class_name for inst in out["instances"])
    assert chairs[0].points[:, 2].min() < 0.05 and chairs[0].points[:, 2].max() > 1.0
    assert (out["semantics"].instance_ids[np.isin(names, ["seat", "back"])] == chairs[0].id).mean() > 0.9
    ids = out["semantics"].instance_ids
    table_id, thing_id = np.bincount(ids[names == "coffee_table"]).argmax(), np.bincount(ids[names == "thing"]).argmax()
    named = {inst.id: inst.class_name for inst in out["instances"]}
    assert table_id != thing_id and named[table_id] == "table" and named[thing_id] != "chair"


def seating(x0: float, length: float, name: str, far_wall: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Upholstered seating 0.85 m deep with its back on the y = 0 wall (the far wall, y = ROOM[1],
    with ``far_wall``): a seat block 0.42 m high, a 0.72 m back along the wall and 0.62 m arms at both
    ends (an armchair, or a sofa when long)."""
    back, arm = 0.2, 0.15
    parts = [
        (name, (x0 + arm, back, 0.0), (x0 + length - arm, 0.85, 0.42)),
        (name, (x0, 0.02, 0.0), (x0 + length, back, 0.72)),
        (name, (x0, back, 0.0), (x0 + arm, 0.85, 0.62)),
        (name, (x0 + length - arm, back, 0.0), (x0 + length, 0.85, 0.62)),
    ]
    pts, names = solids(parts, 0.02)
    keep = (pts[:, 2] > 1e-6) & (pts[:, 1] > 0.02 + 1e-6)  # its bottom on the floor and its back on the wall unseen
    pts = pts[keep]
    if far_wall:
        pts[:, 1] = ROOM[1] - pts[:, 1]
    return pts, names[keep]


@pytest.fixture(scope="module")
def seating_room() -> tuple[np.ndarray, np.ndarray, list]:
    """One room and one recognition run for the seating tests. On the y = 0 wall, voted "table" by a
    detector without their labels: an armchair, a sofa and a sideboard of the armchair's height. On
    the far wall, voted "chair": a 1.8 m sofa boxed as two chairs (the mapper's size prior cuts an
    over-long chair in two) and two armchairs 10 cm apart."""
    board, board_names = solids([("sideboard", (4.6, 0.02, 0.0), (5.6, 0.47, 0.72))], 0.02)
    keep = (board[:, 2] > 1e-6) & (board[:, 1] > 0.02 + 1e-6)
    points, names = in_room(
        seating(0.6, 0.9, "armchair"),
        seating(2.2, 2.0, "sofa"),
        (board[keep], board_names[keep]),
        seating(0.6, 1.8, "long_sofa", far_wall=True),
        seating(2.8, 0.9, "left", far_wall=True),
        seating(3.8, 0.9, "right", far_wall=True),
    )
    long_sofa = names == "long_sofa"
    masks = [(names == n, "table") for n in ("armchair", "sofa", "sideboard")]
    masks += [(long_sofa & (points[:, 0] < 1.5), "chair"), (long_sofa & (points[:, 0] >= 1.5), "chair")]
    masks += [(names == "left", "chair"), (names == "right", "chair")]
    return points, names, list(recognized(points, names, masks)["instances"])


def test_seating_a_detector_called_a_table_is_a_chair_or_a_sofa(seating_room):
    """An armchair and a sofa against a wall, which a detector without their labels voted "table"
    (closed below, so no table): seen from above, a seat with a back and arms rising over it, no flat
    top. The armchair is a chair, the sofa a sofa; a sideboard of the same height, its top flat, stays
    a cabinet."""
    points, names, instances = seating_room
    shapes = {n: describe_shape(points[names == n], 0.0, []) for n in ("armchair", "sofa", "sideboard")}
    assert shapes["armchair"].seat and shapes["sofa"].seat and not shapes["sideboard"].seat
    near = [i for i in instances if i.box.center[1] < ROOM[1] / 2]
    by_size = sorted((round(float(max(i.box.size[:2])), 1), i.class_name) for i in near)
    assert [name for _, name in by_size] == ["chair", "cabinet", "sofa"], by_size


def test_a_sofa_boxed_as_two_chairs_is_one_sofa_and_two_armchairs_stay_two(seating_room):
    """A detector boxed a 1.8 m sofa as two chairs: the two halves touch and together are seating too
    long for a chair, one sofa. Two armchairs 10 cm apart, each voted chair, stay two chairs."""
    _, _, instances = seating_room
    far = [i for i in instances if i.box.center[1] > ROOM[1] / 2]
    by_x = sorted((round(float(i.box.center[0]), 1), i.class_name) for i in far)
    assert [name for _, name in by_x] == ["sofa", "chair", "chair"], by_x


@pytest.mark.slow  # a whole kitchen through clusters twice: the longest test make test-fast ran (11 s)
def test_every_object_says_how_it_got_its_class():
    """Each instance records how it was named (``attributes['naming']``), as the run report and the
    viewer show it: the previous stage's objects kept as they were say what that stage said; an
    object no mask covered is named by its votes, else by the rule of the priors that named it; a
    renamed one says what it was."""
    from stratamap.core.map.instances import NAMED_BY, instances_from_semantics, naming_text

    points, names = kitchen_room(0.02)
    classes = np.zeros(len(points), np.int32)
    instances = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    masked = ((names == "table") & (points[:, 2] > 0.7)) | (names == "cup")
    classes[masked], instances[masked] = VOCAB.id("table"), 1
    classes[names == "chair"], instances[names == "chair"] = VOCAB.id("chair"), 2

    def masked_map() -> PipelineData:
        data = PipelineData()
        data.map.geometry = Geometry(points=points, voxel_size=0.02)
        data.map.semantics = Semantics(classes, instances, VOCAB)
        data.map.instances = instances_from_semantics(
            points, None, data.map.semantics, 1, naming=("labels", "the test's masks")
        )
        return data

    out = ClustersSegmenter(keep_instances=True, recognize=True).run(masked_map())["instances"]
    by_class = {inst.class_name: inst for inst in out}
    assert sorted(by_class) == ["chair", "counter", "cup", "table"]
    assert all(inst.attributes["naming"]["by"] in NAMED_BY for inst in out)
    assert naming_text(by_class["chair"]) == "labels: the test's masks"
    assert naming_text(by_class["table"]) == "labels: the test's masks"
    # No mask of its own: the priors' rule that named the counter.
    rule = prior_class(describe_shape(by_class["counter"].points, 0.0, []), VOCAB)
    assert rule[0] == "counter" and by_class["counter"].attributes["naming"] == {"by": "shape", "why": rule[1]}
    # The cup came with the table's mask, so its votes said table; recognition renamed it.
    naming = by_class["cup"].attributes["naming"]
    assert naming["by"] == "shape" and naming["why"].endswith("on a support, its size (was table)"), naming

    # Renamed by recognition: a solid unit the frames called a table says what it was.
    points, names = in_room(unit_row(0.02, with_tall_unit=False))
    out = recognized(points, names, [(names == "counter", "table")])["instances"]
    assert [inst.class_name for inst in out] == ["counter"]
    naming = next(iter(out)).attributes["naming"]
    assert naming["by"] == "shape" and naming["why"].endswith("(was table)"), naming

    # clusters alone, with no votes: its own rules.
    points, names = kitchen_room(0.02)
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    out = ClustersSegmenter().run(data)["instances"]
    assert len(out) >= 3 and {inst.attributes["naming"]["by"] for inst in out} <= {"size rules", "unnamed"}
    assert all((inst.attributes["naming"]["by"] == "unnamed") == (inst.class_name == "object") for inst in out)
    table_top = next(inst for inst in out if inst.class_name == "table")
    assert "support surface" in table_top.attributes["naming"]["why"]

    # No mask, no vote and recognition off: nothing named the counter, it stays `object`, and says so.
    out = ClustersSegmenter(keep_instances=True, recognize=False).run(masked_map())["instances"]
    (unnamed,) = [inst for inst in out if inst.class_name == "object"]
    assert unnamed.attributes["naming"] == {"by": "unnamed", "why": "no vote named it, and recognize is off"}


def test_a_mug_against_the_wall_that_frames_voted_wall_is_a_mug():
    """A mug on a worktop, 2 cm off the wall behind it, whose frames took it for the wall (a plane
    fit's band): 10 cm every way, it is no thin piece of the wall but a thing on a support. A framed
    picture on the wall, as thin but half a metre broad, stays wall."""
    layout = room_shell(0.02)
    parts = [
        ("counter", (0.02, 1.0, 0.0), (0.62, 2.6, 0.9)),
        ("mug", (0.04, 1.5, 0.9), (0.14, 1.6, 1.0)),
        ("picture", (5.94, 2.0, 1.2), (6.0, 2.5, 1.6)),
    ]
    objects, names = solids(parts, 0.02)
    keep = (objects[:, 2] > 1e-6) & ~((names == "counter") & (objects[:, 0] < 0.03))
    keep &= ~((names == "mug") & (objects[:, 2] < 0.9 + 1e-6)) & ~((names == "picture") & (objects[:, 0] > 5.99))
    points = np.concatenate([p for _, p in layout] + [objects[keep]])
    names = np.concatenate([np.full(len(p), n) for n, p in layout] + [names[keep]])
    mug, picture = names == "mug", names == "picture"
    names_voted = np.where(mug | picture, "wall", names)
    out = recognized(points, names_voted, [])
    sem = out["semantics"]
    owner = np.bincount(sem.instance_ids[mug][sem.instance_ids[mug] > 0], minlength=1)
    assert owner.sum() > 0.7 * mug.sum(), "the mug went to the wall"
    inst = next(i for i in out["instances"] if i.id == int(np.argmax(owner)))
    assert inst.class_name == "cup", naming_text(inst)
    assert (sem.class_ids[picture] == VOCAB.id("wall")).mean() > 0.9


def storage_unit(y0: float, length: float, height: float, depth: float = 0.62) -> tuple[np.ndarray, np.ndarray]:
    """A closed unit against the x=0 wall from y0, its back and the floor under it unseen."""
    unit, names = solids([("unit", (0.0, y0, 0.0), (depth, y0 + length, height))], 0.02)
    keep = (unit[:, 2] > 1e-6) & (unit[:, 0] > 1e-6)
    return unit[keep], names[keep]


def test_a_counter_sized_unit_where_nothing_says_kitchen_is_a_cabinet():
    """A 1 m closed unit, 0.62 m deep and 0.9 m high, is a short worktop's size and a chest's or a
    storage unit's too. Alone in a room (an office's storage unit scaled to a cabinet's height) it is a
    cabinet, and its naming says why; beside a worktop run longer than one unit (a kitchen) the same
    unit is a counter."""
    points, names = in_room(storage_unit(1.0, 1.0, 0.9))
    out = recognized(points, names, [(names == "unit", "box")])
    assert [inst.class_name for inst in out["instances"]] == ["cabinet"]
    assert next(iter(out["instances"])).attributes["naming"]["by"] == "context"
    run, run_names = storage_unit(2.4, 1.6, 0.9)
    points, names = in_room(storage_unit(0.6, 1.0, 0.9), (run, np.full(len(run), "run")))
    out = recognized(points, names, [(names == "unit", "box"), (names == "run", "box")])
    assert sorted(inst.class_name for inst in out["instances"]) == ["counter", "counter"]


def test_a_worktop_run_has_one_top():
    """A worktop over two units is one slab at one level along its whole length; two units side by
    side at 0.82 m and 0.9 m that came out as one object show two tops: no run, no kitchen."""
    from stratamap.plugins.segmenters.clusters.shapes import counter_run

    one, _ = storage_unit(1.0, 1.6, 0.9)
    assert counter_run(describe_shape(one, 0.0, []))
    low, _ = storage_unit(1.0, 0.9, 0.82)
    high, _ = storage_unit(1.9, 0.7, 0.9)
    two = describe_shape(np.concatenate([low, high]), 0.0, [])
    assert two.length > 1.5 and fits_class("counter", two) and not counter_run(two)


def test_an_unnamed_chair_between_the_arms_of_an_l_of_units_is_no_part_of_them():
    """The frames' masks took an L of base units (a run along each of two walls) as one cabinet, and
    the chair standing on the floor between the L's arms as an unnamed object. The chair lies within
    the L's box, but its centre lies outside the L's outline (top view): it is no piece of the
    units (on a real kitchen, one of the table's chairs was joined to an L of a shelf and a unit so).
    An armchair's arm boxed apart still joins its armchair (the test above)."""
    parts = [
        ("units", (0.02, 0.02, 0.0), (0.62, 1.6, 0.9)),  # along the x = 0 wall
        ("units", (0.62, 0.02, 0.0), (1.6, 0.62, 0.9)),  # along the y = 0 wall
        *chair(1.2, 1.2),
    ]
    objects, names = solids(parts, 0.02)
    keep = (objects[:, 2] > 1e-6) & (objects[:, 0] > 0.03) & (objects[:, 1] > 0.03)  # nothing seen on the walls
    points, names = in_room((objects[keep], names[keep]))
    units, seat = names == "units", names == "chair"
    out = recognized(points, names, [(units, "cabinet"), (seat, "object")])
    sem = out["semantics"]
    on_chair, on_units = sem.instance_ids[seat], sem.instance_ids[units]
    assert (on_chair > 0).mean() > 0.9 and (on_units > 0).mean() > 0.9
    assert not np.isin(on_chair, on_units).any()
    chair_id = np.bincount(on_chair[on_chair > 0]).argmax()
    assert next(i for i in out["instances"] if i.id == chair_id).class_name == "chair"
