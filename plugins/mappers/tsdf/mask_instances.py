"""Map instances from per-voxel class votes and 3D pieces re-joined by the frames' masks.

The Voxblox++ fusion of :mod:`stratamap.plugins.mappers.tsdf.panoptic_fusion` trusts each frame's segments: a mask that
spans two chairs relabels both chairs' voxels, and over a walk the labels of neighbouring objects
fuse for good. With a learned segmenter that happens often, so the map's instances can be built
the other way round, from evidence that averages out over frames:

1. **Class per voxel**: every frame's class at a voxel is a vote; a map point takes the class most
   frames gave its voxel (SemanticFusion-style voting, McCormac et al. 2017), not its label's.
2. **Pieces**: the points of one class and one fused instance, cut into connected pieces (points
   within ``1.5`` voxels link). Two objects of a class that a merged label covered fall apart
   where they do not touch; pieces under ``min_points`` join the piece they touch most. Small
   things have a lower bar (``min_points_by_class``): a whole cup is about a hundred map points at
   2 cm, and the part of it most frames call "cup" is often under sixty, which then joined the table.
3. **Agglomeration by masks** (as superpoint merging with 2D masks in open-vocabulary 3D instance
   segmentation, e.g. Open3DIS, Nguyen et al. 2024): in each frame, a piece is *in* a 2D thing
   segment when most of its visible voxels fall in it; two pieces in one segment count a *together*,
   in two segments an *apart*. Same-class groups merge greedily, best ratio first, while
   together / (together + apart) exceeds ``merge_ratio`` (and together >= ``min_together``).
   An object cut by a thin part the TSDF does not keep (a chair's post) is re-joined, because
   masks cover it whole; two chairs a few frames merged stay apart, because most frames split them.
   Objects are compact: groups with no points within ``near_gap`` of each other merge only when
   the masks are near unanimous (``far_ratio``; a plant's pot and leaves, with the stem lost),
   so books a segmenter often covers together, or chairs seen one behind the other, stay apart.
   An object the segmenter calls by two names (half a chair "sofa") is two groups of two classes
   that masks keep covering together: near groups of different classes merge above
   ``cross_ratio`` when the smaller holds at least ``cross_share`` of the larger's
   points, and the merged group takes the class most of its points have. A book on a shelf that
   masks often miss is far smaller than the shelf and stays a book.
4. **Misfires**: an instance under ``min_class_share`` of the typical size of its class's
   instances in the map (a chair of 90 points beside chairs of 5,000) is a misfire and is dropped;
   typical is the size of the instance the class's median point lies in, which a crowd of
   misfires does not pull down as it does the median instance (``fragment_reference``).
5. **Stacked pieces**: furniture does not stand on furniture of its own class, so two instances
   of such a class (``stacked_classes``: chairs, tables, ...) one above the other, the smaller's
   footprint at least ``stack_overlap`` inside the larger's (5 cm cells), are one object whose
   thin joining parts the TSDF lost and the segmenter's boundaries cut: a swivel chair's base and
   seat, a table's legs and top. Books, boxes and cups do stack and are left out.
6. **Size prior** (the shape filter of instance clustering, used to cut instead of reject): an
   instance longer than any single object of its class (``max_length``: two cups side by side
   are 0.2 m, no cup is) is as many objects as the prior says fit, found by k-means along its
   longest horizontal axis; it is cut only if the parts come out of comparable size
   (``split_balance``), so a monitor whose instance took a scrap of something far beyond it is
   not cut into two monitors.
   Touching objects of one class are one 2D segment in every frame of a segmenter that works
   at a coarse resolution, so the masks of step 3 hold no evidence against them; the size does.

With ground-truth masks this reproduces the objects (the oracle's map PQ does not drop);
with a segmenter's masks it stops one bad frame from fusing two objects.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from stratamap.core.geometry.points import VOXEL_NEIGHBOURS, cell_keys
from stratamap.core.lazy import lazy_module
from stratamap.core.map.priors import NOT_STACKED, class_max_lengths
from stratamap.core.map.vocabulary import Vocabulary

vq = lazy_module("scipy.cluster.vq")
sparse = lazy_module("scipy.sparse")
csgraph = lazy_module("scipy.sparse.csgraph")
spatial = lazy_module("scipy.spatial")

_OFFSET = np.int64(1) << 20  # voxel coordinates within +-2^20 voxels (20 km at 2 cm) pack into one int64
_BITS = 21

#: Pieces of these classes stand alone from this many points (``min_points`` for the others):
#: a whole cup, bottle or book is 100-300 map points at 2 cm voxels.
DEFAULT_MIN_POINTS_BY_CLASS: dict[str, int] = {"cup": 30, "bottle": 30, "book": 30}

#: Classes whose objects do not stand on one another (step 5): same-class pieces one above the other are one object.
DEFAULT_STACKED_CLASSES: tuple[str, ...] = NOT_STACKED
FOOTPRINT_CELL = 0.05  # m; coarse enough that a chair base's legs fall in the cells of the seat above them

#: Longest horizontal side (m) one object of a class has (step 6): a longer instance is several objects.
DEFAULT_MAX_LENGTH: dict[str, float] = class_max_lengths()


def voxel_keys(voxels: np.ndarray) -> np.ndarray:
    """One int64 per integer voxel coordinate (x, y, z)."""
    v = np.asarray(voxels, np.int64) + _OFFSET
    if v.size and (v.min() < 0 or v.max() >= (1 << _BITS)):
        raise ValueError("voxel coordinates beyond +-2^20 voxels cannot be packed")
    return (v[:, 0] << (2 * _BITS)) | (v[:, 1] << _BITS) | v[:, 2]


def key_voxels(keys: np.ndarray) -> np.ndarray:
    mask = (np.int64(1) << _BITS) - 1
    return np.stack([keys >> (2 * _BITS), (keys >> _BITS) & mask, keys & mask], 1) - _OFFSET


@dataclass
class MaskObservations:
    """What every frame's segmenter said about the voxels it saw: (voxel, class, 2D instance)."""

    keys: list[np.ndarray] = field(default_factory=list)
    classes: list[np.ndarray] = field(default_factory=list)
    instances: list[np.ndarray] = field(default_factory=list)

    def add(self, voxels: np.ndarray, classes: np.ndarray, instances: np.ndarray) -> None:
        """One frame: integer voxel coordinates of its sampled pixels (one per voxel) and their labels."""
        self.keys.append(voxel_keys(voxels))
        self.classes.append(np.asarray(classes, np.int16))
        self.instances.append(np.asarray(instances, np.int32))

    def __len__(self) -> int:
        return len(self.keys)

    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """The distinct voxel keys observed, and for every observation (frames in order) its index among them."""
        uniq, inverse = np.unique(np.concatenate(self.keys), return_inverse=True)
        return uniq, inverse.reshape(-1)


