"""What the naming model of ``clusters`` (``naming: model``) reads of each instance: measured features
of its points, its support, the sensor's rays through it, the detector's votes on it and its
neighbours' votes. The same function gives the training script (scripts/train_naming.py) its rows
and the pass ``name_by_model`` its input, so the two cannot drift apart. Deterministic: no sampling,
instances in id order."""

from __future__ import annotations

import numpy as np

from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP, Shape, on_a_support

#: Other instances whose box centres lie this close (m, horizontally) are an instance's neighbours.
NEIGHBOUR_RADIUS = 1.5
#: A foot this close (m) to another instance's top stands on it; a top this close under a foot holds it.
STACK_GAP = 0.05
#: Fewer rays than this through an object's middle heights say nothing of whether it is open.
MIN_RAYS = 20
#: Distances to walls are capped here (m): farther is "in the room", whatever the room's size.
WALL_CAP = 2.0

#: The features that do not depend on the model's classes, in column order.
GEOMETRY = (
    "length",
    "depth",
    "height",
    "bottom",
    "top",
    "reach",
    "depth_to_length",
    "height_to_length",
    "footprint",
    "against_wall",
    "wall_distance",
    "flat_top",
    "solid",
    "seat",
    "knee_space",
    "top_span",
    "seen_through",
    "rays",
    "on_floor",
    "on_support",
    "on_object",
    "holds_top",
    "supports",
    "voted_share",
    "vote_top_share",
)


def feature_names(classes: list[str]) -> list[str]:
    """The columns of ``instance_features`` for a model of ``classes``: GEOMETRY, then each class's
    share of the instance's votes, then how many of its neighbours were voted each class."""
    return [*GEOMETRY, *(f"votes_{c}" for c in classes), *(f"neighbours_{c}" for c in classes)]


def instance_features(lab: Labelling, classes: list[str]) -> tuple[list[int], np.ndarray]:
    """The thing instances of the labelling (ids ascending) and their features (``feature_names``),
    float32. ``classes`` name the vote columns; a class the map's vocabulary lacks has no votes."""
    info = lab.thing_shapes()
    ids = sorted(info)
    if not ids:
        return [], np.zeros((0, len(feature_names(classes))), np.float32)
    points = lab.points
    boxes = [_box(points[info[i][2]]) for i in ids]
    shares = np.array([_vote_shares(lab, info[i][2]) for i in ids])  # per instance, per vocabulary class
    columns = [lab.vocab.id(c) if c in lab.vocab else -1 for c in classes]
    votes = np.stack([shares[:, c] if c >= 0 else np.zeros(len(ids)) for c in columns], axis=1)
    voted = np.where(shares.sum(1) > 0, shares.argmax(1), -1)  # each instance's most voted class
    centres = np.array([b.center for b in boxes])  # for the neighbours
    held = lab.supports.area[lab.support_of_point] if len(lab.supports.area) else np.zeros(len(points))
    rows = []
    for k, iid in enumerate(ids):
        _, shape, sel = info[iid]
        foot = lab.base_z + shape.bottom
        others = [j for j in range(len(ids)) if j != k]
        on_object = any(_stands_on(boxes[k], boxes[j], foot) for j in others)
        carried = sum(_stands_on(boxes[j], boxes[k], boxes[j].center[2] - boxes[j].size[2] / 2) for j in others)
        near = [j for j in others if np.linalg.norm(centres[j, :2] - centres[k, :2]) <= NEIGHBOUR_RADIUS]
        neighbours = [sum(voted[j] == c for j in near) if c >= 0 else 0 for c in columns]
        through, stopped = _rays(lab, sel, boxes[k])
        rows.append(
            [
                *_geometry(shape, lab, sel),
                float(through / (through + stopped)) if through + stopped >= MIN_RAYS else -1.0,
                float(np.log1p(through + stopped)),
                float(shape.bottom <= FLOOR_GAP),
                float(on_a_support(foot, lab.supports.height, lab.standing_tolerance)),
                float(on_object),
                float(held[sel].max()) if len(sel) else 0.0,
                float(carried),
                float(shares[k].sum()),
                float(shares[k].max()),
                *votes[k].tolist(),
                *neighbours,
            ]
        )
    return ids, np.asarray(rows, np.float32)


def _geometry(shape: Shape, lab: Labelling, sel: np.ndarray) -> list[float]:
    pts = lab.points[sel]
    wall = min((float(w.distance(pts).min()) for w in lab.walls), default=WALL_CAP)
    longest = max(shape.length, 1e-3)
    return [
        shape.length,
        shape.depth,
        shape.height,
        shape.bottom,
        shape.bottom + shape.height,
        shape.reach,
        shape.depth / longest,
        shape.height / longest,
        shape.length * shape.depth,
        float(shape.against_wall),
        min(wall, WALL_CAP),
        float(shape.flat_top),
        float(shape.solid),
        float(shape.seat),
        float(shape.knee_space),
        shape.top_span,
    ]


def _vote_shares(lab: Labelling, sel: np.ndarray) -> np.ndarray:
    """Per vocabulary class, the share of the instance's points the map's fused votes gave it (none: zeros)."""
    n = len(lab.vocab)
    if lab.votes is None:
        return np.zeros(n)
    ids = np.asarray(lab.votes.class_ids)[sel]
    ids = ids[(ids > 0) & (ids < n)]
    return np.bincount(ids, minlength=n)[:n] / max(1, len(sel))


def _rays(lab: Labelling, sel: np.ndarray, box: object) -> tuple[int, int]:
    if lab.sight is None:
        return 0, 0
    seen = lab.sight.seen_through(lab.points[sel], box)
    return seen.through, seen.stopped


def _box(pts: np.ndarray) -> object:
    from stratamap.core.geometry.boxes import gravity_aligned_box

    return gravity_aligned_box(pts)


def _stands_on(upper: object, lower: object, foot: float) -> bool:
    """Whether the box ``upper``, its foot at ``foot``, stands on ``lower``'s top: the foot within
    STACK_GAP of that top, its centre over that footprint."""
    return abs(lower.center[2] + lower.size[2] / 2 - foot) <= STACK_GAP and _inside(upper.center, lower)


def _inside(point: np.ndarray, box: object) -> bool:
    """Whether ``point`` lies over ``box``'s footprint."""
    local = (np.asarray(point[:2]) - box.center[:2]) @ box.pose[:2, :2]
    return bool(np.all(np.abs(local) <= box.size[:2] / 2))
