"""Peak memory of reading a long bag with `rosbag`, against the size of what the bag holds.

Writes, in a temporary folder, a 640 x 480 RGB-D bag (ROS 1 and ROS 2, raw images) and a LiDAR
bag of ``--frames`` frames each (a generated office's frames and sweeps repeated with new stamps),
then reads each in a fresh process: `rosbag`'s ``read()`` and every frame's depth (or every sweep's
points). Prints, per bag, its size on disk, the peak resident memory of the reading process and of
a process that only imports stratamap, and the ratio of the difference to the bag's size: a reader
that holds a bag's messages grows with the bag (a ratio near 1), one that reads them when used
does not (a ratio that falls as the bag grows). Last line: JSON.

    python benchmarks/bag_memory.py [--frames 300]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

READ = """
import sys
from stratamap.plugins.sources.rosbag import RosbagSource
if sys.argv[1] != "-":
    stream = RosbagSource(path=sys.argv[1], gravity="off").read()["frames"]
    if stream.lidar_scans:
        total = sum(len(s.points) for s in stream.lidar_scans)
    else:
        total = sum(float(f.depth.sum()) for f in stream.frames)
# VmHWM, not ru_maxrss: Linux keeps ru_maxrss across exec, so a child would report its parent's peak
print([int(line.split()[1]) / 1024 for line in open("/proc/self/status") if line.startswith("VmHWM")][0])
"""


def write_bags(folder: Path, frames: int) -> dict[str, Path]:
    from stratamap.core.io.rosbag import write_lidar_bag, write_rgbd_bag
    from stratamap.core.map.sensors import LidarScan
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld

    spec = SceneSpec.model_validate(
        {
            "type": "office",
            "seed": 1,
            "camera": {"width": 640, "height": 480},
            "trajectory": {"type": "walk", "frames": 10},
            "lidar": {"enabled": True},
        }
    )
    world = SyntheticWorld(spec)
    stream = world.stream()
    rendered = [world.frame(k)[0] for k in range(len(world))]
    long = replace(stream, frames=[replace(rendered[k % 10], timestamp=0.1 * k) for k in range(frames)])
    sweeps = world.lidar_scans
    swept = [LidarScan(0.1 * k, sweeps[k % 10].points, sweeps[k % 10].pose) for k in range(frames)]
    return {
        "rgbd_ros1": write_rgbd_bag(folder / "rgbd.bag", long, ros_version=1),
        "rgbd_ros2": write_rgbd_bag(folder / "rgbd", long, ros_version=2),
        "lidar_ros1": write_lidar_bag(folder / "lidar.bag", swept, ros_version=1),
    }


def peak_mb(bag: str) -> float:
    out = subprocess.run([sys.executable, "-c", READ, bag], check=True, capture_output=True, text=True).stdout
    return float(out.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=300, help="frames (and sweeps) per bag")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bags = write_bags(Path(tmp), args.frames)
        base = peak_mb("-")
        rows = {}
        for name, bag in bags.items():
            files = [bag] if bag.is_file() else list(bag.rglob("*"))
            size = sum(f.stat().st_size for f in files if f.is_file()) / 2**20
            peak = peak_mb(str(bag))
            rows[name] = {
                "bag_mb": round(size, 1),
                "peak_mb": round(peak, 1),
                "growth_per_bag_mb": (peak - base) / size,
            }
            print(
                f"{name:11s} bag {size:7.1f} MB  peak {peak:7.1f} MB  (import only {base:.0f} MB)  "
                f"growth / bag size {(peak - base) / size:.2f}"
            )
    print(json.dumps({"frames": args.frames, "import_peak_mb": round(base, 1), "bags": rows}))


if __name__ == "__main__":
    main()
