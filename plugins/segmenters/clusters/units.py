"""Pass ``split_units`` (``recognize``): units side by side that came out as one instance (a counter
against a tall unit, their fronts in one plane) become two where their tops step."""

from __future__ import annotations

import numpy as np

from stratamap.plugins.segmenters.clusters.labelling import Labelling
from stratamap.plugins.segmenters.clusters.shapes import FLOOR_GAP

#: An instance needs this many points before it is tried as two units.
MIN_POINTS = 200


def split_units(lab: Labelling) -> None:
    """Sets ``instance_ids``: the taller unit of each split takes a new id (and the reason for its
    class, ``naming``). Each split is noted (``units_split``)."""
    from stratamap.core.map.instances import instance_members

    if not lab.cfg.recognize:
        return
    splits = []
    next_id = int(lab.instance_ids.max()) + 1
    for iid, sel in instance_members(lab.instance_ids).items():
        cls = int(np.bincount(lab.class_ids[sel]).argmax())
        if len(sel) < MIN_POINTS or not lab.vocab.is_thing[cls]:
            continue
        tall = split_at_step(lab.points[sel], lab.base_z)
        if tall is None:
            continue
        lab.relabel(sel[tall], instance=next_id)
        splits.append({"instance": iid, "taller_unit": next_id, "points": int(tall.sum())})
        if iid in lab.naming:
            by, reason = lab.naming[iid]
            lab.naming[next_id] = (by, f"{reason} (split from object {iid} where their tops step)")
        next_id += 1
    lab.note("units_split", splits)


#: Units in a row differ in height by at least this (m) where one ends: a tall unit (a fridge, an oven
#: column, a cupboard) rises far above a worktop; an appliance standing on it (a coffee machine, a
#: microwave, 0.3-0.45 m) does not.
STEP_HEIGHT = 0.5
#: Each unit of a row is at least this long (m) along the row.
UNIT_LENGTH = 0.3


def split_at_step(pts: np.ndarray, base_z: float) -> np.ndarray | None:
    """Where a floor-standing solid object is two units side by side (a counter against a tall unit,
    their fronts in one plane, so that neither the frames' depth edges nor the map's convexity part
    them): its top, along its long axis, is level on each side of one place and steps there by
    STEP_HEIGHT or more, each side UNIT_LENGTH long or longer, and the taller side's front lies at the
    same place across the row above and below the lower top (a unit's front from the floor up, not a
    coffee machine standing back on a worktop). Returns a boolean mask of the taller unit's points,
    or None."""
    from stratamap.core.geometry.boxes import gravity_aligned_box

    box = gravity_aligned_box(pts)
    axis = np.array([np.cos(box.yaw), np.sin(box.yaw)])
    if box.size[1] > box.size[0]:
        axis = np.array([-axis[1], axis[0]])
    length = float(max(box.size[:2]))
    if length < 2 * UNIT_LENGTH or float(pts[:, 2].min()) - base_z > FLOOR_GAP:
        return None
    cell = 0.05
    along = pts[:, :2] @ axis
    bins = np.floor((along - along.min()) / cell).astype(np.int64)
    n_bins = int(bins.max()) + 1
    top = np.full(n_bins, np.nan)
    for b in np.unique(bins):
        z = pts[bins == b, 2]
        if len(z) >= 5:
            top[b] = np.percentile(z, 95)
    # The cut of the best two-level fit of the top profile (least absolute deviation).
    best: tuple[float, int] | None = None
    need = int(round(UNIT_LENGTH / cell))
    for cut in range(need, n_bins - need + 1):
        left, right = top[:cut], top[cut:]
        left, right = left[np.isfinite(left)], right[np.isfinite(right)]
        if len(left) < need or len(right) < need:
            continue
        cost = float(np.abs(left - np.median(left)).sum() + np.abs(right - np.median(right)).sum())
        if best is None or cost < best[0]:
            best = (cost, cut)
    if best is None:
        return None
    cut = best[1]
    left, right = top[:cut], top[cut:]
    left, right = left[np.isfinite(left)], right[np.isfinite(right)]
    left_top, right_top = float(np.median(left)), float(np.median(right))
    level = (np.abs(left - left_top) <= 0.1).mean() >= 0.8 and (np.abs(right - right_top) <= 0.1).mean() >= 0.8
    if abs(right_top - left_top) < STEP_HEIGHT or not level:
        return None
    tall = bins >= cut if right_top > left_top else bins < cut
    lower_top = min(left_top, right_top)
    across = pts[:, :2] @ np.array([-axis[1], axis[0]])
    upper = across[tall & (pts[:, 2] > lower_top + 0.05)]
    below = across[tall & (pts[:, 2] > base_z + 0.2) & (pts[:, 2] < lower_top - 0.1)]
    if len(upper) < 20 or len(below) < 20:
        return None
    # The taller unit's body reaches the floor: its front (the row's side seen most: the back stands
    # against a wall) lies at the same place across the row above and below the lower top; a coffee
    # machine's front stands back from the worktop's.
    back, front = float(across.min()), float(across.max())
    sign = 1.0 if (across > front - 0.03).sum() >= (across < back + 0.03).sum() else -1.0
    if abs(np.percentile(sign * upper, 95) - np.percentile(sign * below, 95)) > 0.05:
        return None
    return tall
