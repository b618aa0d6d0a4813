"""Nav2 map files (``map.yaml`` + ``map.pgm``), written and read by nav2_map_server's rules.

Writing follows ``map_saver`` in *trinary* mode: occupied cells (>= 65) are 0 (black), free cells
(0) are 254, unknown cells are 205; thresholds occupied 0.65, free 0.196. The image's first row is
the map's *top* (highest y), so rows are flipped relative to ``OccupancyGrid.data``.

Reading follows ``map_server``'s ``loadMapFromFile``: for each pixel, ``p = (255 - v) / 255``
(``v / 255`` with ``negate: 1``); in trinary mode ``p > occupied_thresh`` is 100,
``p < free_thresh`` is 0, anything else -1; in *scale* mode values in between become
``99 * (p - free) / (occ - free)`` rounded; in *raw* mode the value is the cell.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from stratamap.core.atomic import atomic_path, write_text
from stratamap.core.errors import DataError
from stratamap.core.io import brief
from stratamap.core.map.layers import OccupancyGrid

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN = 0, 254, 205


#: Occupancy values (0-100) at and above which a cell is occupied, and at or below which it is free,
#: as map_saver's defaults (occupied_thresh 0.65, free_thresh 0.196 of 100, rounded to cells).
OCCUPIED_CELL, FREE_CELL = 65, 25
#: Nav2 costmap values.
COST_FREE, COST_INSCRIBED, COST_LETHAL, COST_UNKNOWN = 0, 253, 254, 255


def _write_image_map(
    image: np.ndarray, grid: OccupancyGrid, directory: Path, basename: str, mode: str
) -> tuple[Path, Path]:
    """``basename.pgm`` (rows flipped: the image's first row is the map's top) and ``basename.yaml``."""
    directory.mkdir(parents=True, exist_ok=True)
    pgm = directory / f"{basename}.pgm"
    with atomic_path(pgm) as tmp:
        Image.fromarray(np.flipud(image), mode="L").save(tmp, format="PPM")  # PIL writes "L" images as binary P5 PGM
    meta = {
        "image": pgm.name,
        "mode": mode,
        "resolution": float(grid.resolution),
        "origin": [float(v) for v in grid.origin],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
    }
    yml = directory / f"{basename}.yaml"
    write_text(yml, yaml.safe_dump(meta, sort_keys=False, default_flow_style=None))
    return yml, pgm


def no_free_space(grid: OccupancyGrid, what: str) -> str | None:
    """Why a map written from ``grid`` gives a robot nowhere to go, when none of its cells is free
    (``FREE_CELL``): a Nav2 planner finds no path on it. ``what`` names the file; else None."""
    data = np.asarray(grid.data)
    if np.any((data >= 0) & (data <= FREE_CELL)):
        return None
    occupied = int(np.sum(data >= OCCUPIED_CELL))
    return (
        f"{what} has no free cells ({occupied:,} occupied, {data.size - occupied:,} unknown of {data.size:,}): a "
        "planner finds no path on it (a laser layer needs several looks at a place to call it free; see the "
        "report's occupancy notes for what it was made from)"
    )


def write_map(grid: OccupancyGrid, directory: str | Path, basename: str = "map") -> tuple[Path, Path]:
    """Write ``basename.pgm`` and ``basename.yaml`` (atomically) for nav2_map_server."""
    data = grid.data
    img = np.full(data.shape, PGM_UNKNOWN, np.uint8)
    img[(data >= 0) & (data <= FREE_CELL)] = PGM_FREE
    img[data >= OCCUPIED_CELL] = PGM_OCCUPIED
    return _write_image_map(img, grid, Path(directory), basename, "trinary")


def costmap_values(
    grid: OccupancyGrid, inscribed_radius: float, inflation_radius: float, cost_scaling_factor: float
) -> np.ndarray:
    """Nav2 cost values of an occupancy grid with inflation: 0 free, 254 lethal (occupied), 253
    inscribed (within ``inscribed_radius`` of an obstacle), 255 unknown, and between them Nav2's
    decay ``252 * exp(-cost_scaling_factor * (d - inscribed_radius))`` up to ``inflation_radius``."""
    from scipy import ndimage

    occupied = grid.data >= OCCUPIED_CELL
    unknown = grid.data < 0
    dist = (
        ndimage.distance_transform_edt(~occupied) * grid.resolution
        if occupied.any()
        else np.full(grid.data.shape, np.inf)
    )
    cost = np.zeros(grid.data.shape, np.float64)
    ramp = (dist > inscribed_radius) & (dist <= inflation_radius)
    cost[ramp] = 252.0 * np.exp(-cost_scaling_factor * (dist[ramp] - inscribed_radius))
    out = np.rint(cost).astype(np.uint8)
    out[dist <= inscribed_radius] = COST_INSCRIBED
    out[occupied] = COST_LETHAL
    out[unknown & ~occupied] = COST_UNKNOWN
    return out


def write_costmap(
    values: np.ndarray, grid: OccupancyGrid, directory: str | Path, basename: str = "costmap"
) -> tuple[Path, Path]:
    """Write cost values as ``basename.pgm`` + ``basename.yaml`` in Nav2's *raw* mode (atomically)."""
    return _write_image_map(np.asarray(values, np.uint8), grid, Path(directory), basename, "raw")


