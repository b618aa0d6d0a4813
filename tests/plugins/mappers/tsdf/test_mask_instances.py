"""Map instances from voxel class votes and pieces re-joined by masks (core.mask_instances)."""

from __future__ import annotations

import numpy as np
import pytest

from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.mappers.tsdf.mask_instances import (
    MaskInstanceParams,
    MaskObservations,
    agglomerate,
    class_min_points,
    connected_pieces,
    key_voxels,
    mask_instances,
    merge_stacked,
    misfire_instances,
    piece_proximity,
    split_oversized,
    voxel_keys,
)

VOXEL = 0.02
VOCAB = Vocabulary.default()
CHAIR, DESK, FLOOR = VOCAB.id("chair"), VOCAB.id("desk"), VOCAB.id("floor")


def slab(x0: int, y0: int, z0: int, nx: int, ny: int, nz: int) -> np.ndarray:
    """Integer voxel coordinates of a solid block (a stand-in for an object's surface voxels)."""
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1).reshape(-1, 3)
    return g + np.array([x0, y0, z0])


def scene():
    """Two chairs 0.4 m apart that the label fusion fused into one instance; a desk in two pieces
    0.2 m apart (the TSDF lost the thin part between them), some of whose points the fusion called
    chair; a floor."""
    chair_a, chair_b = slab(0, 0, 1, 10, 10, 6), slab(30, 0, 1, 10, 10, 6)
    desk_top, desk_foot = slab(0, 30, 20, 20, 10, 2), slab(0, 30, 1, 20, 10, 4)
    floor = slab(-5, -5, 0, 60, 50, 1)
    voxels = np.concatenate([chair_a, chair_b, desk_top, desk_foot, floor])
    part = np.repeat(np.arange(5), [len(chair_a), len(chair_b), len(desk_top), len(desk_foot), len(floor)])
    fused_class = np.array([CHAIR, CHAIR, DESK, DESK, FLOOR])[part]
    fused_instance = np.array([1, 1, 2, 2, 0])[part]
    fused_class[(part == 2) & (voxels[:, 0] < 5)] = CHAIR  # a border the label fusion got wrong
    return voxels, part, fused_class, fused_instance


def observe(voxels, part, frames_merged: int, frames: int = 10) -> MaskObservations:
    """Frames that see everything; the segmenter splits the chairs except in ``frames_merged`` frames
    and always covers the desk's two pieces with one mask."""
    obs = MaskObservations()
    cls = np.array([CHAIR, CHAIR, DESK, DESK, FLOOR])[part]
    for k in range(frames):
        inst = np.array([1, 1 if k < frames_merged else 2, 3, 3, 0])[part]
        obs.add(voxels, cls, inst)
    return obs


def test_voxel_keys_round_trip():
    v = np.array([[0, 0, 0], [-5, 7, 123456], [-(2**20), 2**20 - 1, -1]])
    assert np.array_equal(key_voxels(voxel_keys(v)), v)
    assert len(np.unique(voxel_keys(slab(-3, -3, -3, 7, 7, 7)))) == 343
    with pytest.raises(ValueError, match="2\\^20"):
        voxel_keys(np.array([[2**21, 0, 0]]))


def test_masks_split_fused_objects_and_join_pieces():
    voxels, part, fused_class, fused_instance = scene()
    points = voxels * VOXEL
    cls, inst = mask_instances(
        points, fused_class, fused_instance, observe(voxels, part, frames_merged=2), VOCAB, VOXEL
    )
    # Class by the frames' votes: the desk's wrongly fused corner is desk again.
    assert np.all(cls[part == 2] == DESK) and np.all(cls[part == 4] == FLOOR)
    assert np.all(inst[part == 4] == 0)
    ids = [set(np.unique(inst[part == k])) for k in range(4)]
    assert all(len(s) == 1 and 0 not in s for s in ids), ids
    chair_a, chair_b, desk_top, desk_foot = (s.pop() for s in ids)
    assert chair_a != chair_b  # most frames split the chairs: the fused instance is cut
    assert desk_top == desk_foot  # every frame's mask covers both pieces: re-joined
    assert len({chair_a, chair_b, desk_top}) == 3


