"""Pass ``instances``: large enough objects become instances, numbered by size (deterministic), and
take their class from the map's fused votes (the majority class of their points; a majority of a
stuff class makes a thin one stuff), else from the class size priors (``recognize``), else from
clusters' own size rules (``table_min_area``, ``class_rules``). An object lying mostly near one
floor, wall or ceiling plane (``layout_share``) is that stuff. With ``keep_instances`` the map's
instances stay instead, and only what they leave uncovered is added (``completion``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.map.instances import members_of
from stratamap.core.map.layers import Semantics
from stratamap.core.map.priors import HOLDS_A_TOP
from stratamap.core.map.vocabulary import Vocabulary
from stratamap.plugins.segmenters.clusters.config import ClustersConfig
from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.layout import LAYOUT_NAMES, WALL
from stratamap.plugins.segmenters.clusters.shapes import NO_RULE_FITS, thin, unnamed
from stratamap.plugins.segmenters.clusters.sightlines import Sightlines


def make_instances(lab: Labelling) -> None:
    """Sets ``class_ids``, ``instance_ids`` and ``naming``, and what shapes are measured against."""
    from stratamap.plugins.segmenters.clusters.completion import complete_instances

    cfg, vocab, points, votes = lab.cfg, lab.vocab, lab.points, lab.votes
    obj, layout, supports = lab.obj, lab.layout, lab.supports
    point_obj = obj[lab.cell_of_point]
    n_obj = int(obj.max()) + 1 if (obj >= 0).any() else 0
    cell_count = np.bincount(obj[obj >= 0], minlength=n_obj)
    kept = np.flatnonzero(cell_count >= lab.min_cells)
    kept = kept[np.lexsort((kept, -cell_count[kept]))]
    stuff_ids = lab.stuff_ids
    class_ids = stuff_ids[layout.labels[lab.cell_of_point]]
    instance_ids = np.zeros(len(points), np.int32)
    votes_of = vote_table(point_obj, votes, n_obj, len(vocab)) if votes is not None else None
    top_area = np.zeros(n_obj)
    if len(supports.area):
        has = (supports.of_cell >= 0) & (obj >= 0)
        np.maximum.at(top_area, obj[has], supports.area[supports.of_cell[has]])
    base_z = (
        layout.floor_height
        if layout.floor_height is not None
        else float(supports.height.min())
        if len(supports.height)
        else float(points[:, 2].min())
    )
    on_plane = on_layout_planes(lab.cells, obj, layout, n_obj, cfg.layout_voxels * lab.voxel)
    next_id, things, turned_stuff, on_layout = 1, 0, 0, 0
    walls = [plane for plane in layout.planes if plane.label == WALL]
    sight = Sightlines.from_stream(lab.stream) if (cfg.recognize or cfg.naming != "rules") and cfg.sightlines else None
    lab.set_context(base_z, walls, sight)
    why: dict[int, tuple[str, str]] = {}  # how each instance got its class (NAMED_BY), where this stage named it
    if cfg.keep_instances and votes is not None and (votes.instance_ids > 0).any():
        class_ids, instance_ids, added, why = complete_instances(
            lab, point_obj, kept, on_plane, cell_count, top_area, class_ids
        )
        kept = kept[:0]  # the loop below is the clusters-only naming
        things = added
    points_of = members_of(point_obj, n_obj) if len(kept) else []
    for k in kept:
        mask = points_of[k]
        name = None
        label = int(np.argmax(on_plane[k]))
        if top_area[k] == 0 and on_plane[k, label] >= cfg.layout_share * cell_count[k]:
            class_ids[mask] = stuff_ids[label]
            on_layout += 1
            continue
        if votes_of is not None:
            name = voted_name(votes_of[k], points[mask], stuff_ids, vocab)
            if name is not None:
                reason = voted_reason(name, votes_of[k, vocab.id(name)] / len(mask))
        if name is None and cfg.recognize:
            name, rule = lab.prior(lab.shape(mask))
            reason = ruled_reason("shape", rule)
        if name is None:
            name, rule = class_of(points[mask], top_area[k], base_z, vocab, cfg)
            reason = ruled_reason("size rules", rule)
        class_ids[mask] = vocab.id(name)
        if vocab.is_thing[vocab.id(name)]:
            why[next_id] = reason
            instance_ids[mask] = next_id
            next_id += 1
            things += 1
        else:
            turned_stuff += 1
    lab.class_ids, lab.instance_ids, lab.naming = class_ids, instance_ids, why
    lab.counts.update(instances=things, stuff_by_votes=turned_stuff, stuff_on_planes=on_layout)


def voted_reason(name: str, share: float) -> tuple[str, str]:
    """The naming (``set_naming``'s by, why) of an object its fused votes named."""
    return "votes", f"{share:.0%} of its points were voted {name}"


#: class_of's reason when none of the class rules names an object.
NO_CLASS_RULE_FITS = "no class rule fits"


def ruled_reason(by: str, rule: str) -> tuple[str, str]:
    """The naming of an object a rule named (``by``, the rule), or ``unnamed`` where no rule fitted it."""
    return ("unnamed", rule) if rule in (NO_RULE_FITS, NO_CLASS_RULE_FITS) else (by, rule)


def on_layout_planes(cells: np.ndarray, obj: np.ndarray, layout: Any, n_obj: int, distance: float) -> np.ndarray:
    """Per object and layout label, how many of its cells lie near a plane of that label."""
    table = np.zeros((n_obj, len(LAYOUT_NAMES)), np.int64)
    member = obj >= 0
    for plane in layout.planes:
        near = member & plane.near(cells, distance)
        table[:, plane.label] += np.bincount(obj[near], minlength=n_obj)
    return table


def voted_name(
    votes: np.ndarray,
    pts: np.ndarray,
    stuff_ids: np.ndarray,
    vocab: Vocabulary,
) -> str | None:
    """The class an object's fused votes give it, if any. Floor, wall or ceiling votes make it that
    stuff where they hold most of its points and it is thin (a floor patch the layout missed); else
    thing votes name it. A thick object whose only votes are the floor its foot stands on (a wardrobe
    in a frame where the detector boxed nothing) is no floor."""
    stuff = np.zeros(len(votes), bool)
    stuff[stuff_ids[stuff_ids > 0]] = True
    if votes[stuff].sum() > 0.5 * len(pts) and thin(pts):
        return vocab.name(int(np.argmax(np.where(stuff, votes, 0))))
    things = np.where(stuff, 0, votes)
    return vocab.name(int(np.argmax(things))) if things.sum() > 0 else None


def vote_table(point_obj: np.ndarray, votes: Semantics, n_obj: int, n_classes: int) -> np.ndarray:
    """Per object, how many of its points each class was fused for (unknown left out)."""
    voted = (point_obj >= 0) & (votes.class_ids > 0) & (votes.class_ids < n_classes)
    key = point_obj[voted] * n_classes + votes.class_ids[voted]
    return np.bincount(key, minlength=n_obj * n_classes).reshape(n_obj, n_classes)


def class_of(
    pts: np.ndarray, top_area: float, base_z: float, vocab: Vocabulary, cfg: ClustersConfig
) -> tuple[str, str]:
    """The class clusters' own rules give an object without votes (and why)."""
    if top_area >= cfg.table_min_area and HOLDS_A_TOP in vocab and vocab.is_thing[vocab.id(HOLDS_A_TOP)]:
        return HOLDS_A_TOP, f"a support surface of {top_area:.2f} m^2 on it (table_min_area {cfg.table_min_area:g})"
    extent = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
    top = float(pts[:, 2].max() - base_z)
    for rule in cfg.class_rules:
        if rule.min_extent <= extent <= rule.max_extent and top <= rule.max_height:
            return rule.class_name, (
                f"extent {extent:.2f} m in {rule.min_extent:g}-{rule.max_extent:g}, top {top:.2f} m "
                f"<= {rule.max_height:g} (class_rules)"
            )
    return unnamed(vocab), NO_CLASS_RULE_FITS
