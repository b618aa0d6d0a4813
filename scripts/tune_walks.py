"""Score the late stages of a benchmark variant on many walks in seconds: the early stages' result
(source, segmenter, TSDF) is computed once per walk and cached; every later run loads it and runs only
the rest (for issue 28: `clusters` recognition and `icp_match` after the detector and `tsdf`).

    python scripts/export_training_library.py           # the tuning kitchen's library, once
    python scripts/tune_walks.py prefix configs/bench/generalization_tuning.yaml --workers 2
    python scripts/tune_walks.py score configs/bench/generalization_tuning.yaml --workers 2
    python scripts/tune_walks.py score configs/bench/generalization_tuning.yaml --scenes office_tune-s2 --objects

`frames` runs only the source and the variant's segmenter (no cache, no TSDF) and prints how its
per-frame labels fall on the ground truth's: per true class, the share of its pixels given each class,
summed over the tuning walks chosen (a change to a per-frame segmenter, such as the detector's depth
segmentation, is read in a minute or two, before a `prefix` of every walk):

    python scripts/tune_walks.py frames configs/bench/generalization_tuning.yaml --scenes office_tune-s1 office_tune-s3

`score` prints, per tuning walk, detection F1 at 3D box IoU >= 0.25 (class-aware, class-agnostic) and
map PQ, then the means of the tuning walks and of the validation walks (seeds --validation-seeds, 4-7
by default) apart, and what the tuning walks' true objects were called (the benchmark report's table,
summed over the tuning walks); `--objects` adds each instance of a tuning walk with the ground-truth
object its box overlaps most. A validation walk is printed only in its group's mean. The cache holds
the prefix as it was computed: after a change to a prefix stage's code, run `prefix --rebuild`. A
development tool: reported figures come from `stratamap bench`, which runs every stage.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import re
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from stratamap.core.errors import StratamapError
from stratamap.core.evaluation import bench


def load(bench_file: Path, variant: str) -> tuple[bench.BenchSpec, list[dict[str, Any]], bench.Variant]:
    spec, path = bench.load_bench(bench_file)
    scenes, skipped = bench.expand_scenes(spec, path)
    for note in skipped:
        print(f"note: {note}", file=sys.stderr)
    chosen = next((v for v in spec.variants if v.name == variant), None)
    if chosen is None:
        raise StratamapError(f"{bench_file}: no variant {variant!r} (variants: {[v.name for v in spec.variants]})")
    return spec, scenes, chosen


def pipeline(spec: bench.BenchSpec, variant: bench.Variant, scene: dict[str, Any], cache: Path) -> Any:
    """The walk's pipeline, writing what its stages write under ``cache``/runs/<walk>."""
    from stratamap.core.config import validate
    from stratamap.core.pipeline import Pipeline

    pipe = Pipeline(validate(bench.variant_document(spec, variant, scene["source"]), origin="tune_walks"))
    pipe.records = []
    pipe.out_dir = cache / "runs" / bench.safe(scene["name"])
    return pipe


def run_source(pipe: Any) -> Any:
    """A PipelineData holding what the walk's source gives (deterministic: rendered or read again)."""
    from stratamap.core.stages import PipelineData

    data = PipelineData()
    pipe._run_stage(pipe.validated.source, -1, data)
    return data


def cache_file(cache: Path, scene: dict[str, Any], spec: bench.BenchSpec, variant: bench.Variant, stages: int) -> Path:
    """The walk's cache file, named by the walk and a digest of its source and prefix stages' settings."""
    doc = bench.variant_document(spec, variant, scene["source"])
    key = json.dumps([doc["source"], doc["stages"][:stages]], sort_keys=True, default=str)
    return cache / f"{bench.safe(scene['name'])}-{hashlib.sha256(key.encode()).hexdigest()[:10]}.pkl"