def test_masks_that_never_split_two_pieces_join_them():
    voxels, part, fused_class, fused_instance = scene()
    cls, inst = mask_instances(
        voxels * VOXEL, fused_class, fused_instance, observe(voxels, part, frames_merged=10), VOCAB, VOXEL
    )
    assert len(np.unique(inst[(part == 0) | (part == 1)])) == 1


def test_small_pieces_join_the_piece_they_touch():
    voxels = np.concatenate([slab(0, 0, 0, 10, 10, 3), slab(10, 0, 0, 2, 2, 2)])  # 300 + 8 points
    cls = np.array([CHAIR] * 300 + [DESK] * 8)
    piece = connected_pieces(voxels * VOXEL, cls, np.zeros(len(voxels), int), 1.5 * VOXEL, min_points=20)
    assert len(np.unique(piece)) == 1 and np.all(cls == CHAIR)
    cls = np.array([CHAIR] * 300 + [DESK] * 8)
    piece = connected_pieces(voxels * VOXEL, cls, np.zeros(len(voxels), int), 1.5 * VOXEL, min_points=5)
    assert len(np.unique(piece)) == 2


def test_agglomeration_is_greedy_by_ratio_and_respects_classes():
    together = np.array([[0, 8, 3, 9], [8, 0, 1, 0], [3, 1, 0, 0], [9, 0, 0, 0]], float)
    apart = np.array([[0, 2, 5, 0], [2, 0, 9, 0], [5, 9, 0, 0], [0, 0, 0, 0]], float)
    group = agglomerate(together, apart, np.array([CHAIR, CHAIR, CHAIR, DESK]), MaskInstanceParams())
    assert group[0] == group[1] != group[2]  # 8 vs 2 merges; 3+1 vs 5+9 does not
    assert group[3] != group[0]  # another class never merges without proximity and sizes, however often together


def plant_with_leaf(leaf_z: int):
    """A plant fused as one instance: a 1,000-point body (voxels z 0-9) and an 18-point leaf at
    voxel height ``leaf_z`` that touches nothing; one frame's mask covers both."""
    body, leaf = slab(0, 0, 0, 10, 10, 10), slab(0, 0, leaf_z, 3, 3, 2)
    voxels = np.concatenate([body, leaf])
    cls, inst = np.full(len(voxels), VOCAB.id("plant")), np.full(len(voxels), 4)
    obs = MaskObservations()
    obs.add(voxels, cls, np.ones(len(voxels), int))
    return voxels, len(body), cls, inst, obs


def test_isolated_small_piece_stays_with_its_fused_instance():
    """A plant's leaf the TSDF kept apart from the rest (too small to stand alone, touching nothing)
    keeps the instance its label had, not a class of nothing."""
    voxels, body, cls, inst, obs = plant_with_leaf(15)  # 12 cm above the body
    plant = VOCAB.id("plant")
    out_cls, out_inst = mask_instances(voxels * VOXEL, cls, inst, obs, VOCAB, VOXEL)
    assert np.all(out_cls == plant) and len(np.unique(out_inst)) == 1 and out_inst[0] > 0
    other = inst.copy()
    other[body:] = 5  # a leaf of another (fused) instance has no host here: dropped
    out_cls, out_inst = mask_instances(voxels * VOXEL, cls, other, obs, VOCAB, VOXEL)
    assert np.all(out_inst[body:] == 0) and np.all(out_cls[body:] == 0)


def test_a_map_of_small_pieces_only_is_no_error():
    """Nothing but pieces too small to stand alone (a tiny clip's map: two plant leaves that touch
    nothing, and no body): they have no host to join and are dropped, without an error."""
    leaves = np.concatenate([slab(0, 0, 0, 3, 3, 2), slab(10, 0, 0, 3, 3, 2)])
    cls, inst = np.full(len(leaves), VOCAB.id("plant")), np.full(len(leaves), 4)
    obs = MaskObservations()
    obs.add(leaves, cls, np.ones(len(leaves), int))
    out_cls, out_inst = mask_instances(leaves * VOXEL, cls, inst, obs, VOCAB, VOXEL)
    assert out_cls.shape == out_inst.shape == (len(leaves),) and not out_inst.any()


