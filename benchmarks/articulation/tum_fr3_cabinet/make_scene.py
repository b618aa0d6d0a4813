"""The articulation ground truth of the real TUM fr3/cabinet recording (scene.json beside this file),
made from hand measurements on the recording's fused geometry and colour frames (README.md).

The cabinet's box is fitted here to the fused map's points (the `tsdf` stage at 1 cm on the `tum`
source, which levels the recording: its report's ``notes.tum.gravity_alignment.transform``): yaw by
the least-area footprint, sides and top at the 1st/99th percentiles, the bottom on the floor
(z = 0). The drawers were measured on the face in a provisional frame (``PROVISIONAL``, the levelled
world); their world positions are carried into the fitted box's frame. ``scene.json`` stores the
pose in the recording's own world (the source levels it again on reading).

    stratamap run GEOMETRY.yaml --out RUN    # source: tum on the recording; stages: tsdf (voxel_size 0.01)
    python benchmarks/articulation/tum_fr3_cabinet/make_scene.py RUN
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: The frame the drawers were measured in (object-to-world in the levelled world: origin at the
#: bottom centre of the face's unit, +z up, the drawer fronts toward -y).
PROVISIONAL = np.array(
    [
        [0.03926255906222202, -0.999228928452277, 0.0, -1.52988],
        [0.999228928452277, 0.03926255906222202, 0.0, 0.456476],
        [0.0, 0.0, 1.0, 0.00886600000000004],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
#: Per drawer (bottom first): its front's x range and z range in PROVISIONAL (README.md's table).
DRAWERS = [
    ((-0.217, 0.214), (0.012, 0.194)),
    ((-0.217, 0.214), (0.194, 0.343)),
    ((-0.217, 0.214), (0.343, 0.491)),
    ((-0.217, 0.214), (0.491, 0.545)),
]
#: The drawer face in PROVISIONAL (the fused face plane, y).
FACE_Y = -0.411
#: Assumed, not measured (no drawer is opened in the recording): a drawer's depth and its travel,
#: as shares of the cabinet's depth.
DRAWER_DEPTH, TRAVEL = 0.9, 0.8


def fit_box(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(levelled-world pose of the fitted box, its size, the source's levelling transform)."""
    from stratamap.core.map.format import read_layers

    report = json.loads((run / "report.json").read_text())
    level = np.array(report["notes"]["tum"]["gravity_alignment"]["transform"])
    m = read_layers(json.loads((run / "map/manifest.json").read_text()), run / "map")
    pts = np.asarray(m.geometry.points, float)
    local = (pts - PROVISIONAL[:3, 3]) @ PROVISIONAL[:3, :3]
    near = (np.abs(local[:, 0]) < 0.25) & (local[:, 1] > -0.43) & (local[:, 1] < 0.41)
    near &= (pts[:, 2] > 0.03) & (pts[:, 2] < 0.57)
    xy, top = pts[near, :2], float(np.percentile(pts[near, 2], 99.5))
    best = None
    for yaw in np.radians(np.arange(0.0, 90.0, 0.25)):
        c, s = np.cos(yaw), np.sin(yaw)
        u, v = xy @ np.array([c, s]), xy @ np.array([-s, c])
        lo = np.percentile(u, 1), np.percentile(v, 1)
        hi = np.percentile(u, 99), np.percentile(v, 99)
        area = (hi[0] - lo[0]) * (hi[1] - lo[1])
        if best is None or area < best[0]:
            best = (area, yaw, lo, hi)
    _, yaw, lo, hi = best
    c, s = np.cos(yaw), np.sin(yaw)
    axes = np.array([[c, -s], [s, c]])  # columns: the box's u and v in the world
    centre = axes @ np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2])
    size = np.array([hi[0] - lo[0], hi[1] - lo[1], top])
    # The box's axes as the object frame's x (across the face) and y (into it, the face at -y).
    face_dir = PROVISIONAL[:3, 1]  # +y of the provisional frame: from the face into the cabinet
    rot = np.eye(3)
    rot[:2, :2] = axes
    k = int(np.argmax(np.abs(rot.T @ face_dir)))
    y_axis = rot[:, k] * np.sign(rot[:, k] @ face_dir)
    x_axis = np.cross(y_axis, [0.0, 0.0, 1.0])
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = x_axis, y_axis, [0.0, 0.0, 1.0]
    pose[:2, 3] = centre
    sizes = np.array([size[1 - k], size[k], size[2]])  # along x (across the face), y (depth), z
    return pose, sizes, level


def main(run: Path) -> None:
    import trimesh

    pose, size, level = fit_box(run)
    to_box = np.linalg.inv(pose) @ PROVISIONAL
    half_depth = size[1] / 2
    joints, part_boxes = [], {}
    for k, ((x0, x1), (z0, z1)) in enumerate(DRAWERS):
        corners = np.array([[x, FACE_Y, z, 1.0] for x in (x0, x1) for z in (z0, z1)]) @ to_box.T
        bx0, bx1 = corners[:, 0].min(), corners[:, 0].max()
        bz0, bz1 = corners[:, 2].min(), corners[:, 2].max()
        face = -half_depth
        origin = np.eye(4)
        origin[:3, 3] = [(bx0 + bx1) / 2, face, (bz0 + bz1) / 2]
        joints.append(
            {
                "name": f"drawer_{k}_slide",
                "type": "prismatic",
                "parent": "body",
                "child": f"drawer_{k}",
                "origin": np.round(origin, 4).tolist(),
                "axis": [0.0, -1.0, 0.0],
                "lower": 0.0,
                "upper": round(TRAVEL * size[1], 4),
            }
        )
        part_boxes[f"drawer_{k}"] = [
            [round(bx0, 4), round(face, 4), round(bz0, 4)],
            [round(bx1, 4), round(face + DRAWER_DEPTH * size[1], 4), round(bz1, 4)],
        ]
    box = trimesh.creation.box(extents=size)
    box.apply_translation([0.0, 0.0, size[2] / 2])  # origin at the bottom centre
    (HERE / "meshes").mkdir(exist_ok=True)
    box.export(HERE / "meshes" / "cabinet_box.ply")
    scene = {
        "note": (
            "TUM RGB-D fr3/cabinet (CC BY 4.0): the 4-drawer rolling cabinet and its drawers as prismatic "
            "joints, measured by hand on 2026-12-06 (README.md; make_scene.py makes this file). The box is fitted "
            "to the fused map; drawer depth and travel are assumed."
        ),
        "objects": [
            {
                "id": 1,
                "class": "cabinet",
                "mesh": "meshes/cabinet_box.ply",
                "pose": np.round(np.linalg.inv(level) @ pose, 9).tolist(),
                "parent": "floor",
                "params": {"size_m": np.round(size, 4).tolist(), "drawers": len(DRAWERS)},
                "joints": joints,
                "part_boxes": part_boxes,
            }
        ],
        "layout": {"floor_z": 0.0},
    }
    (HERE / "scene.json").write_text(json.dumps(scene, indent=1) + "\n")
    print("box size", np.round(size, 3), "wrote", HERE / "scene.json")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a stratamap run of the recording with the tsdf stage (1 cm)")
    main(parser.parse_args().run)
