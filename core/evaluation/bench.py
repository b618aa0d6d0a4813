"""Benchmarks: every (scene, variant) pair of a benchmark file, run, measured and tabulated.

A benchmark file names scenes (synthetic specs with seeds, or any source with its parameters)
and variants of one base pipeline (whole stage lists, or ``--set``-style overrides of the base).
Per scene, the stages every pending variant shares from the start are run once and their result
is reused by each variant (a completer comparison maps a scene once). Runs are jobs handed to an
executor: local worker processes, or Ray tasks on a cluster. Every finished run is one JSON
record written atomically under ``DIR/records/``, so an interrupted benchmark loses nothing and a
re-run skips what is done; ``results.json``/``.csv``/``.md``, the figures and ``report.html`` are
rebuilt from the records at the end. Every run also writes its own ``report.html`` under ``DIR/runs/``.

A run that fails (bad input, a stage's error, a worker process killed by the system) costs only
itself: it is written as a failure under ``DIR/failures/`` with its error in one line, listed in
``results.json`` (``failures``), ``results.md`` and ``report.html``, and tried again by the next
``stratamap bench``; the others' results are written as usual. The bench then ends normally (exit
0) with a warning per failed run, unless no run has a result at all: then, results written, it is
an error (exit 2). Ctrl-C stops the bench: the workers are ended, the runs they had finished keep
their records, and no results are written.

    stratamap bench configs/bench/completion.yaml --out out/bench/completion --workers 2
"""

from __future__ import annotations

import copy
import json
import re
import resource
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.atomic import write_json
from stratamap.core.documents import load_model
from stratamap.core.errors import ConfigError, DataError, StratamapError

# ----------------------------------------------------------------------------------- the file


class SyntheticScenes(BaseModel):
    """Synthetic scenes: one spec file, several seeds."""

    model_config = ConfigDict(extra="forbid")

    scene_file: str = Field(
        description="Scene spec YAML (configs/scenes/*.yaml), relative to the benchmark file's repository or absolute."
    )
    seeds: list[int] = Field(min_length=1, description="One scene per seed.")
    frames: int | None = Field(default=None, ge=1, description="Override the trajectory's number of frames.")
    camera: dict[str, Any] = Field(default_factory=dict, description="Override camera fields (e.g. width, height).")
    scene: dict[str, Any] = Field(
        default_factory=dict, description="Override scene spec fields (e.g. room_size, objects)."
    )


class SceneEntry(BaseModel):
    """Scenes to run: synthetic specs with seeds, or one source (a dataset) with its parameters."""

    model_config = ConfigDict(extra="forbid")

    name: str | None = Field(
        default=None, description="Scene name in the records (default: the spec file's stem plus the seed)."
    )
    synthetic: SyntheticScenes | None = Field(default=None, description="Synthetic scenes from a spec file and seeds.")
    source: dict[str, Any] | None = Field(
        default=None, description="A source stage ({plugin, params}) reading a dataset."
    )
    requires_path: str | None = Field(
        default=None,
        description="Skip this scene (with a note) when this path does not exist, e.g. ../shared/data/mosd/test.",
    )
    files: str | None = Field(
        default=None,
        description=(
            "With `source`: a glob (e.g. ../shared/data/mosd/test/*.pcd); one scene per file, its path in "
            "source.params.path."
        ),
    )
    variants: list[str] | None = Field(
        default=None, description="Run only these variants on these scenes (default: all)."
    )
    scene_list: str | None = Field(
        default=None,
        description=(
            "With `files`: a text file of scene ids, one a line (e.g. ScanNet's scannetv2_val.txt); only the files "
            "named by a listed id (their stem, or their folder's name) are scenes."
        ),
    )


