"""Pass ``split_oversized``: no instance is larger than any class of the vocabulary allows.

A thing instance larger than any class of the vocabulary has objects (``Labelling.too_large``: it
reaches farther than every class's extent and is deeper or taller than every any-length class
allows, core/map/priors.py) is several objects that a mapper's masks or a join took together: on a
real kitchen, a table, two counter runs and a shelf wall touching through the walls the layout
missed. It is split back, never kept silently: points the fused map's layout calls floor, wall or
ceiling go to that stuff; the rest is cut where its footprint parts into rectangles (an L of two
counter runs at its inner corner), then, where a piece is still too large, into the geometric
objects it holds (the clustering's ``obj``), then into their segments. Each piece is named as the
``instances`` pass names an object (its fused votes where they hold most of it and its size allows
that class, else the priors with ``recognize``, else ``object``); pieces smaller than a scrap join
the nearest piece. Each split, and each oversized instance with nothing to split by, is noted
(``oversized``) with its size and what it became."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from stratamap.plugins.segmenters.clusters.completion import VOTE_SHARE
from stratamap.plugins.segmenters.clusters.instances import ruled_reason, voted_reason
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import NONE
from stratamap.plugins.segmenters.clusters.shapes import fits_class, unnamed


def split_oversized(lab: Labelling) -> None:
    """Sets ``instance_ids``, ``class_ids`` and ``naming`` of the pieces; notes ``oversized``."""
    if lab.obj is None:
        return
    point_layout = lab.layout.labels[lab.cell_of_point]
    point_obj, point_segment = lab.obj[lab.cell_of_point], lab.segment[lab.cell_of_point]
    levels = (
        lambda sel: _footprint_cut(lab, sel),
        lambda sel: _pieces(lab, sel, point_obj),
        lambda sel: _pieces(lab, sel, point_segment),
    )
    next_id = int(lab.instance_ids.max()) + 1
    notes = []
    for iid, (name, shape, sel) in sorted(lab.thing_shapes().items()):
        if not lab.too_large(shape):
            continue
        on_layout = point_layout[sel] != NONE
        stuff, rest = sel[on_layout], sel[~on_layout]
        if len(stuff):
            lab.relabel(stuff, instance=0, cls=lab.stuff_ids[point_layout[stuff]])
        if not len(rest):
            pieces = []
        elif lab.too_large(lab.shape(rest)):
            pieces = _split(lab, rest, levels)
        else:
            pieces = [rest]
        note: dict[str, Any] = {
            "instance": iid,
            "class": name,
            "size": [round(float(v), 2) for v in (shape.length, shape.depth, shape.height)],
            "reach": round(float(shape.reach), 2),
            "why": "no class of the vocabulary has objects this large",
            "to_stuff": int(len(stuff)),
        }
        if len(pieces) < 2 and not len(stuff):
            notes.append({**note, "kept": "nothing parts it: its footprint fills its box, one object, one segment"})
            continue
        into = []
        for k, piece in enumerate(sorted(pieces, key=lambda p: (-len(p), int(p[0])))):
            piece_id = iid if k == 0 else next_id
            next_id += piece_id != iid
            piece_name, why = _name(lab, piece)
            lab.relabel(piece, instance=piece_id, cls=lab.vocab.id(piece_name))
            lab.naming[piece_id] = why
            lab.scores.pop(piece_id, None)
            into.append({"instance": piece_id, "class": piece_name, "points": int(len(piece))})
        notes.append({**note, "into": into})
    lab.note("oversized", notes)


def _split(lab: Labelling, sel: np.ndarray, levels: tuple[Callable[[np.ndarray], list[np.ndarray]], ...]) -> list:
    """The points ``sel`` as the pieces of the first of ``levels`` that parts them; a piece still too
    large is parted again from the first level on (every piece is smaller than what it came from, so
    this ends)."""
    for level in levels:
        pieces = level(sel)
        if len(pieces) > 1:
            return [
                part
                for piece in pieces
                for part in (_split(lab, piece, levels) if lab.too_large(lab.shape(piece)) else [piece])
            ]
    return [sel] if len(sel) else []


def _footprint_cut(lab: Labelling, sel: np.ndarray) -> list[np.ndarray]:
    """``sel`` cut by the vertical plane, along either side of its gravity-aligned box, that leaves
    its two pieces' boxes the least empty floor area (an L of two counter runs parts at its inner
    corner); uncut unless that removes at least half of the empty area of its box (a piece that fills
    its box has no such cut). Stray points (top-view patches of fewer than STRAY_CELLS cells) neither
    set the box nor the empty area: one would stretch a piece's box across the room."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    cell = max(2.0 * lab.voxel, 0.05)
    pts = lab.points[sel]
    kept = _not_stray(pts[:, :2], cell)
    if kept.sum() < 3:
        return [sel]
    box = gravity_aligned_box(pts[kept], area_slack=0.0)
    local = (pts - box.center) @ box.pose[:3, :2]
    grid = np.floor((local - local[kept].min(axis=0)) / cell).astype(np.int64)
    shape = grid[kept].max(axis=0) + 1
    occupied = np.zeros(shape, bool)
    occupied[grid[kept, 0], grid[kept, 1]] = True

    def empty(block: np.ndarray) -> int:
        rows, cols = np.flatnonzero(block.any(axis=1)), np.flatnonzero(block.any(axis=0))
        if not len(rows):
            return 0
        return int((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1) - block.sum())

    whole = empty(occupied)
    best = (whole, None, 0)
    for axis in (0, 1):
        for at in range(1, shape[axis]):
            first, second = np.split(occupied, [at], axis=axis)
            if not first.any() or not second.any():
                continue
            left = empty(first) + empty(second)
            if left < best[0]:
                best = (left, axis, at)
    left, axis, at = best
    if axis is None or whole - left < 0.5 * whole:
        return [sel]
    side = grid[:, axis] < at
    return [sel[side], sel[~side]]


