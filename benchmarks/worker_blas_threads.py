"""Worker processes with a share of the cores for their BLAS threads, against one thread per core each.

Runs one small benchmark (synthetic offices through `tsdf`, `clusters`, `contact_graph` and `bbox`)
with `stratamap bench --workers W`, alternately:
- **per core**: every worker's OpenBLAS on one thread per core, as before
  (`OPENBLAS_NUM_THREADS` set to the core count, which the workers inherit);
- **shared**: the default since 2026-11-29: the variables unset, so each worker gets
  `cores // W` threads (`stratamap.core.parallel.worker_blas_threads`).

Both modes run `--rounds` times, interleaved, in this one process; the figures are medians. It
prints wall time and the workers' CPU time per mode and their ratios. Last line: JSON.

    python benchmarks/worker_blas_threads.py [--workers 2] [--seeds 4] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

import yaml

from stratamap.core.evaluation.bench import run_bench
from stratamap.core.parallel import BLAS_THREAD_VARIABLES

REPO = Path(__file__).resolve().parent.parent


def bench_file(folder: Path, seeds: int, frames: int) -> Path:
    doc = {
        "name": "worker_blas_threads",
        "scenes": [
            {
                "synthetic": {
                    "scene_file": str(REPO / "configs/scenes/office.yaml"),
                    "seeds": list(range(seeds)),
                    "frames": frames,
                    "camera": {"width": 320, "height": 240},
                }
            }
        ],
        "pipeline": {
            "stages": [
                {"plugin": "oracle"},
                {"plugin": "tsdf", "params": {"voxel_size": 0.03}},
                {"plugin": "clusters"},
                {"plugin": "contact_graph"},
                {"plugin": "bbox"},
            ]
        },
        "variants": [{"name": "clusters"}],
    }
    path = folder / "bench.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_once(spec: Path, out: Path, workers: int, per_core: bool) -> tuple[float, float]:
    """(wall seconds, the workers' CPU seconds) of one whole benchmark run."""
    saved = {k: os.environ.pop(k) for k in BLAS_THREAD_VARIABLES if k in os.environ}
    if per_core:
        os.environ["OPENBLAS_NUM_THREADS"] = str(os.cpu_count() or 1)
    try:
        cpu0, t0 = children_cpu(), time.perf_counter()
        run_bench(spec, out, workers=workers, progress=False)
        return time.perf_counter() - t0, children_cpu() - cpu0
    finally:
        os.environ.pop("OPENBLAS_NUM_THREADS", None)
        os.environ.update(saved)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seeds", type=int, default=4, help="Scenes per run (office seeds 0..N-1).")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=2, help="Runs per mode, interleaved.")
    args = parser.parse_args()
    times: dict[str, list[tuple[float, float]]] = {"per core": [], "shared": []}
    with tempfile.TemporaryDirectory() as tmp:
        spec = bench_file(Path(tmp), args.seeds, args.frames)
        for r in range(args.rounds):
            for mode in ("per core", "shared"):
                out = Path(tmp) / f"{mode.replace(' ', '_')}_{r}"  # a fresh folder: every scene runs
                wall, cpu = run_once(spec, out, args.workers, per_core=mode == "per core")
                times[mode].append((wall, cpu))
                print(f"round {r + 1} {mode:>8}: {wall:6.1f} s wall, {cpu:6.1f} s CPU in the workers")
    med = {m: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for m, v in times.items()}
    wall_ratio = med["shared"][0] / med["per core"][0]
    cpu_ratio = med["shared"][1] / med["per core"][1]
    cores = os.cpu_count()
    print(f"{cores} cores, {args.workers} workers, {args.seeds} scenes x {args.frames} frames, {args.rounds} rounds")
    print(f"shared / per core: wall {wall_ratio:.2f}, CPU {cpu_ratio:.2f}")
    result = {
        "cores": cores,
        "workers": args.workers,
        "wall_ratio": round(wall_ratio, 3),
        "cpu_ratio": round(cpu_ratio, 3),
    }
    result["median_seconds"] = {m: {"wall": round(w, 2), "cpu": round(c, 2)} for m, (w, c) in med.items()}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
