"""Write a synthetic sequence to disk in standard formats (the TUM RGB-D layout plus ``gt/``).

::

    DIR/rgb/<t>.png            8-bit RGB
    DIR/depth/<t>.png          16-bit, 5000 units per metre (0 = no measurement)
    DIR/rgb.txt, depth.txt     "timestamp filename" per frame (TUM association files)
    DIR/groundtruth.txt        "timestamp tx ty tz qx qy qz qw": camera (optical) to world, true poses
    DIR/odometry.txt           the drifting reported poses (only when noise.pose_drift > 0)
    DIR/camera.json            width, height, fx, fy, cx, cy, depth_scale
    DIR/laser.txt              "timestamp x y z yaw angle_min angle_increment range_max r_0 ... r_n-1" (inf: no return)
    DIR/lidar/<t>.bin          KITTI layout: float32 x y z intensity, sensor frame (when the LiDAR is enabled)
    DIR/lidar_poses.txt        sensor-to-world poses of the sweeps, TUM format
    DIR/gt/class/<t>.png       16-bit class ids (stratamap vocabulary, listed in gt/scene.json)
    DIR/gt/instance/<t>.png    16-bit instance ids (0 = stuff)
    DIR/gt/trajectory.txt      the true camera poses again (for trajectory error when groundtruth.txt is withheld)
    DIR/gt/scene.json          spec, room layout, vocabulary, objects (id, class, family, model,
                               params, pose, parent, joints, part_boxes: each moving part's box
                               in the object frame, mesh)
    DIR/gt/meshes/<id>.ply     each object's full mesh in its object frame
    DIR/gt/contact_graph.json  node-link JSON of the support graph
    DIR/gt/occupancy_objects.{yaml,pgm}  obstacles in [z_min, robot_height] (Nav2 map files)
    DIR/gt/occupancy_laser.{yaml,pgm}    obstacles at the laser's height
    DIR/gt/occupancy_3d.npz    occupied (nz, ny, nx) bool, origin, resolution

The folder is written to a staging directory and swapped in whole, and every file is a pure
function of the spec: the same spec and seed give identical bytes.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from PIL import Image

from stratamap.core.atomic import atomic_directory, check_output_folder, write_json, write_text
from stratamap.core.geometry.transforms import matrix_to_quat_xyzw, yaw_of
from stratamap.core.io.nav2 import write_map
from stratamap.core.synthetic.generate import SyntheticWorld
from stratamap.core.synthetic.scene import part_boxes

DEPTH_SCALE = 5000.0


def _png(path: Path, array: np.ndarray) -> None:
    Image.fromarray(array).save(path, format="PNG", compress_level=1)


def tum_pose_line(t: float, pose: np.ndarray) -> str:
    q = matrix_to_quat_xyzw(pose[:3, :3])
    if q[3] < 0:  # one sign per rotation keeps files reproducible
        q = -q
    vals = [*pose[:3, 3], *q]
    return f"{t:.6f} " + " ".join(f"{v:.9f}" for v in vals)


def is_sequence(folder: Path) -> bool:
    """Whether ``folder`` holds a sequence this writer wrote (which it may replace)."""
    return (folder / "gt" / "scene.json").is_file() and (folder / "rgb.txt").is_file()


def write_sequence(world: SyntheticWorld, out: str | Path, progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``world`` into ``out``, replacing an earlier sequence there as a whole; a folder with
    anything else in it is refused (a ConfigError), never emptied."""
    out = check_output_folder(out, is_sequence, "synthetic sequence")
    n = len(world)
    with atomic_directory(out) as d:
        for sub in ("rgb", "depth", "gt/class", "gt/instance", "gt/meshes"):
            (d / sub).mkdir(parents=True, exist_ok=True)
        intr = world.intrinsics
        write_json(d / "camera.json", {**intr.to_dict(), "depth_scale": DEPTH_SCALE})
        stamps = [f"{world.timestamp(k):.6f}" for k in range(n)]
        with ThreadPoolExecutor(max_workers=2) as pool:
            jobs = []
            for k in range(n):
                frame, labels = world.frame(k)
                depth = np.clip(np.round(frame.depth.astype(np.float64) * DEPTH_SCALE), 0, 65535).astype(np.uint16)
                jobs += [
                    pool.submit(_png, d / "rgb" / f"{stamps[k]}.png", frame.rgb),
                    pool.submit(_png, d / "depth" / f"{stamps[k]}.png", depth),
                    pool.submit(_png, d / "gt" / "class" / f"{stamps[k]}.png", labels.class_ids.astype(np.uint16)),
                    pool.submit(
                        _png, d / "gt" / "instance" / f"{stamps[k]}.png", labels.instance_ids.astype(np.uint16)
                    ),
                ]
                if len(jobs) > 16:
                    for j in jobs:
                        j.result()
                    jobs = []
                if progress is not None:
                    progress(k + 1, n)
            for j in jobs:
                j.result()
        header = "# timestamp filename\n"
        write_text(d / "rgb.txt", "# color images\n" + header + "".join(f"{s} rgb/{s}.png\n" for s in stamps))
        write_text(d / "depth.txt", "# depth maps\n" + header + "".join(f"{s} depth/{s}.png\n" for s in stamps))
        gt_header = "# ground truth trajectory: camera (optical frame) to world\n# timestamp tx ty tz qx qy qz qw\n"
        trajectory = gt_header + "".join(
            tum_pose_line(world.timestamp(k), p) + "\n" for k, p in enumerate(world.true_poses)
        )
        write_text(d / "groundtruth.txt", trajectory)
        write_text(d / "gt" / "trajectory.txt", trajectory)  # kept when users drop groundtruth.txt to test odometry
        if world.spec.noise.pose_drift > 0:
            write_text(
                d / "odometry.txt",
                "# drifting reported poses\n# timestamp tx ty tz qx qy qz qw\n"
                + "".join(tum_pose_line(world.timestamp(k), p) + "\n" for k, p in enumerate(world.reported_poses)),
            )
        if world.laser_scans:
            lines = [
                "# 2D laser scans: timestamp x y z yaw angle_min angle_increment range_max ranges... (inf: no return)\n"
            ]
            for s in world.laser_scans:
                p = s.pose
                head = [s.timestamp, p[0, 3], p[1, 3], p[2, 3], yaw_of(p), s.angle_min, s.angle_increment, s.range_max]
                lines.append(
                    " ".join(f"{v:.6f}" for v in head)
                    + " "
                    + " ".join("inf" if not np.isfinite(r) else f"{r:.4f}" for r in s.ranges)
                    + "\n"
                )
            write_text(d / "laser.txt", "".join(lines))
        if world.lidar_scans:
            (d / "lidar").mkdir()
            for s in world.lidar_scans:
                cloud = np.zeros((len(s.points), 4), np.float32)
                cloud[:, :3] = s.points
                (d / "lidar" / f"{s.timestamp:.6f}.bin").write_bytes(cloud.tobytes())
            write_text(
                d / "lidar_poses.txt",
                "# timestamp tx ty tz qx qy qz qw (sensor to world)\n"
                + "".join(tum_pose_line(s.timestamp, s.pose) + "\n" for s in world.lidar_scans),
            )
        _write_ground_truth(world, d / "gt")
    return out