class Variant(BaseModel):
    """One way of running the pipeline."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="Column name in the tables.")
    stages: list[dict[str, Any]] | None = Field(
        default=None, description="The whole stage list (replaces the base pipeline's)."
    )
    set: list[str] = Field(
        default_factory=list,
        description="Overrides of the base pipeline, as `stratamap run --set`, e.g. 'stages[3].plugin=bbox'.",
    )
    drop: list[int] = Field(default_factory=list, description="Indices of base stages to leave out (after `set`).")


class BenchSpec(BaseModel):
    """A benchmark file."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="Benchmark name (titles of tables and figures).")
    description: str = Field(default="", description="What this benchmark compares, for the report.")
    scenes: list[SceneEntry] = Field(min_length=1, description="Scenes to run every variant on.")
    pipeline: dict[str, Any] = Field(
        description="The base pipeline: `stages` (and optionally `output`); the source comes from each scene."
    )
    variants: list[Variant] = Field(min_length=1, description="Variants of the base pipeline, one table column each.")
    per_scene: list[str] = Field(
        default_factory=list, description="Metrics (family.key) to tabulate per scene as well, e.g. instances.f1."
    )
    physics: bool = Field(
        default=True, description="Measure physical plausibility (overlap volume; settling in MuJoCo when installed)."
    )
    physics_seconds: float = Field(default=2.0, gt=0.0, description="Simulated seconds of settling.")
    articulation_check: bool = Field(
        default=False,
        description=(
            "Open every door and drawer of the scene in MuJoCo (the MJCF the mjcf exporter writes by default: room "
            "slabs, free bodies at rest) and look for collisions, then settle it (`physics_seconds`): "
            "articulation.opens_clean_share, articulation.rest_max_displacement_m."
        ),
    )


def load_bench(path: str | Path, overrides: list[str] | None = None) -> tuple[BenchSpec, Path]:
    """A benchmark file, with ``overrides`` (``stratamap bench --set key.path=value``) applied first."""
    path = Path(path)
    if overrides:
        from pydantic import ValidationError

        from stratamap.core.config import apply_override
        from stratamap.core.documents import read_mapping, validation_problems

        doc = read_mapping(path, "benchmark file")
        for assignment in overrides:
            apply_override(doc, assignment)
        try:
            spec = BenchSpec.model_validate(doc)
        except ValidationError as exc:
            raise ConfigError(validation_problems(exc), source=str(path)) from None
    else:
        spec = load_model(BenchSpec, path, "benchmark file")
    names = [v.name for v in spec.variants]
    if len(set(names)) != len(names):
        raise ConfigError([("variants", f"variant names must be unique, got {names}")], source=str(path))
    return spec, path


# ----------------------------------------------------------------------------------- jobs


def _resolve(path: str, base: Path) -> str:
    """Relative paths are looked up next to the benchmark file, then in the stratamap checkout."""
    p = Path(path).expanduser()
    if p.is_absolute():
        return str(p)
    from stratamap.core.paths import repo_root

    for root in (base, repo_root()):
        if (root / p).exists():
            return str((root / p).resolve())
    return str(repo_root() / p)


def _listed(paths: list[Path], listing: Path, k: int, skipped: list[str]) -> list[Path]:
    """The ``paths`` a scene list names (by stem, name or folder name); listed ids without a file are noted."""
    from stratamap.core.documents import read_text

    ids = [line.strip() for line in read_text(listing, "scene list").splitlines() if line.strip()]
    wanted = set(ids)
    kept = [p for p in paths if {p.stem, p.name, p.parent.name} & wanted]
    found = {n for p in kept for n in (p.stem, p.name, p.parent.name)}
    absent = [i for i in ids if i not in found]
    if absent:
        skipped.append(
            f"scenes[{k}]: {len(absent)} of the {len(ids)} scenes {listing} lists have no file "
            f"({', '.join(absent[:5])}{', ...' if len(absent) > 5 else ''}), skipped"
        )
    return kept