@dataclass
class MaskInstanceParams:
    min_points: int = 60
    min_points_by_class: dict[str, int] = field(
        default_factory=lambda: dict(DEFAULT_MIN_POINTS_BY_CLASS)
    )  # class -> points instead of min_points
    merge_ratio: float = 0.5
    min_together: int = 2
    in_share: float = 0.5  # a piece is in a frame's segment when this share of its voxels seen in that frame fall in it
    min_hits: int = 3
    near_gap: float = 0.2  # m; 0: no limit on how far apart merged groups may be
    far_ratio: float = 0.9  # the together share groups farther apart than near_gap need
    min_class_share: float = 0.1  # 0: keep every instance of min_points or more
    fragment_reference: str = (
        "point_median"  # "median": the class's median instance; "point_median": the instance its median point is in
    )
    cross_ratio: float = 0.8  # near groups of two classes merge above this together share; 0: never
    cross_share: float = 0.1  # ... if the smaller has at least this share of the larger's points
    stacked_classes: tuple[str, ...] = DEFAULT_STACKED_CLASSES  # (): no stacked-piece merging
    stack_overlap: float = 0.5  # share of the smaller piece's footprint cells inside the larger's
    max_length: dict[str, float] = field(
        default_factory=lambda: dict(DEFAULT_MAX_LENGTH)
    )  # class -> m; {}: no size prior
    split_balance: float = 0.35  # parts of an over-long instance must each hold this share of the largest part's points

    def __post_init__(self) -> None:
        self.stacked_classes = tuple(self.stacked_classes)