def light_stream(stream: Any) -> Any:
    """The stream without its colour images and without the depth images of frames no stage reads,
    which are the bulk of it: the late stages read the map, and of the stream its metadata, where
    each frame was taken (clusters turns its normals to the cameras and takes the floor where the
    source found it) and the depth of the frames that give clusters its rays (``clusters.sightlines``)."""
    import dataclasses

    from stratamap.core.map.sensors import RGBDFrame
    from stratamap.plugins.segmenters.clusters.sightlines import ray_frames

    if stream is None:
        return None
    world = getattr(stream.frames, "world", None)  # a synthetic walk: its poses without rendering
    if world is not None:
        poses = [np.asarray(pose).copy() for pose in world.reported_poses]
    else:
        poses = [None if f.pose is None else np.asarray(f.pose).copy() for f in stream.frames]
    rgb, no_depth = np.zeros((1, 1, 3), np.uint8), np.zeros((1, 1), np.float32)
    rays = set(ray_frames(len(poses)).tolist()) if stream.intrinsics is not None else set()
    frames = [
        RGBDFrame(k, 0.0, rgb, np.asarray(stream.frames[k].depth).copy() if k in rays else no_depth, pose)
        for k, pose in enumerate(poses)
    ]
    return dataclasses.replace(stream, frames=frames)


def holds_rays(stream: Any) -> bool:
    """Whether a cached stream kept the depth of its ray frames (caches written before it did not)."""
    return stream is not None and any(np.asarray(f.depth).size > 1 for f in stream.frames)


def run_prefix(job: tuple[Path, str, dict[str, Any], int, Path, bool]) -> str:
    bench_file, variant_name, scene, stages, cache, rebuild = job
    spec, _, variant = load(bench_file, variant_name)
    target = cache_file(cache, scene, spec, variant, stages)
    if target.exists() and not rebuild:
        return f"{scene['name']}: cached"
    pipe = pipeline(spec, variant, scene, cache)
    data = run_source(pipe)
    for i in range(stages):
        pipe._run_stage(pipe.validated.stages[i], i, data)
    data.stream = light_stream(data.stream)
    tmp = target.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(data, fh)
    tmp.replace(target)
    return f"{scene['name']}: {sum(r.seconds for r in pipe.records):.0f} s"


def run_rest(job: tuple[Path, str, dict[str, Any], int, Path, bool]) -> dict[str, Any]:
    from stratamap.core.geometry.boxes import box_iou_3d
    from stratamap.core.map.instances import naming_text

    bench_file, variant_name, scene, stages, cache, objects = job
    spec, _, variant = load(bench_file, variant_name)
    source = cache_file(cache, scene, spec, variant, stages)
    if not source.exists():
        return {"scene": scene["name"], "missing": str(source)}
    with open(source, "rb") as fh:
        data = pickle.load(fh)
    pipe = pipeline(spec, variant, scene, cache)
    # A cache written before it kept the ray frames' depth: the source (deterministic, its frames
    # rendered or read when used) gives its stream back for clusters' sightlines.
    if not holds_rays(data.stream):
        data.stream = run_source(pipe).stream
    for i in range(stages, len(pipe.validated.stages)):
        pipe._run_stage(pipe.validated.stages[i], i, data)
    data.map.vocabulary = data.ground_truth.vocabulary
    metrics, details = bench.measure(pipe.hook, data, spec, pipe.out_dir)  # as `stratamap bench` measures a run
    row: dict[str, Any] = {
        "scene": scene["name"],
        "aware": metrics["detection"]["f1_iou25"],
        "agnostic": metrics["detection"]["f1_iou25_agnostic"],
        "pq": metrics.get("panoptic", {}).get("pq", float("nan")),
        "labels": details.get("labels_iou25"),
    }
    if objects:
        truth = list(data.ground_truth.objects)
        lines = []
        for inst in data.map.instances:
            overlap = max(((box_iou_3d(inst.box, o.box()), k) for k, o in enumerate(truth)), default=(0.0, -1))
            size = np.round(np.asarray(inst.box.size), 2).tolist()
            foot = float(inst.points[:, 2].min())
            matched = f"#{overlap[1]} {truth[overlap[1]].class_name}" if overlap[1] >= 0 else "-"
            seen = f"foot {foot:.2f} {len(inst.points)} pts"
            lines.append(
                f"  {inst.class_name:10s} {size} {seen} -> {matched} IoU {overlap[0]:.2f} ({naming_text(inst)})"
            )
        lines += [
            f"  truth #{k} {o.class_name:10s} {np.round(np.asarray(o.box().size), 2).tolist()}"
            for k, o in enumerate(truth)
        ]
        row["objects"] = lines
    return row


