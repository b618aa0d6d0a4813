"""How completion cost grows with the model library, with and without the descriptor shortlist.

Maps two synthetic offices once (oracle labels), takes their chairs, and matches the same chairs
with `icp_match` against procedural libraries of 10, 100 and 1,000 models (families in turn),
with the shortlist (top 20 by global descriptor) and exhaustively. Reports seconds per object,
top-1 accuracy (the chosen model's family is the ground truth's) and median Chamfer-L1 of the
completed shapes. Target: with the shortlist, 1,000 models cost <= 1 s per object and lose no
more than 2 points of top-1 accuracy against the exhaustive search. Last line: JSON.

    python benchmarks/completion_scaling.py [--sizes 10 100 1000]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from stratamap.core.evaluation.completion import evaluate_completion
from stratamap.core.library.models import ModelLibrary, model_to_library
from stratamap.core.map.layers import ObjectInstances
from stratamap.core.synthetic.models import FAMILIES, make_model
from stratamap.plugins.completers._matching import register_library
from stratamap.plugins.completers.icp_match import ICPMatchCompleter

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run as a script or with -m
from benchmarks.completion_compare import mapped_scene  # noqa: E402


def library_of(size: int, seed: int = 5000) -> ModelLibrary:
    families = list(FAMILIES)
    return ModelLibrary(
        [model_to_library(make_model(families[k % len(families)], seed, k // len(families))) for k in range(size)]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000])
    parser.add_argument("--frames", type=int, default=80)
    args = parser.parse_args()
    scenes = [mapped_scene(200 + k, args.frames) for k in range(2)]
    result = {
        "sizes": args.sizes,
        "s_per_object_shortlist": [],
        "s_per_object_exhaustive": [],
        "top1_shortlist": [],
        "top1_exhaustive": [],
        "chamfer_shortlist": [],
        "chamfer_exhaustive": [],
    }
    for size in args.sizes:
        name = register_library(f"bench-{size}", library_of(size))
        for mode, k in (("shortlist", 20), ("exhaustive", None)):
            completer = ICPMatchCompleter(library=name, classes=["chair"], shortlist=k, workers=1)
            seconds, rows = [], []
            for data in scenes:
                n = sum(1 for i in data.map.instances if i.class_name == "chair")
                t0 = time.perf_counter()
                insts: ObjectInstances = completer.run(data)["instances"]
                seconds.append((time.perf_counter() - t0) / max(n, 1))
                rows += [
                    r
                    for r in evaluate_completion(insts, data.ground_truth.objects)["per_object"]
                    if r["class"] == "chair"
                ]
            top1 = float(np.mean([bool(r.get("same_family")) for r in rows])) if rows else 0.0
            chamfer = float(np.median([r["chamfer_l1"] for r in rows])) if rows else None
            result[f"s_per_object_{mode}"].append(round(float(np.mean(seconds)), 4))
            result[f"top1_{mode}"].append(round(top1, 4))
            result[f"chamfer_{mode}"].append(None if chamfer is None else round(chamfer, 4))
            print(
                f"{size:5d} models, {mode:10s}: {np.mean(seconds):7.3f} s/object, top-1 {top1:.3f}, Chamfer-L1 "
                f"{chamfer:.4f} "
                f"m ({len(rows)} chairs)"
            )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
