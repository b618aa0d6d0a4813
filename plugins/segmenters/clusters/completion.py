"""``keep_instances``, in the ``instances`` pass: the map's instances (a tsdf mapper's, from a
detector's masks) stay, every geometric object they leave uncovered becomes an instance of its own,
and an instance's unmasked parts (a table's legs under its masked top) join it."""

from __future__ import annotations

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.core.map.priors import HAND_HELD, UNNAMED
from stratamap.plugins.segmenters.clusters.instances import ruled_reason, voted_reason
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import LAYOUT_NAMES
from stratamap.plugins.segmenters.clusters.shapes import fits_class, hand_held, on_a_support, thin

#: A small object standing on a support inside a larger object's mask is an object of its own when it
#: holds less than this share of that mask's points (a cup in the table's box).
OWN_SHARE = 0.15
#: A mask instance lying within a geometric object by this share of its points is a piece of it where its
#: class's size rules it out (a detector box that framed one side of a unit).
PIECE_SHARE = 0.8
#: Leftover votes name an added object only where they hold this share of its points.
VOTE_SHARE = 0.5


def complete_instances(
    lab: Labelling,
    point_obj: np.ndarray,
    kept: np.ndarray,
    on_plane: np.ndarray,
    cell_count: np.ndarray,
    top_area: np.ndarray,
    layout_class: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int, dict[int, tuple[str, str]]]:
    """keep_instances: the map's instances stay; each geometric object they leave (mostly)
    uncovered becomes an instance; the unmasked points of a covered one join the nearest
    instance. Stuff is where the fused map's own layout puts it (not each frame's guess).
    Returns point classes, point instances, how many instances were added and how each added
    one got its class (``(by, why)`` by instance id)."""
    from scipy.spatial import cKDTree

    cfg, votes, points, supports = lab.cfg, lab.votes, lab.points, lab.supports
    vocab = votes.vocabulary
    prev_c, prev_i = votes.class_ids.astype(np.int32), votes.instance_ids.astype(np.int32)
    smallest = lab.scrap_size
    out_c, out_i = prev_c.copy(), prev_i.copy()
    free = prev_i == 0
    relabel = free & (layout_class > 0)
    out_c[relabel] = layout_class[relabel]
    stuff_ids = [vocab.id(n) for n in LAYOUT_NAMES[1:] if n in vocab]
    inst_size = np.bincount(prev_i[prev_i > 0], minlength=int(prev_i.max()) + 1)
    tol = lab.standing_tolerance
    # Each mask instance's class (its points' most frequent one).
    n_instances = int(prev_i.max()) + 1
    votes_by_instance = np.bincount(
        np.asarray(prev_i, np.int64) * len(vocab) + prev_c, minlength=n_instances * len(vocab)
    ).reshape(n_instances, len(vocab))
    inst_class = votes_by_instance.argmax(axis=1)
    next_id, added = int(prev_i.max()) + 1, 0
    why: dict[int, tuple[str, str]] = {}
    points_of = members_of(point_obj, int(point_obj.max(initial=-1)) + 1)
    instance_points = members_of(prev_i, int(prev_i.max(initial=0)) + 1)
    for k in kept:
        mask = points_of[k]
        inside = prev_i[mask] > 0
        carried_by = None  # the class of the instance whose mask took this object along, if any
        if inside.mean() >= cfg.covered_share:
            owner = np.bincount(prev_i[mask[inside]]).argmax()
            owner_class = int(inst_class[owner])
            standing = on_a_support(float(points[mask, 2].min()), supports.height, tol) and top_area[k] == 0
            # A small object standing on a support, inside a larger object's mask (a cup in the
            # table's box), or of a hand-held thing's size there inside any other thing's mask (a
            # mug framed with a strip of worktop as a "table"): an object of its own.
            own = standing and (
                len(mask) < OWN_SHARE * inst_size[owner]
                or (vocab.name(owner_class) not in HAND_HELD and hand_held(lab.shape(mask)))
            )
            if not own:
                rest = mask[~inside]
                if len(rest):
                    near = cKDTree(points[mask[inside]]).query(points[rest])[1]
                    out_i[rest] = prev_i[mask[inside][near]]
                    out_c[rest] = prev_c[mask[inside][near]]
                continue
            rest = mask
            owner_shape = lab.shape(instance_points[owner])
            if not fits_class(vocab.name(owner_class), owner_shape):
                carried_by = owner_class
        else:
            rest = mask[~inside]
            label = int(np.argmax(on_plane[k]))
            if top_area[k] == 0 and on_plane[k, label] >= cfg.layout_share * cell_count[k]:
                continue
        if len(rest) < smallest:
            continue
        # Mostly voted floor, wall or ceiling and thin: that stuff where the map's layout missed it (a
        # floor patch, a poster). Thicker, the votes say nothing: a tall unit's front the frames took
        # for a wall.
        if np.isin(prev_c[rest], stuff_ids).mean() > 0.5 and thin(points[rest]):
            continue
        # Instances lying within this object whose own class their shape rules out (a detector box
        # that framed one side of a unit) are pieces of it.
        for piece in np.unique(prev_i[mask[inside]]):
            members = instance_points[piece]
            if (point_obj[members] == k).mean() < PIECE_SHARE:
                continue
            if not fits_class(vocab.name(int(inst_class[piece])), lab.shape(members)):
                rest = np.union1d(rest, members)
        thing = [c for c in np.unique(prev_c[rest]) if c > 0 and vocab.is_thing[c]]
        shape = lab.shape(rest)
        counts = {int(c): int((prev_c[rest] == c).sum()) for c in thing}
        # Leftover votes name it only where they hold most of its points (a vote its size rules
        # out is kept for now: the piece may join an object of that class, else recognition renames it).
        # A vote for the class of the object it stands on, which that object's own size rules out, came
        # with that object's mask (a detector without a 'counter' label framed the counter as a "box"
        # and took the mug along): it names neither.
        if carried_by is not None:
            counts.pop(carried_by, None)
        voted = [vocab.name(c) for c in sorted(counts, key=lambda c: -counts[c]) if counts[c] >= VOTE_SHARE * len(rest)]
        prior, rule = lab.prior(shape) if cfg.recognize else (UNNAMED, "")
        name = voted[0] if voted else prior
        if voted:
            why[next_id] = voted_reason(name, counts[vocab.id(name)] / len(rest))
        elif cfg.recognize:
            why[next_id] = ruled_reason("shape", rule)
        else:
            why[next_id] = ("unnamed", "no vote named it, and recognize is off")
        out_i[rest] = next_id
        out_c[rest] = vocab.id(name) if name in vocab else 0
        next_id += 1
        added += 1
    # Scraps (a few points of a mask that missed its object) are no instances.
    sizes = np.bincount(out_i[out_i > 0], minlength=int(out_i.max()) + 1)
    scrap = (out_i > 0) & (sizes[out_i] < smallest)
    out_c[scrap], out_i[scrap] = 0, 0
    return out_c, out_i, added, why