def run_frames(job: tuple[Path, str, dict[str, Any], int, Path, bool]) -> dict[str, Any]:
    """The walk's per-frame confusion: pixels of each true class (rows) given each class (columns) by the
    variant's first stage, a segmenter of frames."""

    bench_file, variant_name, scene, _, cache, _ = job
    spec, _, variant = load(bench_file, variant_name)
    pipe = pipeline(spec, variant, scene, cache)
    data = run_source(pipe)
    if data.ground_truth is None or not data.ground_truth.frame_labels:
        return {"scene": scene["name"], "error": "its source gives no per-frame ground truth"}
    try:
        pipe._run_stage(pipe.validated.stages[0], 0, data)
    except StratamapError as err:
        return {"scene": scene["name"], "error": str(err)}
    if data.frame_labels is None:
        return {"scene": scene["name"], "error": f"{pipe.validated.stages[0].plugin!r} labels no frames"}
    vocab = data.ground_truth.vocabulary
    n = len(vocab.names)
    truth = {f.frame_index: np.asarray(f.class_ids, np.int64) for f in data.ground_truth.frame_labels}
    confusion = np.zeros((n, n), np.int64)
    for frame in data.frame_labels.frames:
        given = np.asarray(frame.class_ids, np.int64)
        true = truth[frame.frame_index]
        confusion += np.bincount((true * n + given).ravel(), minlength=n * n).reshape(n, n)
    return {"scene": scene["name"], "confusion": confusion, "names": list(vocab.names), "things": vocab.is_thing}