def two_chairs(gap_voxels: int, frames_together: int, frames: int = 10):
    """Two chair pieces ``gap_voxels`` apart, fused as one instance, that ``frames_together`` of the
    frames' masks cover as one (the others split them)."""
    a, b = slab(0, 0, 0, 10, 10, 5), slab(10 + gap_voxels, 0, 0, 10, 10, 5)
    voxels = np.concatenate([a, b])
    in_b = np.arange(len(voxels)) >= len(a)
    obs = MaskObservations()
    for k in range(frames):
        obs.add(voxels, np.full(len(voxels), CHAIR), np.where(in_b & (k >= frames_together), 2, 1))
    return voxels, obs


def chair_instances(voxels: np.ndarray, obs: MaskObservations, params: MaskInstanceParams) -> np.ndarray:
    """The instance per voxel of ``voxels`` fused as one "chair" instance, after ``mask_instances``."""
    return mask_instances(
        voxels * VOXEL, np.full(len(voxels), CHAIR), np.ones(len(voxels), int), obs, VOCAB, VOXEL, params
    )[1]


@pytest.mark.parametrize(("gap_voxels", "near_gap", "joined"), [(5, 0.2, True), (50, 0.2, False), (50, 0.0, True)])
def test_far_pieces_need_near_unanimous_masks(gap_voxels, near_gap, joined):
    """Seven frames in ten covering both: enough 10 cm apart, not 1 m apart (a segmenter's masks
    that often run over two books or two chairs), unless the distance limit is off. The size prior is
    off here (it would cut a 1.4 m "chair" again, below)."""
    voxels, obs = two_chairs(gap_voxels, frames_together=7)
    inst = chair_instances(voxels, obs, MaskInstanceParams(near_gap=near_gap, max_length={}))
    assert np.all(inst > 0)
    assert (len(np.unique(inst)) == 1) == joined