def expand_scenes(spec: BenchSpec, bench_file: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """Every scene as ``{name, source}``, and notes on the scenes skipped."""
    scenes, skipped = [], []
    base = bench_file.parent
    for k, entry in enumerate(spec.scenes):
        if entry.requires_path and not Path(_resolve(entry.requires_path, base)).exists():
            skipped.append(
                f"scenes[{k}] ({entry.name or entry.requires_path}): {entry.requires_path} not found, skipped"
            )
            continue
        if entry.synthetic is not None:
            syn = entry.synthetic
            from stratamap.core.synthetic.spec import resolve_spec_paths

            scene_path = Path(_resolve(syn.scene_file, base))
            # The spec travels as a mapping: its relative library paths are made absolute first.
            scene_doc = resolve_spec_paths(yaml.safe_load(scene_path.read_text()), scene_path.parent)
            scene_doc.update(copy.deepcopy(syn.scene))
            if syn.camera:
                scene_doc["camera"] = {**scene_doc.get("camera", {}), **syn.camera}
            stem = entry.name or Path(syn.scene_file).stem
            for seed in syn.seeds:
                params: dict[str, Any] = {"scene": scene_doc, "seed": seed}
                if syn.frames is not None:
                    params["frames"] = syn.frames
                scenes.append(
                    {
                        "name": f"{stem}-s{seed}",
                        "source": {"plugin": "synthetic", "params": params},
                        "variants": entry.variants,
                    }
                )
        elif entry.source is not None:
            if entry.files:
                # The pattern's folders may hold wildcards too (ScanNet: scans/*/*.sens).
                parts = Path(entry.files).parts
                fixed = next((i for i, part in enumerate(parts) if any(c in part for c in "*?[")), len(parts) - 1)
                root = Path(_resolve(str(Path(*parts[:fixed])) if fixed else ".", base))
                paths = sorted(root.glob(str(Path(*parts[fixed:]))))
                if entry.scene_list is not None:
                    paths = _listed(paths, Path(_resolve(entry.scene_list, base)), k, skipped)
                if not paths:
                    skipped.append(f"scenes[{k}]: no file matches {entry.files}, skipped")
                for file in paths:
                    source = copy.deepcopy(entry.source)
                    source.setdefault("params", {})["path"] = str(file)
                    scenes.append(
                        {
                            "name": f"{entry.name + '-' if entry.name else ''}{file.stem}",
                            "source": source,
                            "variants": entry.variants,
                        }
                    )
                continue
            if not entry.name:
                raise ConfigError(
                    [(f"scenes[{k}].name", "a scene with a `source` needs a name")], source=str(bench_file)
                )
            source = copy.deepcopy(entry.source)
            params = source.get("params", {})
            for key in ("path", "root", "folder", "file", "scene_file"):
                if isinstance(params.get(key), str):
                    params[key] = _resolve(params[key], base)
            scenes.append({"name": entry.name, "source": source, "variants": entry.variants})
        else:
            raise ConfigError([(f"scenes[{k}]", "give `synthetic` or `source`")], source=str(bench_file))
    return scenes, skipped


def variant_document(spec: BenchSpec, variant: Variant, source: dict[str, Any]) -> dict[str, Any]:
    from stratamap.core.config import apply_override

    doc = copy.deepcopy(spec.pipeline)
    if variant.stages is not None:
        doc["stages"] = copy.deepcopy(variant.stages)
    for assignment in variant.set:
        apply_override(doc, assignment)
    if variant.drop:
        doc["stages"] = [s for i, s in enumerate(doc.get("stages", [])) if i not in set(variant.drop)]
    doc["source"] = copy.deepcopy(source)
    doc.setdefault("output", {})
    doc["output"].update({"save_map": False, "report": False})
    return doc


def safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)


def record_path(out: Path, scene: str, variant: str) -> Path:
    return out / "records" / safe(scene) / f"{safe(variant)}.json"


class StageFailed(Exception):
    """A variant's stage raised ``error``; ``stage`` names it as ``stages[2]:tsdf``."""

    def __init__(self, stage: str, error: Exception):
        super().__init__(stage, error)
        self.stage, self.error = stage, error


def failure_path(out: Path, scene: str, variant: str) -> Path:
    return out / "failures" / safe(scene) / f"{safe(variant)}.json"


#: The longest error kept in a failure (an Open3D error names its C++ function in full).
ERROR_CHARS = 300