def point_class_votes(
    points: np.ndarray, voxel_size: float, obs: MaskObservations, voxels: tuple[np.ndarray, np.ndarray], classes: int
) -> np.ndarray:
    """Per map point, how many frames gave each class to its voxel (or, if it has none, to the
    nearest observed voxel of its 26 neighbours). ``voxels`` is ``obs.voxels()``."""
    uniq, inv = voxels
    flat = np.asarray(inv, np.int64).reshape(-1) * classes + np.concatenate(obs.classes).astype(np.int64)
    votes = np.zeros(len(uniq) * classes, np.int32)
    # One flat index and values of the table's dtype: ufunc.at's fast path (20 times the speed of a
    # two-index add), without bincount's int64 copy of a table of voxels x classes.
    np.add.at(votes, flat, np.ones(len(flat), np.int32))
    votes = votes.reshape(len(uniq), classes)
    base = np.round(points / voxel_size).astype(np.int64)
    out = np.zeros((len(points), classes), np.int32)
    if len(uniq) == 0:  # no frame labelled anything: no votes
        return out
    todo = np.ones(len(points), bool)
    for off in VOXEL_NEIGHBOURS:
        idx = np.flatnonzero(todo)
        if len(idx) == 0:
            break
        k = voxel_keys(base[idx] + off)
        pos = np.minimum(np.searchsorted(uniq, k), len(uniq) - 1)
        hit = uniq[pos] == k
        out[idx[hit]] = votes[pos[hit]]
        todo[idx[hit]] = False
    return out


def connected_pieces(
    points: np.ndarray, point_class: np.ndarray, group: np.ndarray, link: float, min_points: int | np.ndarray
) -> np.ndarray:
    """Connected pieces of same-class, same-``group`` points (ids from 0); pieces under
    ``min_points`` (one number, or one per class id) join (with their class) the neighbouring
    piece they share most links with."""
    n = len(points)
    pairs = spatial.cKDTree(points).query_pairs(link, output_type="ndarray")
    a, b = pairs[:, 0], pairs[:, 1]
    same = (point_class[a] == point_class[b]) & (group[a] == group[b])
    graph = sparse.coo_matrix((np.ones(int(same.sum())), (a[same], b[same])), shape=(n, n))
    count, piece = csgraph.connected_components(graph, directed=False)
    piece_class = np.zeros(count, np.int64)
    piece_class[piece] = point_class  # a piece keeps its id, and so its class, when others join it
    per_class = np.asarray(min_points)
    bar = np.full(count, int(per_class)) if per_class.ndim == 0 else per_class[piece_class]
    for _ in range(3):  # a small piece may touch only other small pieces: a few rounds settle chains
        sizes = np.bincount(piece, minlength=count)
        cross = piece[a] != piece[b]
        src = np.r_[piece[a[cross]], piece[b[cross]]]
        dst = np.r_[piece[b[cross]], piece[a[cross]]]
        small = sizes[src] < bar[src]
        if not small.any():
            break
        src, dst = src[small], dst[small]
        pair_keys, links = np.unique(src.astype(np.int64) * count + dst, return_counts=True)
        s, d = pair_keys // count, pair_keys % count
        weight = links * (1 + (sizes[d] >= bar[d]))  # prefer joining a real piece
        order = np.lexsort((-weight, s))
        first = np.r_[True, s[order][1:] != s[order][:-1]]
        target = np.arange(count)
        target[s[order][first]] = d[order][first]
        for _ in range(8):
            target = target[target]
        piece = target[piece]
    piece = np.unique(piece, return_inverse=True)[1]
    point_class[:] = piece_majority(piece, point_class)[piece]  # absorbed pieces take their host's class
    return piece


