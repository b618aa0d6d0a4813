"""Colours of classes and instances, the same wherever a map is drawn (report.html, the viewer,
recordings, ROS 2 markers): matplotlib's tab20 by id, grey for id 0 (no class, no instance)."""

from __future__ import annotations

import numpy as np

UNLABELLED_GREY = 0.62


def id_colors(ids: np.ndarray) -> np.ndarray:
    """(N, 3) float colours in [0, 1] for integer ids."""
    from matplotlib import colormaps

    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    colors = np.asarray(colormaps["tab20"](ids % 20))[:, :3]
    colors[ids == 0] = UNLABELLED_GREY
    return colors