def one_line(exc: BaseException) -> str:
    """The error as one line: stratamap's own as it says it, any other with its type."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(exc))  # Open3D colours its errors
    text = "; ".join(line.strip() for line in text.splitlines() if line.strip())
    if not isinstance(exc, StratamapError):
        text = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    return text if len(text) <= ERROR_CHARS else text[: ERROR_CHARS - 3] + "..."


def write_failure(out: Path, scene: str, variant: str, error: str, stage: str | None = None) -> dict[str, Any]:
    failure = {"scene": scene, "variant": variant, "failed": True, "stage": stage, "error": error}
    write_json(failure_path(out, scene, variant), failure)
    return failure


def peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


# ----------------------------------------------------------------------------------- one scene


def run_scene(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Run the pending variants of one scene; shared leading stages once. Returns the records, and
    a failure (also written under ``failures/``) for each variant that raised: an error in the
    shared stages fails every variant, one in a variant's own stages that variant only.
    KeyboardInterrupt is never caught."""
    from stratamap.core.config import validate
    from stratamap.core.pipeline import Pipeline

    scene, variants, bench, out = job["scene"], job["variants"], job["bench"], Path(job["out"])
    spec = BenchSpec.model_validate(bench)
    pipes = {}
    failures: list[dict[str, Any]] = []
    for v in variants:
        variant = next(x for x in spec.variants if x.name == v)
        try:
            pipes[v] = Pipeline(
                validate(variant_document(spec, variant, scene["source"]), origin=f"{job['bench_file']}#{v}")
            )
        except Exception as exc:  # one variant's invalid document does not stop the others
            failures.append(write_failure(out, scene["name"], v, one_line(exc), "pipeline"))
    variants = [v for v in variants if v in pipes]
    if not variants:
        return failures

    # Shared prefix: the leading stages every pending variant runs with identical parameters.
    def key(p: Pipeline, i: int) -> str:
        s = p.validated.stages[i]
        return json.dumps([s.info.kind, s.info.name, s.config.model_dump(mode="json")], sort_keys=True, default=str)

    first = pipes[variants[0]]
    shared = 0
    while (
        all(shared < len(p.validated.stages) for p in pipes.values())
        and len({key(p, shared) for p in pipes.values()}) == 1
    ):
        shared += 1
    # Exporters write files: never share them, every variant writes its own.
    while shared > 0 and first.validated.stages[shared - 1].info.kind == "exporters":
        shared -= 1
    from stratamap.core.stages import PipelineData

    first.out_dir = out / "runs" / safe(scene["name"]) / "_shared"
    base = PipelineData()
    first.records = []
    resolved = first.validated.source
    try:
        first._run_stage(resolved, -1, base)
        for i in range(shared):
            resolved = first.validated.stages[i]
            first._run_stage(resolved, i, base)
    except Exception as exc:
        where = f"{resolved.path}:{resolved.info.name}"
        return failures + [write_failure(out, scene["name"], v, one_line(exc), where) for v in variants]
    shared_records = list(first.records)
    records = []
    for v in variants:
        try:
            records.append(_run_variant(job, spec, pipes[v], v, base, shared, shared_records))
            continue
        except StageFailed as failed:
            failures.append(write_failure(out, scene["name"], v, one_line(failed.error), failed.stage))
        except Exception as exc:
            failures.append(write_failure(out, scene["name"], v, one_line(exc), "evaluation"))
        # What the failed run's exporters had written is not a result: no half-done run folder stays.
        shutil.rmtree(out / "runs" / safe(scene["name"]) / safe(v), ignore_errors=True)
    return records + failures


def _run_variant(
    job: dict[str, Any], spec: BenchSpec, pipe: Any, v: str, base: Any, shared: int, shared_records: list
) -> dict[str, Any]:
    """One variant of a scene from the shared stages' result: its own stages, its measures, its record."""
    from stratamap.core.pipeline import MemorySampler

    scene, out = job["scene"], Path(job["out"])
    data = copy.copy(base)
    data.map = copy.deepcopy(base.map)
    data.notes = copy.deepcopy(base.notes)
    data.warnings = list(base.warnings)
    pipe.out_dir = out / "runs" / safe(scene["name"]) / safe(v)
    pipe.records = []
    for i in range(shared, len(pipe.validated.stages)):
        resolved = pipe.validated.stages[i]
        try:
            pipe._run_stage(resolved, i, data)
        except Exception as exc:
            raise StageFailed(f"{resolved.path}:{resolved.info.name}", exc) from exc
    if data.ground_truth is not None:
        data.map.vocabulary = data.ground_truth.vocabulary
    with MemorySampler() as evaluation_memory:
        metrics, details = measure(pipe.hook, data, spec, pipe.out_dir)
    stages = [
        {
            "name": r.name,
            "plugin": r.plugin,
            "kind": r.kind,
            "seconds": round(r.seconds, 4),
            "cpu_seconds": round(r.cpu_seconds, 4),
            "shared": shared_run,
            "memory": r.memory(),
        }
        for shared_run, part in ((True, shared_records), (False, pipe.records))
        for r in part
    ]
    record = {
        "scene": scene["name"],
        "variant": v,
        "plugins": [
            {"path": s.path, "plugin": s.info.name, "kind": s.info.kind, "params": s.config.model_dump(mode="json")}
            for s in [pipe.validated.source, *pipe.validated.stages]
        ],
        "seconds": {f"{s['name']}:{s['plugin']}": s["seconds"] for s in stages},
        "seconds_total": round(sum(s["seconds"] for s in stages), 4),
        "cpu_seconds": {f"{s['name']}:{s['plugin']}": s["cpu_seconds"] for s in stages},
        "cpu_seconds_total": round(sum(s["cpu_seconds"] for s in stages), 4),
        "peak_memory_mb": round(peak_memory_mb(), 1),
        "memory_by_stage": {f"{s['name']}:{s['plugin']}": s["memory"]["peak_mb"] for s in stages},
        "evaluation_peak_memory_mb": round(evaluation_memory.peak_mb, 1),
        "scale": scene_scale(data),
        "metrics": metrics,
        "details": details,
        "warnings": data.warnings,
        # What each learned model was trained on and what it never saw, so the results say it.
        "networks": {
            stage: facts["network"]
            for stage, facts in data.notes.items()
            if isinstance(facts, dict) and isinstance(facts.get("network"), dict)
        },
    }
    write_run_report(data, record, stages, pipe.validated.origin, pipe.out_dir)
    write_json(record_path(out, scene["name"], v), record)
    return record


