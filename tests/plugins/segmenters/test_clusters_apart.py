"""clusters' pass ``split_seen_apart``: one instance holding two parts the frames saw empty space
between (a counter and the wall shelf above it, which one detector mask covered) is two objects;
where that space was never seen, nothing says so and it stays one. Depth frames ray-cast from
hand-made scenes (tests/plugins/mappers/test_refined_boxes.py)."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.layers import Geometry, Semantics
from stratamap.core.map.sensors import RGBDFrame, SensorStream
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter
from stratamap.plugins.segmenters.clusters.apart import gap_seen_empty
from tests.plugins.mappers.test_refined_boxes import INTRINSICS, depth_of, free_space, look_at, slab
from tests.plugins.segmenters.test_clusters_recognition import in_room, unit_row
from tests.plugins.segmenters.test_layout_planes import ROOM, solids

VOCAB = Vocabulary.default()
#: The counter of ``unit_row`` (against the x=0 wall, 1.0-2.5 m along it, 0.9 m high) and a shelf
#: on the wall 0.45 m above its worktop.
COUNTER = ((0.0, 1.0, 0.0), (0.6, 2.5, 0.9))
SHELF = ((0.0, 1.2, 1.35), (0.25, 2.3, 1.39))
#: Cameras across the room, eye high, looking at the wall between worktop and shelf.
POSES = [look_at((3.0, y, 1.5), (0.0, 1.75, 1.1)) for y in (1.0, 1.75, 2.5)]


def room_meshes(*boxes) -> list:
    lx, ly, lz = ROOM
    shell = [
        slab((0, 0, -0.02), (lx, ly, 0)),
        slab((0, 0, lz), (lx, ly, lz + 0.02)),
        slab((-0.02, 0, 0), (0, ly, lz)),
        slab((lx, 0, 0), (lx + 0.02, ly, lz)),
        slab((0, -0.02, 0), (lx, 0, lz)),
        slab((0, ly, 0), (lx, ly + 0.02, lz)),
    ]
    return shell + [slab(lo, hi) for lo, hi in boxes]


def counter_and_shelf(frames: bool) -> tuple[PipelineData, np.ndarray]:
    """The room with the counter and the shelf, both in one mask instance voted counter; with or
    without the frames that saw them."""
    shelf, shelf_names = solids([("shelf", *SHELF)], 0.02)
    shelf_part = (shelf[:, 0] > 1e-6, shelf_names)
    keep = shelf_part[0]
    # The whole ROOM: the frames are ray-cast in it.
    points, names = in_room(unit_row(0.02, with_tall_unit=False), (shelf[keep], shelf_names[keep]), whole_room=True)
    classes = np.zeros(len(points), np.int32)
    instances = np.zeros(len(points), np.int32)
    for name in ("floor", "wall", "ceiling"):
        classes[names == name] = VOCAB.id(name)
    masked = np.isin(names, ["counter", "shelf"])
    classes[masked], instances[masked] = VOCAB.id("counter"), 1
    data = PipelineData()
    if frames:
        meshes = room_meshes(COUNTER, SHELF)
        data.stream = SensorStream(
            "kitchen",
            INTRINSICS,
            [
                RGBDFrame(k, float(k), np.zeros((120, 160, 3), np.uint8), depth_of(meshes, pose), pose)
                for k, pose in enumerate(POSES)
            ],
        )
    data.map.geometry = Geometry(points=points, voxel_size=0.02)
    data.map.semantics = Semantics(classes, instances, VOCAB)
    return data, names


def test_a_gap_is_seen_empty_only_where_the_frames_saw_through_it():
    free = free_space(room_meshes(COUNTER, SHELF), POSES)
    worktop = np.array([[x, y, 0.9] for x in (0.3, 0.5) for y in np.arange(1.3, 2.2, 0.1)])
    shelf = worktop + [0.0, 0.0, 0.45]
    assert gap_seen_empty(shelf, worktop, free, 0.02)
    # A board in front hides the space between them: nothing says they are apart.
    board = slab((0.65, 0.9, 0.0), (0.67, 2.6, 1.5))
    assert not gap_seen_empty(shelf, worktop, free_space(room_meshes(COUNTER, SHELF) + [board], POSES), 0.02)
    # Nearer than MIN_GAP, a gap is not judged.
    assert not gap_seen_empty(worktop + [0.0, 0.0, 0.1], worktop, free, 0.02)


def test_a_shelf_one_mask_took_with_the_counter_below_is_an_object_of_its_own():
    data, names = counter_and_shelf(frames=True)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    ids = out["semantics"].instance_ids
    counter_id = np.bincount(ids[names == "counter"]).argmax()
    shelf_id = np.bincount(ids[names == "shelf"]).argmax()
    assert counter_id > 0 and shelf_id > 0 and shelf_id != counter_id
    assert (ids[names == "shelf"] == shelf_id).mean() > 0.9
    counter = next(inst for inst in out["instances"] if inst.id == counter_id)
    assert counter.box.size[2] < 1.0, counter.box.size  # the counter alone: 0.9 m high
    assert any(split["part"] == shelf_id for split in data.notes["clusters"]["split_seen_apart"])


def test_without_frames_nothing_says_the_shelf_is_apart():
    data, names = counter_and_shelf(frames=False)
    ids = ClustersSegmenter(keep_instances=True, recognize=True).run(data)["semantics"].instance_ids
    assert np.bincount(ids[names == "shelf"]).argmax() == np.bincount(ids[names == "counter"]).argmax()


def test_a_strip_of_wall_a_mask_took_apart_from_its_object_is_wall():
    """The counter's mask also took a patch of the y=0 wall beside it: apart from the counter across
    space the frames saw empty, and on the wall the layout found, it is wall, no object."""
    data, names = counter_and_shelf(frames=True)
    points = data.map.geometry.points
    patch = (names == "wall") & (np.abs(points[:, 1]) < 1e-6) & (points[:, 0] > 0.8) & (points[:, 0] < 1.1)
    patch &= (points[:, 2] > 1.0) & (points[:, 2] < 1.3)
    sem = data.map.semantics
    classes, instances = sem.class_ids.copy(), sem.instance_ids.copy()
    classes[patch], instances[patch] = VOCAB.id("counter"), 1
    data.map.semantics = Semantics(classes, instances, VOCAB)
    out = ClustersSegmenter(keep_instances=True, recognize=True).run(data)
    assert (out["semantics"].instance_ids[patch] == 0).mean() > 0.9
    assert (out["semantics"].class_ids[patch] == VOCAB.id("wall")).mean() > 0.9
    assert any(split["part"] == 0 for split in data.notes["clusters"]["split_seen_apart"])
