"""Run a validated pipeline: source, stages in order, save the map, write the report."""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from stratamap.core.atomic import write_json
from stratamap.core.config import ResolvedStage, ValidatedPipeline
from stratamap.core.errors import ConfigError
from stratamap.core.registry import Registry, default_registry
from stratamap.core.stages import LAYERS, Exporter, PipelineData, Stage


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("stratamap", "numpy", "open3d", "trimesh", "scipy", "networkx", "pydantic"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    return out


@dataclass
class StageRecord:
    name: str
    plugin: str
    kind: str
    seconds: float
    outputs: list[str] = field(default_factory=list)


class Pipeline:
    """A validated pipeline bound to a registry (whose plugin manager carries the event hooks)."""

    def __init__(self, validated: ValidatedPipeline, registry: Registry | None = None):
        self.validated = validated
        self.registry = registry or default_registry()
        self.records: list[StageRecord] = []
        self.data: PipelineData | None = None
        self.out_dir: Path | None = None

    @property
    def hook(self) -> Any:
        return self.registry.hook

    def _run_stage(self, resolved: ResolvedStage, index: int, data: PipelineData) -> None:
        stage: Stage = resolved.instantiate()
        stage._hook = self.hook
        self.hook.stratamap_stage_start(pipeline=self, stage=stage, index=index)
        t0 = time.perf_counter()
        export_dir = None
        if isinstance(stage, Exporter):
            assert self.out_dir is not None
            export_dir = self.out_dir / self.validated.spec.output.export_dir
        result = stage.run(data, export_dir)
        seconds = time.perf_counter() - t0
        outputs: list[str] = []
        if isinstance(result, dict):
            for layer, value in result.items():
                if layer not in stage.provides:
                    raise RuntimeError(
                        f"{resolved.path} ({stage.name}) returned layer {layer!r} that it does not declare in provides"
                    )
                expected = LAYERS[layer]
                if value is not None and not isinstance(value, expected):
                    raise TypeError(
                        f"{resolved.path} ({stage.name}) returned {type(value).__name__} for layer "
                        f"{layer!r}; expected {expected.__name__}"
                    )
                if value is not None:
                    data.set(layer, value, producer=stage.name)
                    outputs.append(layer)
        else:
            outputs = [str(p) for p in result]
        self.records.append(StageRecord(resolved.path, stage.name, stage.kind, seconds, outputs))
        self.hook.stratamap_stage_end(pipeline=self, stage=stage, index=index, seconds=seconds)

    def run(self, out_dir: str | Path | None = None) -> dict[str, Any]:
        """Run every stage; write map, exports and report under ``out_dir``; return the report."""
        spec = self.validated.spec
        out = out_dir or spec.output.dir
        if out is None:
            raise ConfigError([("output.dir", "no output folder: pass --out DIR or set output.dir in the pipeline file")], self.validated.origin)
        self.out_dir = Path(out)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        data = self.data = PipelineData()
        self.records = []
        self.hook.stratamap_pipeline_start(pipeline=self)
        t_start = time.perf_counter()

        self._run_stage(self.validated.source, -1, data)
        for i, resolved in enumerate(self.validated.stages):
            self._run_stage(resolved, i, data)

        if data.ground_truth is not None:
            data.map.vocabulary = data.ground_truth.vocabulary
        if spec.output.save_map:
            data.map.metadata.setdefault("pipeline", self.validated.origin)
            data.map.save(self.out_dir / "map")

        report = self._report(data, time.perf_counter() - t_start)
        if spec.output.report:
            write_json(self.out_dir / "report.json", report)
        self.hook.stratamap_pipeline_end(pipeline=self, report=report)
        return report

    def _report(self, data: PipelineData, total_seconds: float) -> dict[str, Any]:
        from stratamap.core.metrics import evaluate

        metrics: dict[str, Any] = {}
        if self.validated.spec.output.metrics and data.ground_truth is not None:
            metrics = evaluate(data)
        return {
            "pipeline": self.validated.origin,
            "versions": package_versions(),
            "stages": [
                {"name": r.name, "plugin": r.plugin, "kind": r.kind, "seconds": round(r.seconds, 4), "outputs": r.outputs}
                for r in self.records
            ],
            "seconds_total": round(total_seconds, 4),
            "layers": data.map.layer_counts(),
            "frames": 0 if data.stream is None else len(data.stream),
            "metrics": metrics,
            "notes": json.loads(json.dumps(data.notes, default=str)),
            "warnings": data.warnings,
            "plugin_load_failures": [str(f) for f in self.registry.failures],
        }
