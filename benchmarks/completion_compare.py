"""Head-to-head completion: none, bbox, icp_match and plane_box_match on the same synthetic scenes.

Each scene is generated, mapped once (oracle labels, panoptic TSDF, contact graph), then every
completer runs on a copy of the same map, so differences come from the completers alone.
Reports per completer: Chamfer-L1 (m, median over objects, and for chairs), F-score at 2 and
5 cm, yaw error, Scan2CAD accuracy and seconds per object. Last line: JSON.

    python benchmarks/completion_compare.py [--scenes 3] [--frames 80]
"""

from __future__ import annotations

import argparse
import copy
import json
import time

import numpy as np

from stratamap.core.evaluation.completion import evaluate_completion
from stratamap.core.pipeline import run_stages
from stratamap.core.stages import PipelineData
from stratamap.core.synthetic import SceneSpec, SyntheticWorld
from stratamap.plugins.completers.bbox import BBoxCompleter
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from stratamap.plugins.completers.plane_box_match import PlaneBoxMatchCompleter
from stratamap.plugins.mappers.contact_graph import ContactGraphMapper
from stratamap.plugins.mappers.tsdf import TSDFMapper
from stratamap.plugins.segmenters.oracle import OracleSegmenter

COMPLETERS = {
    "none": None,
    "bbox": BBoxCompleter,
    "icp_match": ICPMatchCompleter,
    "plane_box_match": PlaneBoxMatchCompleter,
}


def mapped_scene(seed: int, frames: int) -> PipelineData:
    spec = SceneSpec.model_validate(
        {"type": "office", "seed": seed, "trajectory": {"type": "walk", "frames": frames}, "noise": {"depth": "kinect"}}
    )
    world = SyntheticWorld(spec)
    data = PipelineData(stream=world.stream(), ground_truth=world.ground_truth())
    return run_stages([OracleSegmenter(), TSDFMapper(), ContactGraphMapper()], data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--frames", type=int, default=80)
    args = parser.parse_args()
    rows: dict[str, list[dict]] = {name: [] for name in COMPLETERS}
    seconds: dict[str, list[float]] = {name: [] for name in COMPLETERS}
    for seed in range(args.scenes):
        base = mapped_scene(100 + seed, args.frames)
        for name, cls in COMPLETERS.items():
            data = copy.copy(base)
            data.map = copy.copy(base.map)
            n = len(base.map.instances)
            t0 = time.perf_counter()
            if cls is not None:
                data.map.instances = cls().run(data)["instances"]
            seconds[name].append((time.perf_counter() - t0) / max(n, 1))
            res = evaluate_completion(data.map.instances, data.ground_truth.objects)
            rows[name].extend(res["per_object"])
    summary = {}
    for name, objs in rows.items():
        chairs = [o["chamfer_l1"] for o in objs if o["class"] == "chair"]
        yaw = [o["yaw_error_deg"] for o in objs if "yaw_error_deg" in o]
        s2c = [o["scan2cad"] for o in objs if "scan2cad" in o]
        summary[name] = {
            "objects": len(objs),
            "chamfer_l1": float(np.median([o["chamfer_l1"] for o in objs])),
            "chamfer_l1_chairs": float(np.median(chairs)) if chairs else None,
            "fscore_2cm": float(np.median([o["fscore_2cm"] for o in objs])),
            "fscore_5cm": float(np.median([o["fscore_5cm"] for o in objs])),
            "yaw_error_deg": float(np.median(yaw)) if yaw else None,
            "scan2cad_accuracy": float(np.mean(s2c)) if s2c else None,
            "seconds_per_object": float(np.mean(seconds[name])),
        }
    print(
        f"{'completer':16s} {'CD-L1 all':>10s} {'CD-L1 chair':>12s} {'F@2cm':>7s} {'F@5cm':>7s} {'yaw deg':>8s} "
        f"{'s/obj':>7s}"
    )
    for name, s in summary.items():

        def fmt(v, spec):
            return "-" if v is None else format(v, spec)

        print(
            f"{name:16s} {fmt(s['chamfer_l1'], '10.4f')} {fmt(s['chamfer_l1_chairs'], '12.4f')} "
            f"{fmt(s['fscore_2cm'], '7.3f')} "
            f"{fmt(s['fscore_5cm'], '7.3f')} {fmt(s['yaw_error_deg'], '8.2f')} {fmt(s['seconds_per_object'], '7.3f')}"
        )
    print(json.dumps({"scenes": args.scenes, "completers": summary}))


if __name__ == "__main__":
    main()
