"""Throughput of the whole RGB-D pipeline against bare Open3D TSDF integration of the same frames.

On the same frames, held in memory (reading and rendering are not timed), side by side in one run:

(a) bare Open3D: VoxelBlockGrid integration of every frame plus point-cloud and mesh extraction;
(b) the `tsdf` mapper with panoptic fusion of labels made beforehand (oracle labels on the rendered
    walk, the detector's on a real recording; not timed);
(c) every stage of `configs/rgbd.yaml` after its source (detector, tsdf, clusters, completion,
    physics check, occupancy, exports) into a temporary folder.

Printed per input: frames per second of each, the ratios (b)/(a) and (c)/(a), and each one's peak
resident memory above what the process held before it (sampled; the frames themselves are held by
all three). Inputs: a rendered 640 x 480 office walk, and the real `tum_fr3_cabinet` recording from
`../shared/data/` when it is there. Last line: JSON.

    python benchmarks/pipeline_throughput.py [--frames 40] [--repeats 1] [--real ../shared/data/tum_fr3_cabinet]
"""

from __future__ import annotations

import argparse
import functools
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from stratamap.core.pipeline import MemorySampler, run_stages
from stratamap.core.stages import PipelineData

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "tum_fr3_cabinet"


def rendered_walk(frames: int) -> PipelineData:
    from stratamap.core.synthetic import SceneSpec, SyntheticWorld
    from stratamap.plugins.segmenters.oracle import OracleSegmenter

    spec = SceneSpec.model_validate(
        {"type": "office", "seed": 0, "trajectory": {"type": "walk", "frames": frames}, "noise": {"depth": "kinect"}}
    )
    world = SyntheticWorld(spec)
    stream = world.stream()
    stream.frames = list(stream.frames)
    data = PipelineData(stream=stream, ground_truth=world.ground_truth())
    data.ground_truth.frame_labels = list(data.ground_truth.frame_labels)
    labels = OracleSegmenter().run(data)["frame_labels"]
    data.ground_truth = None  # the pipeline runs as on a user's recording
    data.frame_labels = labels
    return data


def real_recording(path: Path, frames: int) -> PipelineData:
    from stratamap.core.config import load_pipeline

    validated = load_pipeline(ROOT / "configs" / "rgbd.yaml", [f"source.params.path={path}"])
    data = run_stages([validated.source.instantiate()])
    data.stream.frames = list(data.stream.frames)[:frames]
    data.ground_truth = None
    detector = validated.stages[0].instantiate()
    data.frame_labels = detector.run(data)["frame_labels"]
    return data


def pipeline_stages() -> list[Any]:
    """Every stage of configs/rgbd.yaml after its source, as configured there (the source is replaced,
    for validation only, by one that needs no files)."""
    from stratamap.core.config import load_pipeline

    validated = load_pipeline(ROOT / "configs" / "rgbd.yaml", ["source.plugin=synthetic", "source.params={}"])
    return [stage.instantiate() for stage in validated.stages]


def timed(function: Any) -> tuple[float, float]:
    """Seconds and peak memory (MB above the start) of ``function()``."""
    with MemorySampler(interval=0.02, release_every=None) as memory:
        start = time.perf_counter()
        function()
        seconds = time.perf_counter() - start
    return seconds, memory.peak_mb - memory.start_mb


def measure(name: str, data: PipelineData, repeats: int) -> dict[str, Any]:
    from mapping_throughput import bare_open3d  # beside this script

    from stratamap.plugins.mappers.tsdf import TSDFMapper

    stream = data.stream
    mapper = TSDFMapper(voxel_size=0.02)
    cfg = mapper.config
    n = len(stream.frames)

    def bare() -> None:
        bare_open3d(
            stream.frames,
            stream.intrinsics,
            cfg.voxel_size,
            cfg.depth_max,
            cfg.truncation_voxels,
            cfg.block_resolution,
            cfg.block_count,
        )

    def tsdf() -> None:
        mapper.run(PipelineData(stream=stream, frame_labels=data.frame_labels))

    def whole(stages: list[Any]) -> None:
        with tempfile.TemporaryDirectory() as out:
            run_stages(stages, PipelineData(stream=stream), Path(out))

    runs: dict[str, list[tuple[float, float]]] = {"open3d": [], "tsdf": [], "pipeline": []}
    for _ in range(repeats):  # alternate, so that all three see the same machine load
        runs["open3d"].append(timed(bare))
        runs["tsdf"].append(timed(tsdf))
        stages = pipeline_stages()  # read and checked outside the timing
        runs["pipeline"].append(timed(functools.partial(whole, stages)))
    best = {key: min(values) for key, values in runs.items()}
    fps = {key: n / seconds for key, (seconds, _) in best.items()}
    out = {
        "input": name,
        "frames": n,
        "fps": {key: round(value, 3) for key, value in fps.items()},
        "ratio_tsdf": round(fps["tsdf"] / fps["open3d"], 3),
        "ratio_pipeline": round(fps["pipeline"] / fps["open3d"], 3),
        "peak_mb": {key: round(max(m for _, m in values), 1) for key, values in runs.items()},
    }
    print(
        f"{name}: {n} frames; bare Open3D {fps['open3d']:.2f} frames/s, tsdf {fps['tsdf']:.2f} "
        f"({out['ratio_tsdf']:.2f}x), whole rgbd.yaml {fps['pipeline']:.2f} ({out['ratio_pipeline']:.2f}x); "
        f"peak MB {out['peak_mb']}"
    )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=40, help="frames of each input (the first ones)")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each, alternating; the best is kept")
    parser.add_argument("--real", type=Path, default=REAL, help="a real TUM-layout recording (skipped if absent)")
    args = parser.parse_args()
    results = [measure("rendered office walk", rendered_walk(args.frames), args.repeats)]
    if args.real.is_dir():
        results.append(measure(args.real.name, real_recording(args.real, args.frames), args.repeats))
    else:
        print(f"{args.real}: absent, real recording skipped")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
