"""What the frames saw empty, for the contact graph's refined boxes: an object seen from one side
only grows into the space beside it that no frame saw free (``grow_into_unseen``, towards its
class's usual depth, ``usual_depth``), and an object whose underside the frames saw empty does not
reach down to the floor (``seen_free_below``). The frames are a
:class:`~stratamap.core.map.visibility.FreeSpace`."""

from __future__ import annotations

from typing import Any

import numpy as np

from stratamap.core.map.priors import CLASS_SIZES, least_usual_depth

#: Steps (m) in which a box is grown into space the sensor never saw free.
GROW_STEP = 0.05
#: Sample spacing (m) over a step's slab, along the face and up it.
GROW_SAMPLE = 0.05
#: The heights a box is grown at, as shares of its height: its middle, where a chair's seat and a
#: cabinet's body are (a table's top above a pushed-in chair is not in the way).
GROW_BAND = (0.25, 0.75)
#: A slab sample was seen free when at least this many frames saw past it (one frame's mixed pixel
#: at an edge is not enough).
SEEN_FREE_FRAMES = 2
#: A step stops the growth where this share of its samples was seen free ...
SEEN_FREE_SHARE = 0.25
#: ... or where other surfaces fill it: this share of its face area in the map's points, at one point
#: per MAP_CELL square (a wall or another object's side; a table leg is far less).
OCCUPIED_SHARE = 0.25
MAP_CELL = 0.02


def grow_into_unseen(
    box: Any, usual_depth: float, free: Any, others: Any, step: float = GROW_STEP
) -> tuple[Any, int, float] | None:
    """The box of an object seen from one side only, completed front to back (across its shorter
    horizontal side) towards ``usual_depth``: grown, in ``step``s, on the side where the space beside
    it was never seen free (``free``: a :class:`~stratamap.core.map.visibility.FreeSpace`) and no
    other surface fills it (``others``: the map's points near it that are not its own),
    on its middle heights; the side where it grows farther wins (right behind a chair's back its own
    shadow hides a few centimetres); where both sides let it grow all the way (only its top was
    seen: a chair's back between a table top and a counter), it grows both ways alike. Returns (grown
    box, side +1/-1 along the box axis or 0 for both, growth in m), or None where it is as deep as
    that or both sides stop it alike short of that."""
    size = np.asarray(box.size, float)
    axis = int(np.argmin(size[:2]))
    need = usual_depth - size[axis]
    if need < step / 2:
        return None
    along = 1 - axis
    rot = box.pose[:3, :3]
    half_length = max(size[along] / 2 - GROW_SAMPLE / 2, 0.0)
    ts = np.arange(-half_length, half_length + 1e-9, GROW_SAMPLE)
    zs = np.arange(box.bottom_z + GROW_BAND[0] * size[2], box.bottom_z + GROW_BAND[1] * size[2] + 1e-9, GROW_SAMPLE)
    steps = int(np.ceil(need / step - 1e-9))
    other = np.asarray(others, float).reshape(-1, 3)
    other = other[(other[:, 2] >= zs[0]) & (other[:, 2] <= zs[-1])]
    other_local = (other - box.center) @ rot
    face_cells = max(size[along] * (zs[-1] - zs[0]) / MAP_CELL**2, 1.0)  # a box too low for a band: one cell
    # The samples on the face's plane (world); a step's slab is them moved out along the depth axis.
    t, z = np.meshgrid(ts, zs, indexing="ij")
    local = np.zeros((t.size, 3))
    local[:, along] = t.ravel()
    on_face = local @ rot.T + box.center
    on_face[:, 2] = z.ravel()
    outward = rot[:, axis]
    grown = {}
    for side in (1.0, -1.0):
        reach = 0.0
        for k in range(steps):
            near, far = size[axis] / 2 + k * step, size[axis] / 2 + min((k + 1) * step, need)
            samples = on_face + (side * (near + far) / 2) * outward
            if (free.seen_free(samples) >= SEEN_FREE_FRAMES).mean() >= SEEN_FREE_SHARE:
                break
            in_slab = (
                (np.abs(other_local[:, along]) <= size[along] / 2)
                & (side * other_local[:, axis] >= near)
                & (side * other_local[:, axis] <= far)
            )
            if in_slab.sum() >= OCCUPIED_SHARE * face_cells:
                break
            reach = far - size[axis] / 2
        grown[side] = reach
    offset = np.zeros(3)
    if grown[1.0] == grown[-1.0]:
        if grown[1.0] < need - 1e-9:
            return None  # seen free on both sides near it: as thin as it looks
        # Unseen as far as it could reach on both sides (only its top was seen): it grows both ways
        # alike, its centre kept.
        side, reach = 0.0, need
    else:
        side = 1.0 if grown[1.0] > grown[-1.0] else -1.0
        reach = grown[side]
        offset[axis] = side * reach / 2
    new_size = size.copy()
    new_size[axis] += reach
    return type(box)(np.asarray(box.center, float) + rot @ offset, box.yaw, new_size), int(side), float(reach)


#: The slab under an object judged for free space: from this far (m) below its bottom ...
BELOW_FROM = 0.03
#: ... to this far: a shelf hangs over a worktop 0.3-0.5 m below it, a wall cabinet over the tiles.
BELOW_TO = 0.15
#: The object ends at its bottom when this share of the slab's samples was seen free.
BELOW_FREE_SHARE = 0.5


def seen_free_below(box: Any, free: Any) -> bool:
    """Whether the frames (``free``: a :class:`~stratamap.core.map.visibility.FreeSpace`) saw the
    space just under ``box`` empty: BELOW_FREE_SHARE of the samples over its footprint (every
    GROW_SAMPLE, from BELOW_FROM to BELOW_TO under its bottom) seen free by SEEN_FREE_FRAMES frames.
    Then nothing of it reaches down there, however far its support lies."""
    size = np.asarray(box.size, float)
    u = np.arange(-size[0] / 2, size[0] / 2 + 1e-9, GROW_SAMPLE)
    v = np.arange(-size[1] / 2, size[1] / 2 + 1e-9, GROW_SAMPLE)
    z = np.arange(box.bottom_z - BELOW_TO, box.bottom_z - BELOW_FROM + 1e-9, GROW_SAMPLE)
    uu, vv, zz = np.meshgrid(u, v, z, indexing="ij")
    local = np.stack([uu.ravel(), vv.ravel(), np.zeros(uu.size)], axis=1)
    samples = local @ box.pose[:3, :3].T + box.center
    samples[:, 2] = zz.ravel()
    return bool(len(samples)) and (free.seen_free(samples) >= SEEN_FREE_FRAMES).mean() >= BELOW_FREE_SHARE


def usual_depth(class_name: str, box: Any, floor_z: float, tolerance: float) -> float | None:
    """How deep an object is taken to be front to back: its class's usual depth; for an object of no
    class with one (``object``, or a name whose class gives none) that stands on the floor (its box,
    as refined, down to it), the least usual depth of the classes standing that high
    (``priors.least_usual_depth``: a chair's back seen from behind, named nothing, is at least as deep
    as the shallowest furniture of its height); else None."""
    size = CLASS_SIZES.get(class_name)
    if size is not None and size.usual_depth is not None:
        return size.usual_depth
    if box.bottom_z - floor_z > tolerance:
        return None
    return least_usual_depth(float(box.top_z - floor_z))