def scene_scale(data: Any) -> dict[str, Any]:
    """How big the run was: frames, floor area (m^2, when the ground truth knows the room), objects,
    and the walk's coverage of them (the share of each object's surface some frame saw, when the
    synthetic source measured it)."""
    out: dict[str, Any] = {"frames": 0 if data.stream is None else len(data.stream)}
    gt = data.ground_truth
    if gt is None:
        return out
    out["objects"] = len(gt.objects)
    layout = gt.layout if isinstance(gt.layout, dict) else {}
    room = layout.get("room_size")
    if room:
        out["area_m2"] = round(float(room[0]) * float(room[1]), 2)
    coverage = layout.get("coverage")
    if isinstance(coverage, dict):
        out["coverage"] = {k: v for k, v in coverage.items() if k != "per_object"}
    return out


def write_run_report(
    data: Any, record: dict[str, Any], stages: list[dict[str, Any]], origin: str, run_dir: Path
) -> Path:
    """``run_dir/report.html``: the run's map, objects, metrics and stage timings, as ``stratamap run``
    writes it (a benchmark's runs bypass ``Pipeline.run`` to share stages, so they write it here)."""
    from stratamap.core.evaluation.html_report import write_report

    report = {
        "pipeline": origin,
        "frames": 0 if data.stream is None else len(data.stream),
        "seconds_total": record["seconds_total"],
        "layers": data.map.layer_counts(),
        "stages": stages,
        "metrics": record["metrics"],
        "warnings": record["warnings"],
    }
    return write_report(data, report, run_dir)


