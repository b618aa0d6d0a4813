"""``stratamap run --resume``: a run that failed after some stages starts again after the last one that
finished, gives the bytes an uninterrupted run gives, and never takes a checkpoint of other settings."""

from __future__ import annotations

import sys
import types
from pathlib import Path

import pytest
import yaml

from stratamap.core import Completer, hookimpl
from stratamap.core.config import load_pipeline
from stratamap.core.pipeline import Pipeline
from stratamap.core.registry import build_registry

#: How often the counted stage ran, and whether the flaky one fails (module state the stages read).
STATE = {"runs": 0, "fail": True}


class CountedCompleter(Completer):
    """Passes the instances on and counts its runs."""

    name = "counted"

    def complete(self, data):
        STATE["runs"] += 1
        return {"instances": data.map.instances.copy()}


class FlakyCompleter(Completer):
    """Fails while ``STATE['fail']`` is set, as a run cut short would."""

    name = "flaky"

    def complete(self, data):
        if STATE["fail"]:
            raise RuntimeError("flaky: failing as asked")
        return {"instances": data.map.instances.copy()}


@pytest.fixture()
def registry():
    mod = types.ModuleType("resume_test_stages")

    @hookimpl
    def stratamap_register_completers():
        return [CountedCompleter, FlakyCompleter]

    mod.stratamap_register_completers = stratamap_register_completers
    sys.modules[mod.__name__] = mod
    STATE.update(runs=0, fail=True)
    try:
        yield build_registry(eps=[], extra_modules=[mod.__name__], autoload=True)
    finally:
        del sys.modules[mod.__name__]


def pipeline_file(tmp_path: Path, voxel: float = 0.05) -> Path:
    doc = {
        "source": {
            "plugin": "synthetic",
            "params": {"scene": {"type": "office", "seed": 3, "camera": {"width": 160, "height": 120}}, "frames": 8},
        },
        "stages": [
            {"plugin": "oracle"},
            {"plugin": "tsdf", "params": {"voxel_size": voxel}},
            {"plugin": "counted"},
            {"plugin": "flaky"},
            {"plugin": "ply"},
        ],
        "output": {"save_map": True, "metrics": False},
    }
    path = tmp_path / f"pipeline-{voxel}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def saved(out: Path) -> dict[str, bytes]:
    files = [p for top in ("map", "export") for p in sorted((out / top).rglob("*")) if p.is_file()]
    return {str(p.relative_to(out)): p.read_bytes() for p in files}


@pytest.mark.slow
def test_a_failed_run_resumes_after_its_last_finished_stage_with_the_same_bytes(tmp_path, registry):
    config, out = pipeline_file(tmp_path), tmp_path / "out"
    with pytest.raises(RuntimeError, match="failing as asked"):
        Pipeline(load_pipeline(config, registry=registry), registry).run(out, resume=True)
    assert not out.exists() and STATE["runs"] == 1
    kept = list((tmp_path / ".out.checkpoints").iterdir())
    assert [p.name.split("-")[:3] for p in kept] == [["after", "stage", "02"]]  # after `counted`, the latest only

    STATE["fail"] = False
    report = Pipeline(load_pipeline(config, registry=registry), registry).run(out, resume=True)
    assert report["resumed_after"] == "stages[2]" and STATE["runs"] == 1  # oracle, tsdf, counted not run again
    assert [s["plugin"] for s in report["stages"]] == ["synthetic", "oracle", "tsdf", "counted", "flaky", "ply"]
    assert not (tmp_path / ".out.checkpoints").exists()  # the output is complete: its checkpoints are gone

    whole = Pipeline(load_pipeline(config, registry=registry), registry).run(tmp_path / "whole")
    assert "resumed_after" not in whole and STATE["runs"] == 2
    resumed, uninterrupted = saved(out), saved(tmp_path / "whole")
    assert any(k.startswith("export/") for k in resumed) and "map/instances.npz" in resumed
    assert resumed == uninterrupted


@pytest.mark.slow
def test_a_checkpoint_of_other_settings_is_not_taken(tmp_path, registry):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        Pipeline(load_pipeline(pipeline_file(tmp_path), registry=registry), registry).run(out, resume=True)
    STATE["fail"] = False
    other = pipeline_file(tmp_path, voxel=0.06)
    report = Pipeline(load_pipeline(other, registry=registry), registry).run(out, resume=True)
    assert "resumed_after" not in report and STATE["runs"] == 2


def test_without_resume_nothing_is_checkpointed(tmp_path, registry):
    with pytest.raises(RuntimeError):
        Pipeline(load_pipeline(pipeline_file(tmp_path), registry=registry), registry).run(tmp_path / "out")
    assert not (tmp_path / ".out.checkpoints").exists()
