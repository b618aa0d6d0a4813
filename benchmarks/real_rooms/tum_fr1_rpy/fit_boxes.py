"""The hand labels of the held-out office, TUM RGB-D fr1/rpy (benchmarks/real_rooms/tum_fr1_rpy/):
boxes fitted to the fused 2 cm TSDF points inside hand-drawn top-view polygons and height bands, so
that boxes.json can be made again and checked. No segmentation output is read.

    stratamap run GEOMETRY.yaml --out RUN    # source: tum on the recording; stages: tsdf (voxel_size 0.02)
    python benchmarks/real_rooms/tum_fr1_rpy/fit_boxes.py RUN [--write]

The run's map is in the tum source's levelled world (its report's
``notes.tum.gravity_alignment.transform``), which is 4.7 degrees off level on this recording, so the
boxes are drawn in the recording's own motion-capture world levelled on a RANSAC fit of the fused
floor (0.4 degrees; ``T_LEVEL``), which boxes.json stores as ``world_transform``. Each box: the points
in its polygon and height band; yaw from a minimum-area search (1 degree steps) over the 1/99
percentile extents unless given; from the floor (z = 0) to the top given, else the band's 99.5th
percentile.
"""

import argparse
import json
from pathlib import Path

import numpy as np
from matplotlib.path import Path as Poly

OUT = Path(__file__).resolve().parent / "boxes.json"

# recording (mocap) world -> level world: floor normal (0.0024, -0.0069, 1) through (0.218, -1.107, 0.012) to +z, z=0
T_LEVEL = np.array(
    [
        [0.99999712, 8.28e-06, -0.002399936, 0.0],
        [8.28e-06, 0.999976196, 0.006899816, 0.0],
        [0.002399936, -0.006899816, 0.999973316, -0.020160962],
        [0.0, 0.0, 0.0, 1.0],
    ]
)


def level_points(run: Path) -> np.ndarray:
    from stratamap.core.map.format import read_layers

    m = read_layers(json.loads((run / "map/manifest.json").read_text()), run / "map")
    P = np.asarray(m.geometry.points, float)
    T_run = np.array(json.loads((run / "report.json").read_text())["notes"]["tum"]["gravity_alignment"]["transform"])
    M = T_LEVEL @ np.linalg.inv(T_run)
    return P @ M[:3, :3].T + M[:3, 3]


def select(L, poly, z0, z1):
    m = (L[:, 2] > z0) & (L[:, 2] < z1)
    m &= Poly(np.array(poly)).contains_points(L[:, :2])
    return L[m]


def fit(S, yaw=None, pct=(1, 99)):
    xy = S[:, :2]
    best = None
    for a in [yaw] if yaw is not None else np.radians(np.arange(0, 90, 1.0)):
        c, s = np.cos(a), np.sin(a)
        u = xy @ np.array([c, s])
        v = xy @ np.array([-s, c])
        lo = np.percentile(u, pct[0]), np.percentile(v, pct[0])
        hi = np.percentile(u, pct[1]), np.percentile(v, pct[1])
        area = (hi[0] - lo[0]) * (hi[1] - lo[1])
        if best is None or area < best[0]:
            best = (area, a, lo, hi)
    _, a, lo, hi = best
    c, s = np.cos(a), np.sin(a)
    cu, cv = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    center = np.array([c * cu - s * cv, s * cu + c * cv])
    return center, [hi[0] - lo[0], hi[1] - lo[1]], a


# name, top-view polygon (level world x, y), height band, yaw (None: fitted), top (None: the band's 99.5th
# percentile), least horizontal size (a seat is at least 0.4 m deep). Class and how each was seen are in
# boxes.json (params.seen), written by hand.
BOXES = [
    ("desk_block_main", [(-0.72, -0.1), (1.08, -0.1), (1.08, 1.56), (-0.72, 1.56)], (0.62, 0.8), 0.0, 0.765, None),
    ("desk_window", [(0.2, 1.58), (1.1, 1.58), (1.1, 2.41), (0.2, 2.41)], (0.7, 0.86), 0.0, 0.81, None),
    ("desk_south", [(-0.45, -1.08), (0.48, -1.08), (0.48, -2.5), (-0.45, -2.5)], (0.66, 0.9), None, 0.84, None),
    (
        "chair_blue_by_cabinet",
        [(-1.67, -0.52), (-1.0, -0.52), (-1.0, 0.3), (-1.67, 0.3)],
        (0.08, 1.12),
        None,
        None,
        None,
    ),
    ("chair_blue_south", [(-1.7, -1.42), (-1.0, -1.42), (-1.0, -0.85), (-1.7, -0.85)], (0.25, 1.3), None, None, 0.4),
    ("cabinet_tall_white", [(-2.12, -1.05), (-1.7, -1.05), (-1.7, 0.36), (-2.12, 0.36)], (0.02, 2.43), 0.0, 2.45, None),
]


def main(run: Path, write: bool = False) -> list[dict]:
    """The fitted boxes (printed); with ``write``, boxes.json's centres, sizes and yaws replaced by them."""
    L = level_points(run)
    doc = json.loads(OUT.read_text())
    by_name = {box["name"]: box for box in doc["boxes"]}
    for name, poly, (z0, z1), yaw, top, min_depth in BOXES:
        S = select(L, poly, z0, z1)
        c, size, a = fit(S, yaw)
        if min_depth and min(size) < min_depth:
            size[int(np.argmin(size))] = min_depth
        zt = top if top is not None else float(np.percentile(S[:, 2], 99.5))
        box = by_name[name]
        box["center"] = [round(float(c[0]), 3), round(float(c[1]), 3), round(zt / 2, 3)]
        box["size"] = [round(float(size[0]), 2), round(float(size[1]), 2), round(zt, 2)]
        box["yaw"] = round(float(a), 3)
        print(f"{name:24s} n={len(S):6d} center={box['center']} size={box['size']} yaw={box['yaw']}")
    if write:
        doc["world_transform"] = np.round(T_LEVEL, 9).tolist()
        OUT.write_text(json.dumps(doc, indent=1) + "\n")
        print("wrote", OUT)
    return doc["boxes"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a stratamap run of the recording with the tsdf stage")
    parser.add_argument("--write", action="store_true", help="write boxes.json beside this script")
    args = parser.parse_args()
    main(args.run, args.write)
