"""Keyframes: the frames of a stream worth labelling.

A per-frame segmenter costs far more a frame than fusing the frame's depth (the shipped detector
and its depth segmentation: about 0.1 s a frame against 0.02 s), and a hand-held walk sees each
surface in dozens of frames. A frame is a *keyframe* when enough of what it sees is new: at least
``new_surface`` of its depth pixels (on a coarse pixel grid) lie more than a cell (``cell``
metres) from every cell a keyframe before it saw. The margin of one cell keeps a camera that moved
a few centimetres from finding its points in new cells only because they crossed a cell's border.
Every frame is still fused into the geometry; only the labelling is thinned. Chosen in stream
order, frame by frame, from depth and pose alone: deterministic, and cheap (a few thousand points a
frame).
"""

from __future__ import annotations

import numpy as np

from stratamap.core.map.sensors import CameraIntrinsics

#: Cell coordinates within +-2^20 cells pack into one int64 (21 bits an axis).
_OFFSET = np.int64(1) << 20
_BITS = 21


def cell_ids(points: np.ndarray, cell: float) -> np.ndarray:
    """One int64 per point naming its cubic cell of side ``cell`` in the world (the same cell has the
    same id in every frame)."""
    k = np.floor(points / cell).astype(np.int64) + _OFFSET
    return (k[:, 0] << (2 * _BITS)) | (k[:, 1] << _BITS) | k[:, 2]


class KeyframeChooser:
    """Chooses the keyframes of a stream, one frame at a time in stream order.

    ``new_surface``: the share of a frame's sampled depth pixels that must lie more than a cell from
    every cell a keyframe saw (with ``views`` above 1: in cells fewer than ``views`` keyframes saw, or
    near them) for it to be a keyframe (0: every frame is one). ``cell``: the cell
    side (m); ``stride``: the pixel grid the depth is sampled on; ``depth_max``: farther depth is not
    counted (noise at range would make every frame new). A frame without usable depth or pose is no
    keyframe; the first frame with both is one."""

    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        new_surface: float,
        cell: float = 0.1,
        stride: int = 8,
        depth_max: float = 4.0,
        views: int = 1,
    ):
        self.intrinsics = intrinsics
        self.new_surface = float(new_surface)
        self.cell = float(cell)
        self.stride = int(stride)
        self.depth_max = float(depth_max)
        self.views = max(1, int(views))
        self.seen = np.zeros(0, np.int64)  # sorted cell ids the keyframes saw
        self.count = np.zeros(0, np.int64)  # how many keyframes saw each of them

    def __call__(self, depth: np.ndarray | None, pose: np.ndarray | None) -> bool:
        """Whether this frame (its depth in metres, camera-to-world pose) is a keyframe; a keyframe's
        cells count as seen from now on."""
        if self.new_surface <= 0.0:
            return True
        if depth is None or pose is None:
            return False
        depth = np.asarray(depth, np.float64)
        pts, _ = self.intrinsics.backproject(np.where(depth <= self.depth_max, depth, 0.0), self.stride)
        if not len(pts):
            return False
        pose = np.asarray(pose, np.float64)
        cells = cell_ids(pts @ pose[:3, :3].T + pose[:3, 3], self.cell)
        if len(self.seen):
            at = np.minimum(np.searchsorted(self.seen, cells), len(self.seen) - 1)
            views = np.where(self.seen[at] == cells, self.count[at], 0)
        else:
            views = np.zeros(len(cells), np.int64)
        new = views < self.views  # pixels in cells fewer than `views` keyframes saw
        if len(self.seen) and new.mean() < self.new_surface:
            return False
        touched = _with_neighbours(np.unique(cells))
        merged = np.union1d(self.seen, touched)
        count = np.zeros(len(merged), np.int64)
        count[np.searchsorted(merged, self.seen)] = self.count
        count[np.searchsorted(merged, touched)] += 1
        self.seen, self.count = merged, count
        return True


#: The id offsets of a cell's 26 neighbours and itself.
_NEIGHBOURS = np.array(
    [(dx << (2 * _BITS)) + (dy << _BITS) + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)],
    np.int64,
)


def _with_neighbours(cells: np.ndarray) -> np.ndarray:
    """The cells and every cell touching one of them, as sorted unique ids."""
    return np.unique((cells[:, None] + _NEIGHBOURS[None, :]).ravel())