def test_a_chair_longer_than_any_chair_is_cut_in_two():
    """Two chairs 1 m apart that the distance limit let join (it is off) are 1.4 m long: no chair is,
    and the size prior cuts them where they part."""
    voxels, obs = two_chairs(50, frames_together=7)
    inst = chair_instances(voxels, obs, MaskInstanceParams(near_gap=0.0))
    assert len(np.unique(inst[: len(voxels) // 2])) == 1 and len(np.unique(inst)) == 2


def test_far_pieces_join_when_every_mask_covers_both():
    """A plant's pot and leaves 1 m apart (the stem lost) that every frame's mask covers as one. (The
    pieces are voted "chair"; the size prior, off here, would cut a 1.4 m chair in two.)"""
    voxels, obs = two_chairs(50, frames_together=10)
    inst = chair_instances(voxels, obs, MaskInstanceParams(max_length={}))
    assert len(np.unique(inst)) == 1 and inst[0] > 0


def test_piece_proximity():
    """Near means within about the gap (one point per piece and quarter-gap cell stands in for it)."""
    points = (
        np.concatenate(
            [
                slab(0, 0, 0, 10, 10, 10),
                slab(10, 0, 0, 10, 10, 10),
                slab(25, 0, 0, 10, 10, 10),
                slab(100, 0, 0, 10, 10, 10),
            ]
        )
        * VOXEL
    )
    piece = np.repeat([0, 1, 2, 3], 1000)
    piece[:3] = -1  # points that take no part
    near = piece_proximity(points, piece, 4, 0.3)
    assert near[0, 1] and near[1, 0] and near[1, 2]  # touching; 10 cm apart
    assert not near[:3, 3].any() and not near[3, :3].any()  # 1.3 m and more apart
    assert not near[0, 0]


def test_fragments_of_a_class_are_dropped():
    """A 'chair' of 64 points beside chairs of 1,000 is a misfire; a lone small cup is not."""
    voxels = np.concatenate(
        [slab(0, 0, 0, 10, 10, 10), slab(30, 0, 0, 10, 10, 10), slab(60, 0, 0, 4, 4, 4), slab(0, 40, 0, 4, 4, 4)]
    )
    part = np.repeat([0, 1, 2, 3], [1000, 1000, 64, 64])
    cup = VOCAB.id("cup")
    cls = np.array([CHAIR, CHAIR, CHAIR, cup])[part]
    obs = MaskObservations()
    obs.add(voxels, cls, part + 1)
    out_cls, out_inst = mask_instances(voxels * VOXEL, cls, part + 1, obs, VOCAB, VOXEL)
    assert np.all(out_inst[part == 2] == 0) and np.all(out_cls[part == 2] == 0)
    assert all(len(np.unique(out_inst[part == k])) == 1 and out_inst[part == k][0] > 0 for k in (0, 1, 3))
    _, kept = mask_instances(voxels * VOXEL, cls, part + 1, obs, VOCAB, VOXEL, MaskInstanceParams(min_class_share=0.0))
    assert np.all(kept[part == 2] > 0)
    assert misfire_instances(np.array([0, 1, 1, 1, 2, 3, 3, 3]), np.array([0, 4, 4, 4, 4, 4, 4, 4]), 0.5).tolist() == [
        2
    ]


def test_isolated_small_piece_far_from_its_host_is_dropped():
    voxels, body, cls, inst, obs = plant_with_leaf(40)  # 0.62 m above the body
    _, out_inst = mask_instances(voxels * VOXEL, cls, inst, obs, VOCAB, VOXEL)
    assert np.all(out_inst[body:] == 0) and np.all(out_inst[:body] > 0)
    _, out_inst = mask_instances(voxels * VOXEL, cls, inst, obs, VOCAB, VOXEL, MaskInstanceParams(near_gap=0.0))
    assert len(np.unique(out_inst)) == 1


def seen_whole_and_alone(voxels: np.ndarray, part_b: np.ndarray, whole: tuple[int, int], alone: tuple[int, int]):
    """Two touching pieces A and B (B where ``part_b``): ten frames cover both with one mask, half
    of them calling it ``whole[0]``, half ``whole[1]``; twelve frames see only A, as ``alone[0]``,
    and twelve only B, as ``alone[1]`` (so each piece's voxels are voted its ``alone`` class)."""
    obs = MaskObservations()
    for k in range(10):
        obs.add(voxels, np.full(len(voxels), whole[k % 2]), np.ones(len(voxels), int))
    for _ in range(12):
        for sel, cls in ((~part_b, alone[0]), (part_b, alone[1])):
            obs.add(voxels[sel], np.full(int(sel.sum()), cls), np.ones(int(sel.sum()), int))
    return obs, np.where(part_b, alone[1], alone[0]), np.where(part_b, 2, 1)


@pytest.mark.parametrize("cross_ratio", [0.8, 0.0])
def test_an_object_called_by_two_names_is_one_instance(cross_ratio):
    """Half a chair the segmenter calls 'sofa', which masks keep covering whole: one instance of the
    class most of its points have, unless cross-class merging is off."""
    voxels = np.concatenate([slab(0, 0, 0, 10, 10, 6), slab(10, 0, 0, 8, 10, 6)])  # 600 + 480 points, touching
    part_b = np.arange(len(voxels)) >= 600
    sofa = VOCAB.id("sofa")
    obs, cls, inst = seen_whole_and_alone(voxels, part_b, (CHAIR, sofa), (CHAIR, sofa))
    out_cls, out_inst = mask_instances(
        voxels * VOXEL, cls, inst, obs, VOCAB, VOXEL, MaskInstanceParams(cross_ratio=cross_ratio)
    )
    assert np.all(out_inst > 0)
    if cross_ratio:
        assert len(np.unique(out_inst)) == 1 and np.all(out_cls == CHAIR)
    else:
        assert len(np.unique(out_inst)) == 2 and np.all(out_cls[part_b] == sofa) and np.all(out_cls[~part_b] == CHAIR)


@pytest.mark.parametrize(("share", "kept_apart"), [(0.1, True), (0.0, False)])
def test_a_small_thing_on_furniture_keeps_its_class(share, kept_apart):
    """A book (80 points) on a shelf (1,000) that every view of the whole covers with the shelf's
    mask, while close views call it a book: far smaller than the shelf, so it stays a book."""
    voxels = np.concatenate([slab(0, 0, 0, 10, 10, 10), slab(2, 2, 10, 4, 4, 5)])
    part_b = np.arange(len(voxels)) >= 1000
    shelf, book = VOCAB.id("shelf"), VOCAB.id("book")
    obs, cls, inst = seen_whole_and_alone(voxels, part_b, (shelf, shelf), (shelf, book))
    out_cls, out_inst = mask_instances(
        voxels * VOXEL, cls, inst, obs, VOCAB, VOXEL, MaskInstanceParams(cross_share=share)
    )
    assert np.all(out_inst > 0) and np.all(out_cls[~part_b] == shelf)
    assert (out_inst[part_b][0] != out_inst[0]) == kept_apart
    assert np.all(out_cls[part_b] == (book if kept_apart else shelf))


def test_point_median_fragments_are_not_dragged_down_by_many_fragments():
    """Four misfire 'chairs' beside two real ones pull the plain median down to a misfire's size;
    the size-weighted median (the instance a median point is in) stays a real chair's."""
    sizes = [95, 216, 228, 341, 8023, 10432]
    instance = np.repeat(np.arange(1, 7), sizes)
    point_class = np.full(len(instance), CHAIR)
    assert misfire_instances(instance, point_class, 0.1).tolist() == []
    assert misfire_instances(instance, point_class, 0.1, "point_median").tolist() == [1, 2, 3, 4]


def cup(cx: float, cy: float, rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Surface points of a cup (radius 4 cm, 9 cm tall) standing at (cx, cy)."""
    angle, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 0.09, n)
    return np.c_[cx + 0.04 * np.cos(angle), cy + 0.04 * np.sin(angle), z]


def test_size_prior_cuts_two_touching_cups_and_leaves_one_alone():
    rng = np.random.default_rng(0)
    pair = np.concatenate([cup(0.0, 0.0, rng), cup(0.085, 0.03, rng)])  # 5 mm apart: one segment
    truth = np.repeat([0, 1], 400)
    cls = np.full(len(pair), VOCAB.id("cup"))
    out = split_oversized(pair, cls, np.ones(len(pair), int), VOCAB, {"cup": 0.15})
    assert len(np.unique(out)) == 2
    for part in np.unique(out):  # each part is one cup
        assert np.bincount(truth[out == part]).max() >= 0.95 * (out == part).sum()
    single = cup(0.0, 0.0, rng)
    assert np.all(split_oversized(single, cls[:400], np.full(400, 7), VOCAB, {"cup": 0.15}) == 7)
    # no limit for the class, or none at all: nothing is cut
    assert np.all(split_oversized(pair, cls, np.ones(len(pair), int), VOCAB, {"book": 0.45}) == 1)
    assert np.all(split_oversized(pair, cls, np.ones(len(pair), int), VOCAB, {}) == 1)


def test_size_prior_keeps_an_object_with_a_scrap_whole():
    """A 0.6 m monitor whose instance took a scrap of something 0.7 m beyond it is over the limit,
    but the parts k-means finds are the monitor and the scrap, not two monitors."""
    rng = np.random.default_rng(1)
    screen = np.c_[rng.uniform(0, 0.6, 2000), rng.uniform(0, 0.03, 2000), rng.uniform(0.1, 0.45, 2000)]
    scrap = np.c_[rng.uniform(1.3, 1.45, 150), rng.uniform(0, 0.1, 150), rng.uniform(0.0, 0.1, 150)]
    points = np.concatenate([screen, scrap])
    cls = np.full(len(points), VOCAB.id("monitor"))
    assert np.all(split_oversized(points, cls, np.ones(len(points), int), VOCAB, {"monitor": 0.8}) == 1)
    assert (
        len(np.unique(split_oversized(points, cls, np.ones(len(points), int), VOCAB, {"monitor": 0.8}, balance=0.0)))
        == 2
    )


def test_size_prior_rejects_unknown_classes_and_bad_lengths():
    points, cls, inst = np.zeros((3, 3)), np.full(3, CHAIR), np.ones(3, int)
    with pytest.raises(ValueError, match="'cupp'"):
        split_oversized(points, cls, inst, VOCAB, {"cupp": 0.15})
    with pytest.raises(ValueError, match="positive length"):
        split_oversized(points, cls, inst, VOCAB, {"cup": 0.0})


def test_mask_instances_cuts_touching_objects_the_masks_never_part():
    """Two cups that every frame's mask covers together: the masks keep them one instance, the size
    prior (on by default) makes them two; with it off they stay one."""
    rng = np.random.default_rng(2)
    points = np.concatenate([cup(0.0, 0.0, rng), cup(0.085, 0.0, rng)])
    cls = np.full(len(points), VOCAB.id("cup"))
    voxels = np.unique(np.round(points / VOXEL).astype(np.int64), axis=0)
    obs = MaskObservations()
    for _ in range(5):
        obs.add(voxels, np.full(len(voxels), VOCAB.id("cup")), np.ones(len(voxels), np.int32))
    params = MaskInstanceParams(min_points=20)
    _, together = mask_instances(points, cls, np.ones(len(points), np.int32), obs, VOCAB, VOXEL, params)
    assert len(np.unique(together[together > 0])) == 2
    params.max_length = {}
    _, off = mask_instances(points, cls, np.ones(len(points), np.int32), obs, VOCAB, VOXEL, params)
    assert len(np.unique(off[off > 0])) == 1


def test_stacked_pieces_of_furniture_join_and_side_by_side_ones_do_not():
    """A swivel chair's base under its seat is one chair; a chair beside it is another; two books
    in a pile stay two books (books stack, so the class is not listed)."""
    rng = np.random.default_rng(3)
    seat = np.c_[rng.uniform(0, 0.5, 1500), rng.uniform(0, 0.5, 1500), rng.uniform(0.42, 1.0, 1500)]
    base = np.c_[rng.uniform(0.0, 0.5, 300), rng.uniform(0.0, 0.5, 300), rng.uniform(0.0, 0.12, 300)]
    beside = seat + [0.55, 0, 0]
    book_a = np.c_[rng.uniform(2, 2.25, 200), rng.uniform(0, 0.3, 200), rng.uniform(0.75, 0.78, 200)]
    book_b = book_a + [0.01, 0.01, 0.04]
    points = np.concatenate([seat, base, beside, book_a, book_b])
    instance = np.repeat([1, 2, 3, 4, 5], [1500, 300, 1500, 200, 200])
    cls = np.repeat([CHAIR, CHAIR, CHAIR, VOCAB.id("book"), VOCAB.id("book")], [1500, 300, 1500, 200, 200])
    out = merge_stacked(points, cls, instance, VOCAB, ("chair", "table"))
    assert np.all(out[instance == 2] == 1) and np.all(out[instance == 1] == 1)
    assert np.all(out[instance == 3] == 3) and np.all(out[instance == 4] == 4) and np.all(out[instance == 5] == 5)
    assert np.array_equal(merge_stacked(points, cls, instance, VOCAB, ()), instance)
    with pytest.raises(ValueError, match="'chiar'"):
        merge_stacked(points, cls, instance, VOCAB, ("chiar",))


def test_small_things_stand_alone_from_fewer_points():
    """A cup whose 'cup' part is 45 points, standing on a table: at the general bar of 60 points it
    joins the table and takes its class; with cups' own bar (30) it stays a cup."""
    cup_id, table_id = VOCAB.id("cup"), VOCAB.id("table")
    table = slab(0, 0, 0, 25, 20, 1) * VOXEL
    cup_pts = (slab(10, 10, 1, 3, 3, 5) * VOXEL)[:45]
    points = np.concatenate([table, cup_pts])
    cls = np.r_[np.full(len(table), table_id), np.full(len(cup_pts), cup_id)]
    group = np.zeros(len(points), int)
    general = cls.copy()
    connected_pieces(points, general, group, 1.5 * VOXEL, 60)
    assert np.all(general == table_id)
    per_class = cls.copy()
    bar = class_min_points(VOCAB, 60, {"cup": 30})
    pieces = connected_pieces(points, per_class, group, 1.5 * VOXEL, bar)
    assert np.all(per_class[len(table) :] == cup_id) and len(np.unique(pieces)) == 2
    with pytest.raises(ValueError, match="'cupp'"):
        class_min_points(VOCAB, 60, {"cupp": 30})
