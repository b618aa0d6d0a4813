"""Walls for ``layout.find_layout``: the directions the map's vertical cells face, and what the sensor
saw through a wall's openings (a door, a window)."""

from __future__ import annotations

import numpy as np


def wall_directions(normal: np.ndarray, vertical: np.ndarray, spread_deg: float, min_cells: int) -> list[np.ndarray]:
    """Dominant horizontal normal directions of the vertical cells: peaks of a histogram of their
    azimuths (modulo 180 degrees), each at least ``min_cells`` strong, peaks ``spread_deg`` apart."""
    azimuth = np.degrees(np.arctan2(normal[vertical, 1], normal[vertical, 0])) % 180.0
    hist = np.bincount(np.floor(azimuth).astype(np.int64) % 180, minlength=180).astype(float)
    width = max(1, int(spread_deg // 3))
    smooth = sum(np.roll(hist, s) for s in range(-width, width + 1))
    out = []
    for _ in range(16):
        peak = int(np.argmax(smooth))
        if smooth[peak] < min_cells:
            break
        # The peak's direction: the circular mean (of doubled angles, as directions repeat every
        # 180 degrees) of the azimuths near it, not the histogram bin.
        near = np.abs((azimuth - peak + 90.0) % 180.0 - 90.0) <= spread_deg
        doubled = np.radians(2.0 * azimuth[near])
        angle = 0.5 * np.arctan2(np.sin(doubled).sum(), np.cos(doubled).sum())
        out.append(np.array([np.cos(angle), np.sin(angle), 0.0]))
        around = (np.arange(180) - peak + 90) % 180 - 90
        smooth[np.abs(around) <= 2 * spread_deg] = 0.0
    return out


def through_openings(
    beyond: np.ndarray,
    views: np.ndarray,
    normal: np.ndarray,
    offset: float,
    tangent: np.ndarray,
    wall: np.ndarray,
    cell: float,
    doorway_max_width: float,
) -> np.ndarray:
    """Which points ``beyond`` a wall plane (``normal . x = offset``, its points ``wall``) a viewpoint
    saw through an opening of it: the sight line crosses the plane within the wall's width and below
    its top (the 95th percentile of its points' heights), where the wall has no point (``cell``-sized
    squares along ``tangent`` and up), in a column of the wall that is empty or has wall above the
    crossing: a door (its lintel the sensor need not have seen: a camera at eye height rarely sees a
    doorway's top) or a window. A sensor also sees over a cabinet's front or a partition, but that
    crossing lies above its top, so what lies behind those still counts; so does what it sees over a
    counter's front beside a tall cabinet's, which the plane fit can take for one plane: the
    crossing lies above the top of the counter's columns, though below the cabinet's. A run of empty
    columns wider than ``doorway_max_width`` is no doorway: the plane fit joined two things that
    stand apart in one plane (a fridge's side and a chair's across the room)."""
    along = np.floor(wall @ tangent / cell).astype(np.int64)
    up = np.floor(wall[:, 2] / cell).astype(np.int64)
    low = int(up.min()) - 1
    width = int(up.max()) - low + 2
    occupied = np.unique((along - along.min()) * width + (up - low))
    first, last = along.min(), along.max()
    wall_top = np.percentile(up, 95)
    column_top = np.full(last - first + 1, np.iinfo(np.int64).min)
    np.maximum.at(column_top, along - first, up)
    empty_column = column_top == np.iinfo(np.int64).min
    empty_column &= _run_lengths(empty_column) * cell <= doorway_max_width
    seen = np.zeros(len(beyond), bool)
    far = beyond @ normal - offset
    for view in views:
        near = float(view @ normal - offset)
        crossing = near * far < 0
        if not crossing.any():
            continue
        share = near / (near - far[crossing])
        x = view + share[:, None] * (beyond[crossing] - view)
        a = np.floor(x @ tangent / cell).astype(np.int64)
        z = np.floor(x[:, 2] / cell).astype(np.int64)
        inside = (a >= first) & (a <= last) & (z < wall_top)
        key = (a - first) * width + (z - low)
        pos = np.clip(np.searchsorted(occupied, key), 0, len(occupied) - 1)
        empty = (occupied[pos] != key) | (z < low) | (z >= low + width)
        column = np.clip(a - first, 0, last - first)
        under_wall = empty_column[column] | (z < column_top[column])
        seen[np.flatnonzero(crossing)[inside & empty & under_wall]] = True
    return seen


def _run_lengths(flags: np.ndarray) -> np.ndarray:
    """Per element of a non-empty array, the length of the run of equal values it lies in."""
    starts = np.flatnonzero(np.r_[True, flags[1:] != flags[:-1]])
    lengths = np.diff(np.r_[starts, len(flags)])
    return np.repeat(lengths, lengths)
