"""How `clusters` scales with the size of a fused map: halls of boxes, side by side in one run.

Builds halls of 2 cm surface points (floor, four walls, a grid of 30 cm boxes), each hall the last
one's floor area times four with four times its boxes, and segments each with `clusters`' defaults.
Prints the seconds per million points of each hall and the ratio of the largest hall's to the
smallest's: 1.0 is linear in the map's size. A step whose cost grows with (objects x points), such
as selecting each object's points by comparing every point with its id, shows up as a ratio that
grows with the hall. Also checks that every box is its own instance. Last line: JSON.

    python benchmarks/clusters_scaling.py [--halls 3] [--repeats 1]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from stratamap.core.map.layers import Geometry
from stratamap.core.stages import PipelineData
from stratamap.plugins.segmenters.clusters import ClustersSegmenter

SPACING = 0.02


def face_grid(lo, hi, faces: str) -> np.ndarray:
    """Points every SPACING on the named faces of the box lo-hi (x: the face at lo[0], X: at hi[0], ...)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = []
    for face in faces:
        axis = "xyz".index(face.lower())
        u, v = [a for a in range(3) if a != axis]
        uu, vv = np.meshgrid(np.arange(lo[u], hi[u] + 1e-9, SPACING), np.arange(lo[v], hi[v] + 1e-9, SPACING))
        pts = np.zeros((uu.size, 3))
        pts[:, u], pts[:, v] = uu.ravel(), vv.ravel()
        pts[:, axis] = hi[axis] if face.isupper() else lo[axis]
        out.append(pts)
    return np.concatenate(out)


def hall(columns: int, rows: int) -> tuple[np.ndarray, int]:
    """A hall holding a grid of columns x rows boxes 1.2 m x 0.75 m apart; its points and box count."""
    lx, ly, lz = 1.2 * columns + 1.0, 0.75 * rows + 1.0, 2.6
    parts = [
        face_grid((0, 0, 0), (lx, ly, 0), "z"),
        face_grid((0, 0, 0), (0, ly, lz), "x"),
        face_grid((lx, 0, 0), (lx, ly, lz), "X"),
        face_grid((0, 0, 0), (lx, 0, lz), "y"),
        face_grid((0, ly, 0), (lx, ly, lz), "Y"),
    ]
    for i in range(columns):
        for j in range(rows):
            x, y = 1.0 + 1.2 * i, 1.0 + 0.75 * j
            parts.append(face_grid((x - 0.15, y - 0.15, 0.0), (x + 0.15, y + 0.15, 0.3), "xXyYZ"))
    return np.concatenate(parts), columns * rows


def segment(points: np.ndarray) -> int:
    data = PipelineData()
    data.map.geometry = Geometry(points=points, voxel_size=SPACING)
    return len(ClustersSegmenter().run(data)["instances"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--halls", type=int, default=3, help="Number of halls, each 4x the last one's area.")
    parser.add_argument("--repeats", type=int, default=1, help="Timings per hall; the fastest is kept.")
    args = parser.parse_args()
    rows = []
    for k in range(args.halls):
        points, boxes = hall(6 * 2**k, 6 * 2**k)
        best, found = np.inf, -1
        for _ in range(args.repeats):
            start = time.perf_counter()
            found = segment(points)
            best = min(best, time.perf_counter() - start)
        rows.append({"points": len(points), "boxes": boxes, "instances": found, "seconds": round(best, 2)})
        per = best / len(points) * 1e6
        print(f"{len(points):>10,d} points, {boxes:4d} boxes: {found:4d} instances, {best:6.1f} s ({per:.2f} s per M)")
    ratio = (rows[-1]["seconds"] / rows[-1]["points"]) / (rows[0]["seconds"] / rows[0]["points"])
    print(f"cost per point, largest hall / smallest: {ratio:.2f} (1.0 = linear)")
    print(json.dumps({"halls": rows, "per_point_ratio": round(ratio, 2)}))


if __name__ == "__main__":
    main()