def _write_ground_truth(world: SyntheticWorld, gt_dir: Path) -> None:
    scene = world.scene
    objects = []
    for obj in scene.objects:
        mesh = obj.model.mesh()
        mesh.export(gt_dir / "meshes" / f"{obj.id}.ply", file_type="ply", encoding="binary")
        objects.append(
            {
                "id": obj.id,
                "class": obj.class_name,
                "family": obj.model.family,
                "model_id": obj.model.id,
                "params": obj.model.params,
                "pose": np.round(obj.pose, 12).tolist(),
                "parent": obj.parent,
                "joints": [j.to_dict() for j in obj.model.joints],
                "part_boxes": part_boxes(obj.model),
                "mesh": f"meshes/{obj.id}.ply",
            }
        )
    write_json(
        gt_dir / "scene.json",
        {
            "spec": world.spec.model_dump(mode="json"),
            "layout": scene.layout_info(),
            "vocabulary": world.vocabulary.to_dict(),
            "objects": objects,
            "skipped": scene.skipped,
        },
    )
    write_text(
        gt_dir / "contact_graph.json",
        json.dumps(scene.contact_graph().to_dict()["support"], indent=1, default=str) + "\n",
    )
    write_map(world.occupancy_band.project(), gt_dir, "occupancy_objects")
    write_map(world.occupancy_laser.project(), gt_dir, "occupancy_laser")
    occ = world.occupancy_band
    with open(gt_dir / "occupancy_3d.npz", "wb") as fh:
        np.savez_compressed(fh, occupied=occ.occupied, origin=occ.origin, resolution=np.array(occ.resolution))
