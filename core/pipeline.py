"""Run a validated pipeline: source, stages in order, save the map, write the report."""

from __future__ import annotations

import json
import os
import platform
import resource
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import pluggy

from stratamap.core.atomic import atomic_directory, check_output_folder, raise_if_interrupted, write_json
from stratamap.core.checkpoints import Checkpoints, checkpoint_folder, clear_checkpoints
from stratamap.core.config import ResolvedStage, ValidatedPipeline
from stratamap.core.errors import ConfigError, PluginError
from stratamap.core.hookspecs import Observer
from stratamap.core.registry import Registry, default_registry
from stratamap.core.stages import LAYERS, Exporter, PipelineData, Stage, missing_layers


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("stratamap", "numpy", "open3d", "trimesh", "scipy", "networkx", "pydantic"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


def resident_mb() -> float:
    """The process's resident memory now, MB (from /proc; the peak so far where there is none)."""
    try:
        with open("/proc/self/statm", "rb") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return max_resident_mb()


def release_free_memory() -> None:
    """Give the heap memory freed so far back to the operating system (glibc's ``malloc_trim``).
    glibc keeps freed memory for reuse, per thread arena: the memory a stage's library threads freed
    (Open3D's ray casts, say) would otherwise stay resident under the next stage's peak, used by no
    one. Does nothing where there is no glibc."""
    global _malloc_trim
    if _malloc_trim is None:
        try:
            import ctypes

            _malloc_trim = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _malloc_trim = False
    if _malloc_trim:
        _malloc_trim(0)


_malloc_trim: Any = None


def cpu_seconds() -> float:
    """User and system CPU seconds this process has used so far (all threads)."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def max_resident_mb() -> float:
    """The process's peak resident memory so far, MB (ru_maxrss: kB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024


class MemorySampler:
    """The peak resident memory while a block runs, sampled from a background thread every
    ``interval`` seconds (one small /proc read each; no tracemalloc, which would slow every allocation).
    The process's ru_maxrss only ever grows, so it cannot tell a later stage's peak from an earlier one's.

    Every ``release_every`` seconds the thread also gives freed heap memory back to the operating system
    (:func:`release_free_memory`). glibc serves a stream's per-frame buffers (images, point sets,
    Open3D's temporaries) from its heaps once it has freed a larger block, and keeps what they leave
    between longer-lived blocks: fusing 480 frames of a 143 m2 floor (with 16-bit voxel weights) peaked
    at 1.39 GB, at 1.03 GB when trimmed every 0.5 or 2 s, for 2 % more CPU time (fixing glibc's mapping
    threshold at 128 KiB instead gave 0.97 GB for 65 % more; docs/experiments/2026-11-24-scaling.md)."""

    def __init__(self, interval: float = 0.05, release_every: float | None = 1.0):
        self.interval = interval
        self.release_every = release_every
        self.peak_mb = 0.0
        self.start_mb = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _poll(self) -> None:
        released = time.monotonic()
        while not self._stop.wait(self.interval):
            self.peak_mb = max(self.peak_mb, resident_mb())
            if self.release_every is not None and time.monotonic() - released >= self.release_every:
                release_free_memory()
                released = time.monotonic()

    def __enter__(self) -> MemorySampler:
        self.start_mb = self.peak_mb = resident_mb()
        self._thread = threading.Thread(target=self._poll, name="stratamap-memory", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.peak_mb = max(self.peak_mb, resident_mb())


@dataclass
class StageRecord:
    name: str
    plugin: str
    kind: str
    seconds: float
    outputs: list[str] = field(default_factory=list)
    #: Resident memory (MB) when the stage started, its peak while it ran, and the process's
    #: ru_maxrss (peak since the process started) once it ended.
    memory_start_mb: float = 0.0
    memory_peak_mb: float = 0.0
    maxrss_after_mb: float = 0.0
    #: CPU seconds (user + system, all threads) the stage took: unlike wall time, not lengthened by
    #: other processes sharing the machine.
    cpu_seconds: float = 0.0

    def memory(self) -> dict[str, float]:
        return {
            "start_mb": round(self.memory_start_mb, 1),
            "peak_mb": round(self.memory_peak_mb, 1),
            "maxrss_after_mb": round(self.maxrss_after_mb, 1),
        }


#: Written into every run's output folder, so that a later run may replace it (and nothing else).
RUN_MARKER = ".stratamap-run"


def is_run_output(folder: Path) -> bool:
    """Whether ``folder`` holds the output of an earlier ``stratamap run``."""
    return any((folder / name).exists() for name in (RUN_MARKER, "report.json", "map/manifest.json"))


def _renamed(path: str, staging: Path, final: Path) -> str:
    try:
        return str(final / Path(path).relative_to(staging))
    except ValueError:
        return path


def apply_outputs(stage: Stage, result: dict[str, Any] | list[Path], data: PipelineData, where: str = "") -> list[str]:
    """Check a stage's returned layers against what it declares and put them on ``data``; return
    the layers set (or, for an exporter, the files it wrote)."""
    if not isinstance(result, dict):
        return [str(p) for p in result]
    where = where or f"{stage.kind}.{stage.name}"
    outputs: list[str] = []
    for layer, value in result.items():
        if layer not in stage.provides:
            raise RuntimeError(f"{where} ({stage.name}) returned layer {layer!r} that it does not declare in provides")
        expected = LAYERS[layer]
        if value is not None and not isinstance(value, expected):
            raise TypeError(
                f"{where} ({stage.name}) returned {type(value).__name__} for layer {layer!r}; expected "
                f"{expected.__name__}"
            )
        if value is not None:
            data.set(layer, value, producer=stage.name)
            outputs.append(layer)
    return outputs


def run_stages(stages: Iterable[Stage], data: PipelineData | None = None, out_dir: Path | None = None) -> PipelineData:
    """Run stage instances in order on ``data`` (a new blackboard by default), each one's layers
    checked and set as a pipeline does, but with no files, hooks or report: for notebooks, tests
    and benchmarks that build a map step by step."""
    data = data if data is not None else PipelineData()
    for stage in stages:
        apply_outputs(stage, stage.run(data, out_dir), data)
    return data


def evaluate(hook: Any, data: PipelineData, details: bool = False) -> dict[str, Any]:
    """Every metric family the registered ``stratamap_evaluate`` implementations give for ``data``
    (the built-in families first; a later family of the same name replaces an earlier one)."""
    metrics: dict[str, Any] = {}
    for families in reversed(hook.stratamap_evaluate(data=data, details=details)):
        metrics.update(families or {})
    return metrics


class Pipeline:
    """A validated pipeline bound to a registry (whose plugin manager carries the event hooks)."""

    def __init__(self, validated: ValidatedPipeline, registry: Registry | None = None):
        self.validated = validated
        self.registry = registry or default_registry()
        self.records: list[StageRecord] = []
        self.data: PipelineData | None = None
        self.out_dir: Path | None = None
        #: The observers of the current (or last) run, made from the pipeline's ``observers``.
        self.observers: list[Observer] = []

    @property
    def hook(self) -> Any:
        return self.registry.hook

    def _run_stage(self, resolved: ResolvedStage, index: int, data: PipelineData) -> None:
        # The rule validate checked on the declared layers, now on what the earlier stages made: a
        # stage that declared a layer and returned none leaves its readers a one-line error. What a
        # source declares depends on the recording (ground truth only where there is some): the
        # stages that need it say in their own words what is missing and how to get it.
        from_source = self.validated.source.info.cls.provides
        missing = [layer for layer in missing_layers(resolved.info.cls, data.available()) if layer not in from_source]
        if missing:
            earlier = [self.validated.source, *self.validated.stages[: max(index, 0)]]
            problems = []
            for layer in missing:
                declared = [r.spec.plugin for r in earlier if layer in r.info.cls.provides]
                problems.append(
                    (
                        f"{resolved.path}.plugin",
                        f"stage {resolved.spec.plugin!r} requires layer {layer!r}, which no earlier stage made in "
                        f"this run (declared by {', '.join(declared) or 'none'}, which returned none)",
                    )
                )
            raise ConfigError(problems, self.validated.origin)
        stage: Stage = resolved.instantiate()
        stage._hook = self.hook
        self.hook.stratamap_stage_start(pipeline=self, stage=stage, index=index)
        t0 = time.perf_counter()
        export_dir = None
        if isinstance(stage, Exporter):
            assert self.out_dir is not None
            export_dir = self.out_dir / self.validated.spec.output.export_dir
        cpu0 = cpu_seconds()
        with MemorySampler() as memory:
            result = stage.run(data, export_dir)
        seconds = time.perf_counter() - t0
        cpu = cpu_seconds() - cpu0
        release_free_memory()
        outputs = apply_outputs(stage, result, data, resolved.path)
        self.records.append(
            StageRecord(
                resolved.path,
                stage.name,
                stage.kind,
                seconds,
                outputs,
                memory.start_mb,
                memory.peak_mb,
                max_resident_mb(),
                cpu,
            )
        )
        self.hook.stratamap_stage_end(pipeline=self, stage=stage, index=index, seconds=seconds)

    def run(self, out_dir: str | Path | None = None, resume: bool = False) -> dict[str, Any]:
        """Run every stage; write map, exports and report under ``out_dir``; return the report.
        ``resume``: checkpoint the run after each stage before the first exporter, and start after
        the latest checkpoint an interrupted or failed run of the same pipeline, settings and input
        into the same output left (``core/checkpoints.py``); the checkpoints go once the run is done."""
        spec = self.validated.spec
        out = out_dir or spec.output.dir
        if out is None:
            raise ConfigError(
                [("output.dir", "no output folder: pass --out DIR or set output.dir in the pipeline file")],
                self.validated.origin,
            )
        shown = Path(out)
        final = check_output_folder(shown, is_run_output, "stratamap run output")
        # Made before anything is written: an observer that cannot start (a missing library) fails
        # the run with the output folder untouched.
        self.observers = [resolved.instantiate() for resolved in self.validated.observers]
        # Everything is written into a staging folder beside the output and swapped in at the end:
        # a failed or interrupted run leaves the previous output exactly as it was, and no new folder.
        checkpoints = (
            Checkpoints(checkpoint_folder(final), self.validated.source, self.validated.stages, package_versions())
            if resume
            else None
        )
        with atomic_directory(final) as staging:
            self.out_dir = staging
            with self._observed():
                report = self._run_into(staging, shown, checkpoints)
        self.out_dir = shown
        clear_checkpoints(final)  # this output is complete: no run of it resumes any more
        return report

    @contextmanager
    def _observed(self) -> Iterator[None]:
        """The run's observers registered with the plugin manager for its duration only, then
        unregistered and closed (also after a failure), before the staging folder is swapped in."""
        manager = self.registry.plugin_manager
        try:
            for observer in self.observers:
                try:
                    manager.register(observer)
                except pluggy.PluginValidationError as exc:  # a hook method whose signature no hook has
                    raise PluginError(f"observer {observer.name!r} cannot be registered: {exc}") from None
            yield
        finally:
            for observer in self.observers:
                if manager.is_registered(observer):
                    manager.unregister(observer)
                observer.close()

    def _run_into(self, staging: Path, shown: Path, checkpoints: Checkpoints | None = None) -> dict[str, Any]:
        spec = self.validated.spec
        data = self.data = PipelineData()
        self.records = []
        self.hook.stratamap_pipeline_start(pipeline=self)
        t_start = time.perf_counter()

        self._run_stage(self.validated.source, -1, data)
        source_stream, start, resumed = data.stream, 0, None
        found = checkpoints.latest() if checkpoints is not None else None
        if found is not None:
            index, data, self.records = found
            self.data = data
            if data.stream is None:  # the source's frames, read again (the checkpoint leaves them out)
                data.stream = source_stream
            start, resumed = index + 1, self.validated.stages[index].path
            self.hook.stratamap_pipeline_step(pipeline=self, description=f"resumed after {resumed}")
        for i, resolved in enumerate(self.validated.stages):
            if i < start:
                continue
            raise_if_interrupted()
            self._run_stage(resolved, i, data)
            if checkpoints is not None:
                checkpoints.save(i, data, self.records, source_stream)
        raise_if_interrupted()
        if checkpoints is not None and checkpoints.failed:
            data.warnings.append(f"pipeline: {checkpoints.failed}; a resumed run starts before it")

        if data.ground_truth is not None:
            data.map.vocabulary = data.ground_truth.vocabulary
        if spec.output.save_map:
            self.hook.stratamap_pipeline_step(pipeline=self, description="saving the map")
            data.map.metadata.setdefault("pipeline", self.validated.origin)
            data.map.save(staging / "map")
        for record in self.records:  # files as they will be named once the output is in place
            record.outputs = [_renamed(o, staging, shown) for o in record.outputs]

        report = self._report(data, time.perf_counter() - t_start)
        if resumed is not None:
            report["resumed_after"] = resumed
        if spec.output.report:
            write_json(staging / "report.json", report)
        write_json(staging / RUN_MARKER, {"pipeline": self.validated.origin})
        self.hook.stratamap_pipeline_end(pipeline=self, report=report)
        return report

    def _report(self, data: PipelineData, total_seconds: float) -> dict[str, Any]:
        metrics: dict[str, Any] = {}
        if self.validated.spec.output.metrics:
            self.hook.stratamap_pipeline_step(pipeline=self, description="evaluating against ground truth")
            metrics = evaluate(self.hook, data)
        return {
            "pipeline": self.validated.origin,
            "versions": package_versions(),
            "stages": [
                {
                    "name": r.name,
                    "plugin": r.plugin,
                    "kind": r.kind,
                    "seconds": round(r.seconds, 4),
                    "cpu_seconds": round(r.cpu_seconds, 4),
                    "outputs": r.outputs,
                    "memory": r.memory(),
                }
                for r in self.records
            ],
            "seconds_total": round(total_seconds, 4),
            "peak_memory_mb": round(max_resident_mb(), 1),
            "layers": data.map.layer_counts(),
            "frames": 0 if data.stream is None else len(data.stream),
            "metrics": metrics,
            "notes": json.loads(json.dumps(data.notes, default=str)),
            "warnings": data.warnings,
            "plugin_load_failures": [str(f) for f in self.registry.failures],
        }