def read_map(yaml_path: str | Path) -> OccupancyGrid:
    """Load a map as nav2_map_server does; errors name the file and the key at fault."""
    yaml_path = Path(yaml_path)
    if not yaml_path.is_file():
        raise DataError(f"{yaml_path}: map YAML not found")
    try:
        meta: Any = yaml.safe_load(yaml_path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise DataError(f"{yaml_path}: not valid YAML ({brief(exc)})") from exc
    except (ValueError, TypeError, RecursionError) as exc:  # e.g. a date YAML cannot construct: 2022-13-45
        raise DataError(f"{yaml_path}: not valid YAML ({brief(exc, True)})") from exc
    except OSError as exc:
        raise DataError(f"{yaml_path}: cannot be read ({brief(exc)})") from exc
    if not isinstance(meta, dict):
        raise DataError(f"{yaml_path}: expected a mapping with image, resolution, origin, ...")
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise DataError(f"{yaml_path}: missing key {key!r}")
    mode = str(meta.get("mode", "trinary"))
    if mode not in ("trinary", "scale", "raw"):
        raise DataError(f"{yaml_path}: mode {mode!r} is not one of trinary, scale, raw")
    negate = meta.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise DataError(f"{yaml_path}: negate must be 0 or 1, got {negate!r}")
    occ = _number(meta.get("occupied_thresh", OCCUPIED_THRESH), yaml_path, "occupied_thresh")
    free = _number(meta.get("free_thresh", FREE_THRESH), yaml_path, "free_thresh")
    if not 0 <= free < occ <= 1:
        raise DataError(
            f"{yaml_path}: thresholds must satisfy 0 <= free_thresh < occupied_thresh <= 1, got {free}, {occ}"
        )
    origin = meta["origin"]
    if not (isinstance(origin, list) and len(origin) == 3):
        raise DataError(f"{yaml_path}: origin must be [x, y, yaw], got {origin!r}")
    origin = [_number(v, yaml_path, "origin") for v in origin]
    res = _number(meta["resolution"], yaml_path, "resolution")
    if res <= 0:
        raise DataError(f"{yaml_path}: resolution must be a positive number, got {meta['resolution']!r}")
    if not isinstance(meta["image"], str) or not meta["image"].strip():
        raise DataError(f"{yaml_path}: image must be a file name, got {meta['image']!r}")
    image_path = Path(meta["image"])
    if not image_path.is_absolute():
        image_path = yaml_path.parent / image_path
    if not image_path.is_file():
        raise DataError(f"{yaml_path}: the map image {image_path} named by key 'image' does not exist")
    try:
        with Image.open(image_path) as im:
            im.load()
            has_alpha = im.mode in ("LA", "RGBA")
            arr = np.asarray(im.convert("LA") if has_alpha else im.convert("L"), dtype=np.float64)
    except UnidentifiedImageError as exc:
        raise DataError(f"{image_path}: cannot be read as an image ({brief(exc)})") from exc
    except Exception as exc:  # Pillow's decoders raise OSError, ValueError, SyntaxError, struct.error, ...
        raise DataError(f"{image_path}: cannot be read as an image ({brief(exc, True)})") from exc
    if arr.ndim != 2 + has_alpha or arr.size == 0:
        raise DataError(f"{image_path}: expected a non-empty grayscale image, got shape {arr.shape}")
    if has_alpha:
        alpha, arr = arr[..., 1], arr[..., 0]
    else:
        alpha = None
    value = arr if mode == "raw" else (arr / 255.0 if negate else (255.0 - arr) / 255.0)
    cells = np.full(arr.shape, -1, np.int16)
    if mode == "raw":
        cells = arr.astype(np.int16)
    else:
        cells[value > occ] = 100
        cells[value < free] = 0
        if mode == "scale":
            mid = (value >= free) & (value <= occ)
            cells[mid] = np.rint(99 * (value[mid] - free) / (occ - free)).astype(np.int16)
        if alpha is not None:
            cells[alpha < 255] = -1  # map_server: transparent pixels are unknown in scale mode
    data = np.flipud(cells).astype(np.int8)
    return OccupancyGrid(data, res, (origin[0], origin[1], origin[2]))


def _number(value: Any, yaml_path: Path, key: str) -> float:
    """A finite number from the YAML, or a DataError naming the file and key."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DataError(f"{yaml_path}: {key} must be a number, got {value!r}")
    try:
        ok = math.isfinite(value)
    except OverflowError:
        ok = False
    if not ok:
        raise DataError(f"{yaml_path}: {key} must be a finite number, got {value!r}")
    return float(value)