#: A top-view patch of fewer cells than this is a stray (a point or two the mask caught across the room).
STRAY_CELLS = 3


def _not_stray(xy: np.ndarray, cell: float) -> np.ndarray:
    """Per point, whether its top-view cell lies in a patch (8-connected occupied cells) of at least
    STRAY_CELLS cells."""
    from scipy import ndimage

    grid = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    occupied = np.zeros(grid.max(axis=0) + 1, bool)
    occupied[grid[:, 0], grid[:, 1]] = True
    patches, _ = ndimage.label(occupied, structure=np.ones((3, 3), bool))
    size = np.bincount(patches.ravel())
    return size[patches[grid[:, 0], grid[:, 1]]] >= STRAY_CELLS


def _name(lab: Labelling, piece: np.ndarray) -> tuple[str, tuple[str, str]]:
    """A piece's class and naming: its fused thing votes where one class holds VOTE_SHARE of it and
    its size allows that class (the whole's votes came with one mask: a strip of worktop is no table),
    else the priors (``recognize``), else ``object``."""
    vocab = lab.vocab
    if lab.votes is not None:
        voted = lab.votes.class_ids[piece]
        voted = voted[(voted > 0) & (voted < len(vocab))]
        things = voted[np.asarray(vocab.is_thing)[voted]]
        if len(things):
            best = int(np.bincount(things).argmax())
            share = float((things == best).sum()) / len(piece)
            if share >= VOTE_SHARE and fits_class(vocab.name(best), lab.shape(piece)):
                return vocab.name(best), voted_reason(vocab.name(best), share)
    if lab.cfg.recognize:
        name, rule = lab.prior(lab.shape(piece))
        return name, ruled_reason("shape", rule)
    return unnamed(vocab), ("unnamed", "a piece of an oversized instance, and recognize is off")


def _pieces(lab: Labelling, sel: np.ndarray, group: np.ndarray) -> list[np.ndarray]:
    """``sel`` by ``group`` (per point, -1 none); points of no group and groups of fewer cells than a
    scrap go to the nearest larger group."""
    from scipy.spatial import cKDTree

    of = group[sel]
    ids = np.unique(np.stack([of, lab.cell_of_point[sel]]), axis=1)[0]
    groups, cells = np.unique(ids, return_counts=True)
    big = [int(g) for g, n in zip(groups, cells, strict=True) if g >= 0 and n >= lab.scrap_size]
    if len(big) < 2:
        return [sel]
    keep = np.isin(of, big)
    owner = of.copy()
    if (~keep).any():
        near = cKDTree(lab.points[sel[keep]]).query(lab.points[sel[~keep]])[1]
        owner[~keep] = of[keep][near]
    return [sel[owner == g] for g in big]
