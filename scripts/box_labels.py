"""Write a ground-truth ``gt/`` folder from a hand-made box list, so that a real recording without
labels can be scored like a synthetic one (``report.json``'s ``detection`` and ``furniture``
families, ``stratamap bench``).

A box list is a JSON file::

    {"recording": "../shared/data/slambook_dining",
     "frame": "aligned",                        # or "recording"
     "world_transform": [[...4x4...]],          # recording world -> aligned world (with "aligned")
     "boxes": [{"name": "dining_table", "class": "table",
                "center": [x, y, z], "size": [sx, sy, sz], "yaw": 0.3}, ...]}

Boxes are gravity-aligned (yaw about the up axis) in the frame they were drawn in. "aligned" is
the z-up, floor-at-0 world a run's source re-aligns to (``report.json``: ``notes.<source>.
gravity_alignment.transform``): the labeller draws there, and this script stores each box's pose in
the recording's own world, which the source re-aligns again at run time however the floor fit
turns out. Each object gets a box mesh. The folder is read with the ``tum`` source's
``ground_truth_path``::

    python scripts/box_labels.py benchmarks/real_rooms/slambook_dining/boxes.json \\
        --out benchmarks/real_rooms/slambook_dining/gt
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def box_pose(center: list[float], yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    pose = np.eye(4)
    pose[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    pose[:3, 3] = center
    return pose


def write_gt(labels: dict, out: Path, source: Path) -> int:
    import trimesh

    frame = labels.get("frame", "recording")
    if frame not in ("aligned", "recording"):
        _fail(f"{source}: frame must be 'aligned' or 'recording', got {frame!r}")
    to_recording = np.eye(4)
    if frame == "aligned":
        try:
            transform = np.array(labels["world_transform"], float)
        except (KeyError, TypeError, ValueError):
            _fail(f"{source}: world_transform must be a 4x4 matrix when frame is 'aligned'")
        if transform.shape != (4, 4):
            _fail(f"{source}: world_transform must be a 4x4 matrix, got shape {transform.shape}")
        to_recording = np.linalg.inv(transform)
    objects = []
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    for n, box in enumerate(labels.get("boxes", []), start=1):
        try:
            size = np.array(box["size"], float).reshape(3)
            pose = to_recording @ box_pose(list(map(float, box["center"])), float(box["yaw"]))
            name, cls = str(box["name"]), str(box["class"])
        except (KeyError, TypeError, ValueError) as exc:
            _fail(f"{source}: boxes[{n - 1}] needs name, class, center [x, y, z], size [sx, sy, sz] and yaw ({exc})")
        mesh_file = f"meshes/{name}.ply"
        trimesh.creation.box(extents=size).export(out / mesh_file)
        objects.append(
            {
                "id": n,
                "class": cls,
                "mesh": mesh_file,
                "pose": np.round(pose, 9).tolist(),
                "parent": box.get("parent", "floor"),
                "params": {"name": name, "size_m": size.round(4).tolist(), **box.get("params", {})},
            }
        )
    scene = {"note": labels.get("note", f"box labels from {source.name}"), "objects": objects, "layout": {}}
    (out / "scene.json").write_text(json.dumps(scene, indent=1) + "\n", encoding="utf-8")
    return len(objects)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("boxes", type=Path, help="the box list (JSON)")
    parser.add_argument("--out", type=Path, required=True, help="the gt/ folder to write")
    args = parser.parse_args()
    try:
        labels = json.loads(args.boxes.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        _fail(f"{args.boxes}: cannot be read as JSON ({exc})")
    if not isinstance(labels, dict) or not isinstance(labels.get("boxes"), list):
        _fail(f"{args.boxes}: expected an object with a 'boxes' list")
    n = write_gt(labels, args.out, args.boxes)
    print(f"{args.out}: {n} objects")


if __name__ == "__main__":
    main()