def confusion_lines(confusion: np.ndarray, names: list[str], things: Any, top: int = 5) -> list[str]:
    """Per true thing class with pixels: its pixel count and the ``top`` classes given them, by share."""
    lines = []
    for k in np.flatnonzero(np.asarray(things, bool) & (confusion.sum(1) > 0)):
        row = confusion[k] / confusion[k].sum()
        given = [f"{names[j] if j else '(none)'} {row[j]:.3f}" for j in np.argsort(-row)[:top] if row[j] >= 0.005]
        lines.append(f"{names[k]:10s} {int(confusion[k].sum()):>10d} px: " + ", ".join(given))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "command",
        choices=["prefix", "score", "frames"],
        help="prefix: cache the early stages; score: run the rest; frames: the segmenter's per-frame labels.",
    )
    parser.add_argument("bench", type=Path, help="Benchmark file (configs/bench/*.yaml).")
    parser.add_argument("--variant", default="detector", help="The variant whose stages run (default: detector).")
    parser.add_argument("--stages", type=int, default=2, help="How many leading stages the cache holds (default 2).")
    parser.add_argument("--cache", type=Path, default=Path("out/tune_walks"), help="Cache folder.")
    parser.add_argument("--scenes", nargs="*", default=None, help="Only these walks (names as `bench` prints them).")
    parser.add_argument("--workers", type=int, default=1, help="Walks run side by side.")
    parser.add_argument("--rebuild", action="store_true", help="prefix: recompute cached walks too.")
    parser.add_argument("--objects", action="store_true", help="score: print each instance and its ground truth.")
    parser.add_argument(
        "--validation-seeds",
        type=int,
        nargs="*",
        default=[4, 5, 6, 7],
        help="Walks of these seeds are validation walks (default 4-7); the rest are tuning walks.",
    )
    args = parser.parse_args(argv)
    try:
        spec, scenes, variant = load(args.bench, args.variant)
        if not 0 < args.stages < len(bench.variant_document(spec, variant, {})["stages"]):
            raise StratamapError(f"--stages {args.stages}: the variant {args.variant!r} needs a stage after the cache")
    except StratamapError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.scenes:
        unknown = sorted(set(args.scenes) - {s["name"] for s in scenes})
        if unknown:
            print(f"error: --scenes {unknown}: not walks of {args.bench}", file=sys.stderr)
            return 2
        scenes = [s for s in scenes if s["name"] in args.scenes]
    left_out = 0
    if args.command == "frames":  # the validation walks are read as means only
        tuning = [s for s in scenes if not is_validation(s["name"], args.validation_seeds)]
        left_out = len(scenes) - len(tuning)
        if not tuning:
            print(f"error: the {left_out} walks chosen are all validation walks (read as means only)", file=sys.stderr)
            return 2
        scenes = tuning
    args.cache.mkdir(parents=True, exist_ok=True)

    def flag(scene: dict[str, Any]) -> bool:
        if args.command == "prefix":
            return args.rebuild
        # Per-object lines only for tuning walks: the validation walks are read as means only.
        return args.objects and not is_validation(scene["name"], args.validation_seeds)

    jobs = [(args.bench, args.variant, s, args.stages, args.cache, flag(s)) for s in scenes]
    work = {"prefix": run_prefix, "score": run_rest, "frames": run_frames}[args.command]
    if args.workers <= 1:
        results = [work(job) for job in jobs]
    else:
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            results = list(pool.map(work, jobs))
    if args.command == "prefix":
        print("\n".join(results))
        return 0
    if args.command == "frames":
        return print_frames(results, left_out)
    missing = [r["scene"] for r in results if "missing" in r]
    if missing:
        print(f"error: no cached prefix for {missing}: run `prefix` first", file=sys.stderr)
        return 2
    groups: dict[str, list[dict[str, Any]]] = {"tuning": [], "validation": []}
    for row in results:
        group = "validation" if is_validation(row["scene"], args.validation_seeds) else "tuning"
        groups[group].append(row)
        if group == "validation":
            continue
        print(f"{row['scene']:32s} {row['aware']:.3f} {row['agnostic']:.3f} {row['pq']:.3f}")
        for line in row.get("objects", []):
            print(line)
    for name, rows in groups.items():
        if rows:
            a = np.array([[r["aware"], r["agnostic"], r["pq"]] for r in rows])
            label = f"{name} mean of {len(rows)}"
            print(f"{label:32s} {a[:, 0].mean():.3f} {a[:, 1].mean():.3f} {np.nanmean(a[:, 2]):.3f}")
    if groups["validation"]:
        print(f"({len(groups['validation'])} validation walks: read as their mean only)")
    # Where the tuning walks lose class-aware F1 (the validation walks are read as means only).
    print("tuning walks, what the true objects were called (3D box IoU >= 0.25):")
    for line in called_lines([r["labels"] for r in groups["tuning"] if r.get("labels")]):
        print(f"  {line}")
    return 0


def is_validation(scene: str, validation_seeds: list[int]) -> bool:
    """Whether a walk (named ``...-s<seed>``) is a validation walk."""
    seed = re.search(r"-s(\d+)$", scene)
    return seed is not None and int(seed.group(1)) in validation_seeds


def print_frames(results: list[dict[str, Any]], left_out: int) -> int:
    """Print the walks' summed per-frame confusion (``left_out``: validation walks not run)."""
    failed = [f"{r['scene']}: {r['error']}" for r in results if "error" in r]
    if failed:
        print(f"error: {'; '.join(failed)}", file=sys.stderr)
        return 2
    total = sum(r["confusion"] for r in results)
    print(f"per-frame labels of {len(results)} tuning walks: per true class, the share of its pixels given each class")
    if left_out:
        print(f"({left_out} validation walks left out: read as means only)")
    for line in confusion_lines(total, results[0]["names"], results[0]["things"]):
        print(f"  {line}")
    return 0


def called_lines(labels: list[dict[str, Any]]) -> list[str]:
    """``labels_of_matches`` of many walks summed: per true class, what it was called; then the extras."""
    from stratamap.core.evaluation.detection import sum_labels

    summed = sum_labels(labels)

    def text(counts: dict[str, int]) -> str:
        return ", ".join(f"{k} {counts[k]}" for k in sorted(counts, key=lambda k: (-counts[k], k))) or "-"

    called = summed["called"]
    return [f"{true:10s} {text(called[true])}" for true in sorted(called)] + [
        f"{'(extra)':10s} {text(summed['extra'])}"
    ]


if __name__ == "__main__":
    sys.exit(main())