def measure(hook: Any, data: Any, spec: BenchSpec, run_dir: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Metrics by family (every ``stratamap_evaluate`` implementation of ``hook``), and the
    per-object and per-path details the figures need."""
    from stratamap.core.pipeline import evaluate

    metrics = evaluate(hook, data, details=True)
    details: dict[str, Any] = {}
    if "detection" in metrics:
        f1, details["labels_iou25"] = detection_by_iou(data.map.instances, data.ground_truth.objects)
        metrics["detection"].update(f1)
    if "completion" in metrics:
        details["completion_objects"] = metrics["completion"].pop("per_object", [])
        details["chairs"] = [o["chamfer_l1"] for o in details["completion_objects"] if o["class"] == "chair"]
    if "navigation" in metrics:
        details["navigation"] = metrics["navigation"].pop("records", [])
        occ, gt = data.map.occupancy, data.ground_truth.occupancy
        from stratamap.core.atomic import atomic_path

        run_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(run_dir / "navigation.npz") as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(
                    fh,
                    slam=occ["slam"].data,
                    multimap=occ["multimap"].data,
                    truth=gt["objects"].data,
                    origin=np.asarray(occ["multimap"].origin, dtype=float),
                    resolution=float(occ["multimap"].resolution),
                    slam_origin=np.asarray(occ["slam"].origin, dtype=float),
                    slam_resolution=float(occ["slam"].resolution),
                    truth_origin=np.asarray(gt["objects"].origin, dtype=float),
                    truth_resolution=float(gt["objects"].resolution),
                )
    if "articulation" in metrics:
        details["articulation_joints"] = metrics["articulation"].pop("per_joint", [])
    if "panoptic" in metrics:
        details["pq_by_class"] = {c: v["pq"] for c, v in metrics["panoptic"].get("by_class", {}).items()}
    instances = data.map.instances
    if spec.physics and instances is not None and len(instances):
        from stratamap.core.simulation.physics import penetration_volume

        phys: dict[str, Any] = {"penetration_volume_m3": penetration_volume(instances)}
        try:
            import mujoco  # noqa: F401
        except ImportError:
            mujoco = None
        if mujoco is not None:
            from stratamap.core.simulation.mjcf import write_mjcf
            from stratamap.core.simulation.physics import settle

            path = write_mjcf(instances, run_dir / "physics")[0]
            settled = settle(path, spec.physics_seconds)
            # A diverged simulation restarted from the initial pose: no displacement to report.
            phys["diverged"] = bool(settled["diverged"])
            phys["max_displacement_m"] = None if settled["diverged"] else settled["max_displacement_m"]
            phys["free_bodies"] = settled["free_bodies"]
        metrics["physics"] = phys
    if spec.articulation_check and instances is not None and len(instances):
        try:
            import mujoco  # noqa: F401
        except ImportError:
            mujoco = None
        if mujoco is not None:
            from stratamap.core.evaluation.articulation import opening_check
            from stratamap.core.simulation.kinematics import DEFAULT_MOVABLE_CLASSES
            from stratamap.core.simulation.mjcf import write_mjcf
            from stratamap.core.simulation.rest import rest_offsets
            from stratamap.core.simulation.structure import room_structure

            # The scene the mjcf exporter writes by default: the room's slabs (a door hinged on the
            # wrong side swings into the wall) and free bodies placed at rest by its plan (the same
            # inputs: the plan the exporter made is reused).
            statics = room_structure(data.map)
            graph = data.map.contact_graph
            plan = rest_offsets(instances, graph, DEFAULT_MOVABLE_CLASSES, statics)
            path = write_mjcf(
                instances,
                run_dir / "articulation",
                free_classes=DEFAULT_MOVABLE_CLASSES,
                graph=graph,
                statics=statics,
                plan=plan,
            )[0]
            opening = opening_check(path, settle_seconds=spec.physics_seconds)
            details["opening_failures"] = opening.pop("failures")
            metrics.setdefault("articulation", {}).update(opening)
    return json.loads(json.dumps(metrics, default=_plain)), json.loads(json.dumps(details, default=_plain))


def detection_by_iou(instances: Any, gt_objects: Any, iou: float = 0.25) -> tuple[dict[str, float], dict[str, Any]]:
    """Detection F1 with matches by 3D box IoU >= ``iou`` alone (no center-distance criterion),
    class-aware (``f1_iou25``) and class-agnostic (``f1_iou25_agnostic``: any class, a box per object),
    and what the class-agnostic matches say each true object was called (``labels_of_matches``)."""
    from stratamap.core.evaluation.detection import labels_of_matches, match_boxes, prf

    pred = [(i.class_name, i.box) for i in instances]
    gt = [(o.class_name, o.box()) for o in gt_objects]
    threshold = iou - 1e-9  # match_boxes keeps IoU strictly above its threshold
    aware = match_boxes(pred, gt, center_threshold=0.0, iou_threshold=threshold)
    agnostic = match_boxes([("", b) for _, b in pred], [("", b) for _, b in gt], 0.0, threshold)
    tag = f"iou{round(iou * 100)}"
    f1 = {
        f"f1_{tag}": prf(len(aware), len(pred), len(gt))["f1"],
        f"f1_{tag}_agnostic": prf(len(agnostic), len(pred), len(gt))["f1"],
    }
    return f1, labels_of_matches(pred, gt, agnostic)


def _plain(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


# ----------------------------------------------------------------------------------- executors


#: A worker's exit status when Ctrl-C ended it (the shell's 128 + SIGINT).
INTERRUPTED = 130


def _local_worker(job: dict[str, Any]) -> None:
    """A worker process's job: its records and failures go to disk, where the driver reads them."""
    try:
        run_scene(job)
    except KeyboardInterrupt:
        # Ctrl-C reaches every process of the terminal's group: the driver stops the bench, this
        # worker says so by its exit status instead of printing a traceback of its own.
        raise SystemExit(INTERRUPTED) from None


def _died(code: int | None) -> str:
    """How a worker process ended, in words."""
    import signal

    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        killed = " (out of memory?)" if -code == signal.SIGKILL else ""
        return f"the worker process was killed by {name}{killed}"
    return f"the worker process exited with status {code}"


def job_outcomes(job: dict[str, Any], died: str | None = None) -> list[dict[str, Any]]:
    """The records and failures a finished job left on disk; a variant with neither is failed with
    ``died`` (the job's process ended before it wrote either)."""
    out, scene = Path(job["out"]), job["scene"]["name"]
    outcomes = []
    for v in job["variants"]:
        for path in (record_path(out, scene, v), failure_path(out, scene, v)):
            if path.is_file():
                outcomes.append(json.loads(path.read_text()))
                break
        else:
            outcomes.append(write_failure(out, scene, v, died or "the run left no record", None))
    return outcomes


def run_jobs_local(jobs: list[dict[str, Any]], workers: int, on_done) -> None:
    """Jobs in worker processes (one fresh process per scene, so peak memory is per scene). A
    process that dies (killed for memory, a crash in native code) fails its scene's unfinished
    variants and no other job; Ctrl-C ends every worker and is raised."""
    import multiprocessing as mp
    import signal
    from multiprocessing.connection import wait

    from stratamap.core.parallel import worker_blas_threads

    ctx = mp.get_context("spawn")  # Open3D and OpenMP threads do not survive fork
    queue = list(jobs)
    running: dict[Any, tuple[Any, dict[str, Any]]] = {}
    started = []  # listed before start(): a Ctrl-C that lands inside start() still ends the process
    try:
        with worker_blas_threads(workers):
            while queue or running:
                while queue and len(running) < max(1, workers):
                    job = queue.pop(0)
                    proc = ctx.Process(target=_local_worker, args=(job,), name=f"bench {job['scene']['name']}")
                    started.append(proc)
                    proc.start()
                    running[proc.sentinel] = (proc, job)
                for sentinel in wait(list(running)):
                    proc, job = running.pop(sentinel)
                    proc.join()
                    if proc.exitcode in (INTERRUPTED, -signal.SIGINT):
                        raise KeyboardInterrupt
                    on_done(job, job_outcomes(job, None if proc.exitcode == 0 else _died(proc.exitcode)))
    finally:
        alive = [proc for proc in started if proc.is_alive()]
        for proc in alive:  # after Ctrl-C or a failing callback: no worker outlives the bench
            proc.terminate()
        for proc in alive:
            proc.join()


def run_jobs_ray(jobs: list[dict[str, Any]], address: str | None, on_done, num_cpus: int | None = None) -> None:
    """The same jobs as Ray tasks: the benchmark spec goes into the object store once."""
    from stratamap.core.parallel import ensure_ray, ray_module

    ray = ray_module()  # a missing Ray, or no cluster at `address`, is a one-line ConfigError (CLI exit 2)
    started = ensure_ray(address, num_cpus=num_cpus)
    try:
        bench_ref = ray.put(jobs[0]["bench"]) if jobs else None

        @ray.remote(num_cpus=1)
        def task(job: dict[str, Any], bench: dict[str, Any]) -> list[dict[str, Any]]:
            return run_scene({**job, "bench": bench})

        pending = {task.remote({k: v for k, v in job.items() if k != "bench"}, bench_ref): job for job in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    ray.get(ref)
                except Exception as exc:  # the task's worker died (a stage's own error is already a failure)
                    on_done(job, job_outcomes(job, f"the Ray task failed: {one_line(exc)}"))
                else:
                    on_done(job, job_outcomes(job))
    finally:
        if started:
            ray.shutdown()


# ----------------------------------------------------------------------------------- driver


def run_bench(
    bench_file: str | Path,
    out: str | Path,
    workers: int = 1,
    executor: Literal["local", "ray"] = "local",
    address: str | None = None,
    progress: bool = True,
    overrides: list[str] | None = None,
) -> dict[str, Any]:
    """Run what is missing (runs that failed before included), then rebuild ``results.*`` and
    figures from every record. A failed run is listed with its error and the bench goes on; a
    DataError, after the results are written, when no run has a result at all (the CLI's exit 2)."""
    from stratamap.core.config import validate

    spec, path = load_bench(bench_file, overrides)
    out = Path(out)
    scenes, skipped = expand_scenes(spec, path)
    bench_doc = spec.model_dump(mode="json")
    jobs = []
    total = done_before = 0
    for scene in scenes:
        wanted = [v.name for v in spec.variants if scene.get("variants") is None or v.name in scene["variants"]]
        pending = [v for v in wanted if not record_path(out, scene["name"], v).is_file()]
        total += len(wanted)
        done_before += len(wanted) - len(pending)
        for v in pending:  # a mistyped override is the benchmark file's error: found before anything runs
            variant = next(x for x in spec.variants if x.name == v)
            validate(variant_document(spec, variant, scene["source"]), origin=f"{path}#{v}")
        if pending:
            jobs.append(
                {"scene": scene, "variants": pending, "bench": bench_doc, "out": str(out), "bench_file": str(path)}
            )
    out.mkdir(parents=True, exist_ok=True)
    for job in jobs:  # what a run of this bench fails is its own failure, not one left by the last
        for v in job["variants"]:
            failure_path(out, job["scene"]["name"], v).unlink(missing_ok=True)

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(
        TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), disable=not progress
    ) as bar:
        task = bar.add_task(f"bench {spec.name}", total=total, completed=done_before)

        def on_done(job: dict[str, Any], outcomes: list[dict[str, Any]]) -> None:
            bar.update(task, advance=len(outcomes), description=f"bench {spec.name}: {job['scene']['name']}")

        if jobs:
            if executor == "ray":
                run_jobs_ray(jobs, address, on_done, num_cpus=workers)
            else:
                run_jobs_local(jobs, workers, on_done)
    records = collect_records(out, scenes, spec)
    failures = collect_failures(out, scenes, spec)
    results = {"name": spec.name, "versions": versions(), "skipped": skipped, "records": records}
    results["failures"] = failures
    write_json(out / "results.json", results)
    from stratamap.core.evaluation.bench_report import write_reports

    written = write_reports(results, spec, out, bench_file=path)
    from stratamap.core.evaluation.scan2cad import write_pooled

    pooled_scan2cad = write_pooled(records, out)  # the benchmark's own figures pool scans, not average them
    if pooled_scan2cad is not None:
        written.append(pooled_scan2cad)
    from stratamap.core.evaluation.bench_report import scale_table

    failed = [failure_line(f) for f in failures]
    if failed and progress:
        from rich.console import Console

        warn = Console(stderr=True)
        for line in failed:
            warn.print(f"[yellow]warning:[/] bench {spec.name}: {line}", highlight=False, soft_wrap=True, markup=True)
    if failures and not records:
        first = f"first: {failed[0]}" if len(failed) > 1 else failed[0]
        raise DataError(f"bench {spec.name}: all {len(failures)} runs failed ({first}); see {out / 'results.md'}")
    scale = scale_table(records)
    return {
        "records": len(records),
        "ran": sum(len(j["variants"]) for j in jobs),
        "skipped": skipped,
        # One line per run that failed ("scene / variant at stage: error"): no record, tried again next time.
        "failed": failed,
        "files": [str(p) for p in written],
        # The cost against scene size (Markdown lines), when some variant ran at several sizes.
        "scale": scale.markdown() if scale is not None else [],
    }


def failure_line(failure: dict[str, Any]) -> str:
    where = f" at {failure['stage']}" if failure.get("stage") else ""
    return f"{failure['scene']} / {failure['variant']} failed{where}: {failure['error']}"


def _runs(scenes: list[dict[str, Any]], spec: BenchSpec) -> Iterator[tuple[str, str]]:
    """(scene, variant) of every run the benchmark makes, in the order of the records."""
    for scene in scenes:
        for v in spec.variants:
            if scene.get("variants") is None or v.name in scene["variants"]:
                yield scene["name"], v.name


def _read_kept(path: Path) -> dict[str, Any] | None:
    """A record or failure file; None where there is none (or a hand-made half, which is removed:
    atomic writes never leave halves)."""
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError:
        path.unlink()
        return None


def collect_failures(out: Path, scenes: list[dict[str, Any]], spec: BenchSpec) -> list[dict[str, Any]]:
    """The failures of the runs that have no record, in the order of the records."""
    kept = (
        _read_kept(failure_path(out, scene, variant))
        for scene, variant in _runs(scenes, spec)
        if not record_path(out, scene, variant).is_file()
    )
    return [f for f in kept if f is not None]


def collect_records(out: Path, scenes: list[dict[str, Any]], spec: BenchSpec) -> list[dict[str, Any]]:
    kept = (_read_kept(record_path(out, scene, variant)) for scene, variant in _runs(scenes, spec))
    return [r for r in kept if r is not None]


def versions() -> dict[str, str]:
    from stratamap.core.pipeline import package_versions

    out = package_versions()
    for pkg in ("mujoco", "ray", "onnxruntime"):
        try:
            from importlib.metadata import version

            out[pkg] = version(pkg)
        except Exception:
            pass
    out["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    return out