def piece_majority(piece: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The most frequent value of each piece (pieces numbered from 0; ties to the smaller value)."""
    if not len(piece):
        return np.zeros(0, values.dtype)
    span = np.int64(values.max()) + 1
    code, n = np.unique(piece.astype(np.int64) * span + values, return_counts=True)
    p, v = code // span, code % span
    order = np.lexsort((v, -n, p))
    first = np.r_[True, p[order][1:] != p[order][:-1]]
    out = np.zeros(int(piece.max()) + 1 if len(piece) else 0, values.dtype)
    out[p[order][first]] = v[order][first]
    return out


def mask_cooccurrence(
    points: np.ndarray,
    piece: np.ndarray,
    voxel_size: float,
    obs: MaskObservations,
    voxels: tuple[np.ndarray, np.ndarray],
    is_thing: np.ndarray,
    params: MaskInstanceParams,
) -> tuple[np.ndarray, np.ndarray]:
    """(together, apart) counts between pieces (ids from 0; -1: a point that takes no part) over
    all frames' thing segments. ``voxels`` is ``obs.voxels()``."""
    count = int(piece.max()) + 1 if len(piece) else 0
    together = np.zeros((count, count))
    apart = np.zeros((count, count))
    if count == 0 or len(obs) == 0:
        return together, apart
    uniq, inv = voxels
    dist, nearest = spatial.cKDTree(points).query(key_voxels(uniq) * voxel_size, distance_upper_bound=1.5 * voxel_size)
    piece_of_key = np.where(np.isfinite(dist), piece[np.minimum(nearest, len(piece) - 1)], -1)
    start = 0
    for keys, cls, inst in zip(obs.keys, obs.classes, obs.instances, strict=True):
        pk = piece_of_key[inv[start : start + len(keys)]]
        start += len(keys)
        seen = pk >= 0
        if not seen.any():
            continue
        visible = np.bincount(pk[seen], minlength=count)
        use = seen & (inst > 0) & is_thing[cls]
        if not use.any():
            continue
        segment = cls[use].astype(np.int64) << 32 | inst[use].astype(np.int64)
        # (piece, segment) pairs as one integer each: the frame's segments numbered in their order,
        # so the pairs sort as (piece, segment) would, at the cost of a 1-D unique.
        segments, seg_index = np.unique(segment, return_inverse=True)
        code, hits = np.unique(pk[use].astype(np.int64) * len(segments) + seg_index, return_counts=True)
        pair_piece, pair_segment = code // len(segments), segments[code % len(segments)]
        inside = (hits >= params.min_hits) & (hits >= params.in_share * visible[pair_piece])
        members, segs = pair_piece[inside], pair_segment[inside]
        if len(members) < 2:
            continue
        same = segs[:, None] == segs[None, :]
        ix = np.ix_(members, members)
        together[ix] += same
        apart[ix] += ~same
    np.fill_diagonal(together, 0)
    np.fill_diagonal(apart, 0)
    return together, apart


def piece_proximity(points: np.ndarray, piece: np.ndarray, count: int, gap: float) -> np.ndarray:
    """(count, count) bool: which pieces (ids from 0; -1: none) come within ``gap`` of each other,
    measured between one point of each piece per ``gap / 4`` cell (cheap on maps of 10^5 thing
    points). Pieces more than ``gap`` apart are never near; pieces within ``gap / 8`` (touching)
    always are; in between, near when their sampled points are."""
    near = np.zeros((count, count), bool)
    use = piece >= 0
    if count == 0 or not use.any():
        return near
    _, first = np.unique(cell_keys(points[use], gap / 4) * count + piece[use], return_index=True)
    owner = piece[use][first]
    pairs = spatial.cKDTree(points[use][first]).query_pairs(gap, output_type="ndarray")
    a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
    near[a[a != b], b[a != b]] = True
    return near | near.T


def agglomerate(
    together: np.ndarray,
    apart: np.ndarray,
    piece_class: np.ndarray,
    params: MaskInstanceParams,
    near: np.ndarray | None = None,
    sizes: np.ndarray | None = None,
) -> np.ndarray:
    """Greedy agglomeration: merge the same-class pair of groups with the highest
    together / (together + apart) while it exceeds ``merge_ratio`` (``far_ratio`` for groups that
    ``near`` does not mark as neighbours, when given). With ``near`` and ``sizes`` (points per
    piece), near groups of two classes merge above ``cross_ratio`` if the smaller has
    ``cross_share`` of the larger's points; a merged group goes on with the larger one's
    class. Returns a group per piece."""
    together, apart = together.copy(), apart.copy()
    near = None if near is None else near.copy()
    count = len(piece_class)
    group = np.arange(count)
    alive = np.ones(count, bool)
    group_class = np.asarray(piece_class).copy()
    size = None if sizes is None else np.asarray(sizes, np.float64).copy()
    cross_class = near is not None and size is not None and params.cross_ratio > 0
    while True:
        total = together + apart
        score = np.where(total > 0, together / np.maximum(total, 1), 0.0)
        pair_ok = alive[:, None] & alive[None, :] & (together >= params.min_together)
        same_class = group_class[:, None] == group_class[None, :]
        ok = same_class & pair_ok & (score > params.merge_ratio)
        if near is not None:
            ok &= near | (score > params.far_ratio)
        if cross_class:
            small, large = np.minimum(size[:, None], size[None, :]), np.maximum(size[:, None], size[None, :])
            ok |= ~same_class & pair_ok & near & (score > params.cross_ratio) & (small >= params.cross_share * large)
        np.fill_diagonal(ok, False)
        if not ok.any():
            break
        flat = np.flatnonzero(ok)
        best = flat[np.argmax(score.ravel()[flat])]  # first of the best: deterministic
        g, h = divmod(int(best), count)
        g, h = min(g, h), max(g, h)
        for m in (together, apart):
            m[g, :] += m[h, :]
            m[:, g] += m[:, h]
            m[h, :] = 0
            m[:, h] = 0
            m[g, g] = 0
        if near is not None:
            near[g, :] |= near[h, :]
            near[:, g] |= near[:, h]
        if size is not None:
            if size[h] > size[g]:
                group_class[g] = group_class[h]
            size[g] += size[h]
            size[h] = 0
        alive[h] = False
        group[group == h] = g
    return group


def mask_instances(
    points: np.ndarray,
    fused_class: np.ndarray,
    fused_instance: np.ndarray,
    obs: MaskObservations,
    vocabulary: Vocabulary,
    voxel_size: float,
    params: MaskInstanceParams | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(class, instance) per map point: voxel class votes, pieces, agglomeration by masks."""
    params = params or MaskInstanceParams()
    is_thing = np.asarray(vocabulary.is_thing)
    if len(points) == 0 or len(obs) == 0:
        return fused_class.copy(), fused_instance.copy()
    voxels = obs.voxels()
    votes = point_class_votes(points, voxel_size, obs, voxels, len(vocabulary.names))
    point_class = np.where(votes.sum(1) > 0, votes.argmax(1), fused_class).astype(np.int64)
    group = np.where(point_class == fused_class, fused_instance, -1)
    bar = class_min_points(vocabulary, params.min_points, params.min_points_by_class)
    piece = connected_pieces(points, point_class, group, 1.5 * voxel_size, bar)
    count = int(piece.max()) + 1
    piece_class = piece_majority(piece, point_class)
    piece_thing = is_thing[piece_class]
    # Only thing pieces take part: stuff never merges, and a big map has many stuff pieces.
    things = np.flatnonzero(piece_thing)
    thing_index = np.full(count, -1)
    thing_index[things] = np.arange(len(things))
    together, apart = mask_cooccurrence(points, thing_index[piece], voxel_size, obs, voxels, is_thing, params)
    merged = np.arange(count)
    near = piece_proximity(points, thing_index[piece], len(things), params.near_gap) if params.near_gap > 0 else None
    thing_sizes = np.bincount(piece, minlength=count)[things]
    merged[things] = things[agglomerate(together, apart, piece_class[things], params, near, thing_sizes)]
    owner = merged[piece]
    thing_point = piece_thing[piece]
    if params.cross_ratio > 0 and thing_point.any():  # a group merged across classes takes its points' majority class
        point_class[thing_point] = piece_majority(owner[thing_point], point_class[thing_point])[owner[thing_point]]
        piece_class = piece_majority(piece, point_class)
    sizes = np.bincount(owner, minlength=count)
    # A piece too small to stand alone that touches nothing (a plant's leaf) goes to the big
    # group holding most points of its fused instance, if that group is of its class (and,
    # with near_gap, has a point within near_gap of it).
    small = thing_point & (sizes[owner] < bar[point_class]) & (group > 0)
    if small.any():
        big = thing_point & (sizes[owner] >= bar[point_class]) & (group > 0)
        hosted, which = np.unique(group[big], return_inverse=True)
        host = piece_majority(which.reshape(-1), owner[big])
        idx = np.flatnonzero(small)
        pos = np.minimum(np.searchsorted(hosted, group[idx]), max(len(hosted) - 1, 0))
        ok = (hosted[pos] == group[idx]) if len(hosted) else np.zeros(len(idx), bool)
        ok[ok] = piece_class[host[pos[ok]]] == point_class[idx[ok]]
        if params.near_gap > 0 and ok.any():
            cand, target = idx[ok], host[pos[ok]]
            close = np.zeros(len(cand), bool)
            for h in np.unique(target):
                mine = target == h
                dist, _ = spatial.cKDTree(points[owner == h]).query(
                    points[cand[mine]], distance_upper_bound=params.near_gap
                )
                close[mine] = np.isfinite(dist)
            ok[np.flatnonzero(ok)[~close]] = False
        owner[idx[ok]] = host[pos[ok]]
        sizes = np.bincount(owner, minlength=count)
    instance = np.where(thing_point & (sizes[owner] >= bar[point_class]), owner + 1, 0)
    if params.min_class_share > 0:
        instance[
            np.isin(
                instance, misfire_instances(instance, point_class, params.min_class_share, params.fragment_reference)
            )
        ] = 0
    if params.stacked_classes:
        instance = merge_stacked(
            points, point_class, instance, vocabulary, params.stacked_classes, params.stack_overlap
        )
    if params.max_length:
        instance = split_oversized(points, point_class, instance, vocabulary, params.max_length, params.split_balance)
    # Thing points left without an instance (a piece too small to stand alone) carry no class.
    point_class = np.where(is_thing[point_class] & (instance == 0), 0, point_class)
    return point_class.astype(fused_class.dtype), instance.astype(fused_instance.dtype)


def misfire_instances(
    instance: np.ndarray, point_class: np.ndarray, share: float, reference: str = "median"
) -> np.ndarray:
    """Instance ids (> 0) with fewer points than ``share`` of the reference size of their class:
    its median instance (``"median"``), or the instance its median point is in (``"point_median"``,
    the size-weighted median: many misfires beside a few real objects do not drag it down)."""
    if reference not in ("median", "point_median"):
        raise ValueError(f"reference must be 'median' or 'point_median', not {reference!r}")
    ids, first, sizes = np.unique(instance, return_index=True, return_counts=True)
    keep = ids > 0
    ids, cls, sizes = ids[keep], point_class[first[keep]], sizes[keep]

    def typical(of_class: np.ndarray) -> float:
        if reference == "median":
            return float(np.median(of_class))
        ordered = np.sort(of_class)
        return float(ordered[np.searchsorted(np.cumsum(ordered), 0.5 * ordered.sum())])

    out = [ids[(cls == c) & (sizes < share * typical(sizes[cls == c]))] for c in np.unique(cls)]
    return np.concatenate(out) if out else np.zeros(0, ids.dtype)


def require_classes(names: Iterable[str], vocabulary: Vocabulary, setting: str) -> None:
    """Raise ValueError naming ``setting`` and every name in ``names`` that is not a class of ``vocabulary``."""
    unknown = sorted(set(names) - set(vocabulary.names))
    if unknown:
        raise ValueError(
            f"{setting} names classes not in the vocabulary: {unknown} (vocabulary: {list(vocabulary.names)})"
        )


def class_min_points(vocabulary: Vocabulary, min_points: int, by_class: dict[str, int]) -> np.ndarray:
    """Per class id, the points a piece needs to stand alone: ``by_class`` where given, else ``min_points``."""
    require_classes(by_class, vocabulary, "min_points_by_class")
    bar = np.full(len(vocabulary.names), int(min_points), np.int64)
    for name, points in by_class.items():
        bar[vocabulary.id(name)] = int(points)
    return bar


def members_by_instance(instance: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The distinct instance ids (sorted, 0 included if present) and the point indices of each."""
    ids, inverse, counts = np.unique(instance, return_inverse=True, return_counts=True)
    return ids, np.split(np.argsort(inverse.reshape(-1), kind="stable"), np.cumsum(counts)[:-1])


def merge_stacked(
    points: np.ndarray,
    point_class: np.ndarray,
    instance: np.ndarray,
    vocabulary: Vocabulary,
    classes: tuple[str, ...] | list[str],
    overlap: float = 0.5,
    cell: float = FOOTPRINT_CELL,
) -> np.ndarray:
    """Instance ids with same-class instances of ``classes`` one above the other merged: smallest
    first, an instance joins the larger one of its class holding the biggest share (at least
    ``overlap``) of its footprint, counted in horizontal cells of side ``cell`` (z is up)."""
    require_classes(classes, vocabulary, "stacked_classes")
    out = np.asarray(instance).copy()
    if len(points) == 0:
        return out
    wanted = {vocabulary.id(name) for name in classes}
    ids, by_instance = members_by_instance(out)
    majority = piece_majority(out, point_class)
    keys = cell_keys(np.c_[points[:, :2], np.zeros(len(points))], cell)
    pieces: dict[int, tuple[int, int, np.ndarray]] = {}  # id -> (class, points, footprint cells)
    for k in np.flatnonzero(ids > 0):
        members = by_instance[k]
        cls = int(majority[ids[k]])
        if cls in wanted:
            pieces[int(ids[k])] = (cls, len(members), np.unique(keys[members]))
    for small in sorted(pieces, key=lambda i: (pieces[i][1], i)):
        cls, size, cells = pieces[small]
        best, best_share = None, overlap
        for other, (other_cls, other_size, other_cells) in pieces.items():
            if other == small or other_cls != cls or other_size < size:
                continue
            share = np.intersect1d(cells, other_cells, assume_unique=True).size / cells.size
            if share >= best_share:
                best, best_share = other, share
        if best is not None:
            out[out == small] = best
            _, best_size, best_cells = pieces.pop(best)
            pieces[best] = (cls, best_size + size, np.union1d(best_cells, cells))
            del pieces[small]
    return out


def horizontal_length(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Positions along the longest horizontal (x, y) axis of ``points``, and their 2nd-98th percentile span (m)."""
    xy = points[:, :2] - points[:, :2].mean(0)
    if len(xy) < 3:
        return np.zeros(len(xy)), 0.0
    _, axes = np.linalg.eigh(np.cov(xy.T))
    along = xy @ axes[:, -1]
    low, high = np.percentile(along, [2, 98])
    return along, float(high - low)


def split_oversized(
    points: np.ndarray,
    point_class: np.ndarray,
    instance: np.ndarray,
    vocabulary: Vocabulary,
    max_length: dict[str, float],
    balance: float = 0.35,
) -> np.ndarray:
    """Instance ids with every instance longer than its class's ``max_length`` (longest horizontal
    span, m; z is up) cut into ``ceil(length / max_length)`` parts by k-means along that span,
    when the smallest part holds at least ``balance`` of the largest part's points. New parts
    take new ids above the largest; instances of classes without a limit are left alone."""
    require_classes(max_length, vocabulary, "max_length")
    limit = np.full(len(vocabulary.names), np.inf)
    for name, length in max_length.items():
        if not length > 0:
            raise ValueError(f"max_length[{name!r}] must be a positive length in metres, not {length!r}")
        limit[vocabulary.id(name)] = length
    out = np.asarray(instance).copy()
    next_id = int(out.max(initial=0)) + 1
    ids, by_instance = members_by_instance(out)
    majority = piece_majority(out, point_class)
    for k in np.flatnonzero(ids > 0):
        members = by_instance[k]
        cls = int(majority[ids[k]])
        if not np.isfinite(limit[cls]):
            continue
        along, length = horizontal_length(points[members])
        parts = int(np.ceil(length / limit[cls]))
        if parts < 2 or len(members) < 2 * parts:
            continue
        # seeded at the span's quantiles, k-means is deterministic and keeps parts in order along it
        seeds = np.percentile(along, 100 * (np.arange(parts) + 0.5) / parts)[:, None]
        with warnings.catch_warnings():  # an empty part is a failed split, caught by the balance test below
            warnings.simplefilter("ignore", UserWarning)
            _, part = vq.kmeans2(along[:, None], seeds, minit="matrix")
        sizes = np.bincount(part, minlength=parts)
        if sizes.min() < balance * sizes.max():
            continue
        for k in range(1, parts):
            out[members[part == k]] = next_id
            next_id += 1
    return out
