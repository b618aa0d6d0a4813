"""How fast the synthetic generator writes a sequence to disk.

Generates a 300-frame office sequence at 640x480 (walk trajectory, Kinect noise, 2D laser,
ground-truth occupancy) with `write_sequence`, the code behind `stratamap synth`, and reports
the time of each phase. The target is under 2 minutes on 2 cores. Last line: JSON.

    python benchmarks/synth_speed.py [--frames 300] [--scene configs/scenes/office.yaml]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.core.synthetic.writer import write_sequence

REPO = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--scene", type=Path, default=REPO / "configs" / "scenes" / "office.yaml")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    spec = SceneSpec.from_yaml(args.scene)
    spec = spec.model_copy(
        update={"seed": args.seed, "trajectory": spec.trajectory.model_copy(update={"frames": args.frames})}
    )

    t0 = time.perf_counter()
    world = SyntheticWorld(spec)
    t_scene = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        write_sequence(world, Path(tmp) / "seq")
        t_write = time.perf_counter() - t1
    total = time.perf_counter() - t0
    result = {
        "scene": spec.type,
        "frames": args.frames,
        "width": spec.camera.width,
        "height": spec.camera.height,
        "objects": len(world.scene.objects),
        "seconds_scene": round(t_scene, 2),
        "seconds_render_and_write": round(t_write, 2),
        "seconds_total": round(total, 2),
        "frames_per_second": round(args.frames / total, 2),
        "target_seconds": 120,
        "within_target": total < 120,
    }
    print(f"{args.frames} frames of a {spec.type} at {spec.camera.width}x{spec.camera.height}: {total:.1f} s total")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
