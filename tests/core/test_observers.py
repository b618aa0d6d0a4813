"""Observers: a plugin kind whose classes follow one run through the event hooks, named in the
pipeline file (``observers:``) or with ``stratamap run --observe``; unknown names and bad
parameters fail like unknown stages."""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import EntryPoint
from typing import Any, ClassVar

import pytest
import yaml
from pydantic import Field

from stratamap.core.config import load_pipeline
from stratamap.core.errors import ConfigError, DataError, PluginError
from stratamap.core.hookspecs import Observer, ObserverConfig, hookimpl
from stratamap.core.pipeline import Pipeline
from stratamap.core.registry import build_registry
from stratamap.core.testing import parametrize_with_checks
from tests.conftest import REPO


class _Dist:
    name = "acme-observers"


class EventLogConfig(ObserverConfig):
    tag: str = Field(default="log", description="A label kept with the events.")


class EventLog(Observer[EventLogConfig]):
    """Keeps the events of the run it observes (a third-party observer, for the tests)."""

    name = "event_log"
    Config = EventLogConfig
    instances: ClassVar[list[EventLog]] = []

    def __init__(self, config: EventLogConfig | None = None, **params: Any):
        super().__init__(config, **params)
        self.events: list[str] = []
        self.closed = 0
        EventLog.instances.append(self)

    @hookimpl
    def stratamap_pipeline_start(self, pipeline: Any) -> None:
        self.events.append("start")

    @hookimpl
    def stratamap_stage_end(self, pipeline: Any, stage: Any, index: int, seconds: float) -> None:
        self.events.append(f"{stage.kind}.{stage.name}")

    @hookimpl
    def stratamap_pipeline_end(self, pipeline: Any, report: dict) -> None:
        self.events.append("end")

    def close(self) -> None:
        self.closed += 1


class Misnamed(Observer):
    """Implements a hook with an argument the hook does not have."""

    name = "misnamed"

    @hookimpl
    def stratamap_stage_end(self, pipeline: Any, stage: Any, elapsed: float) -> None:
        pass


@pytest.fixture
def registry():
    EventLog.instances.clear()
    entries = [
        EntryPoint(name=name, value=f"{__name__}:{cls}", group="stratamap.observers")._for(_Dist())
        for name, cls in (("event_log", "EventLog"), ("misnamed", "Misnamed"))
    ]
    return build_registry(eps=entries, extra_modules=[], autoload=True)


def _pipeline_file(tmp_path, observers=None, cloud="0 0 0\n1 0 0\n0 1 0\n"):
    (tmp_path / "scan.xyz").write_text(cloud)
    doc: dict[str, Any] = {
        "source": {"plugin": "pointcloud", "params": {"path": "scan.xyz", "gravity": "off"}},
        "output": {"metrics": False, "report": False},
    }
    if observers is not None:
        doc["observers"] = observers
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_observer_entry_point_registers_as_observer_kind(registry):
    info = registry.get("observers", "event_log")
    assert info.cls is EventLog and info.distribution == "acme-observers"
    assert [i.name for i in registry.observers()] == ["event_log", "misnamed", "rerun"]
    assert "event_log" not in {i.name for i in registry.all()}  # not a stage: not in the schema or data flow


def test_observer_follows_exactly_its_run(tmp_path, registry):
    validated = load_pipeline(
        _pipeline_file(tmp_path, [{"name": "event_log", "params": {"tag": "x"}}]), registry=registry
    )
    assert [o.config.tag for o in validated.observers] == ["x"]
    pipeline = Pipeline(validated, registry)
    pipeline.run(tmp_path / "out")
    (log,) = EventLog.instances
    assert log.events == ["start", "sources.pointcloud", "end"]
    assert log.closed == 1
    assert not registry.plugin_manager.is_registered(log)  # gone once the run is over
    Pipeline(validated, registry).run(tmp_path / "out")  # a second run gets a fresh observer
    assert len(EventLog.instances) == 2 and log.events == ["start", "sources.pointcloud", "end"]


def test_observer_is_closed_and_unregistered_after_a_failed_run(tmp_path, registry):
    path = _pipeline_file(tmp_path, [{"name": "event_log"}], cloud="not a point cloud\n")
    pipeline = Pipeline(load_pipeline(path, registry=registry), registry)
    with pytest.raises(DataError):
        pipeline.run(tmp_path / "out")
    (log,) = EventLog.instances
    assert log.events == ["start"] and log.closed == 1
    assert not registry.plugin_manager.is_registered(log)
    assert not (tmp_path / "out").exists()


def test_observer_with_a_wrong_hook_signature_fails_cleanly(tmp_path, registry):
    path = _pipeline_file(tmp_path, [{"name": "event_log"}, {"name": "misnamed"}])
    with pytest.raises(PluginError, match="observer 'misnamed' cannot be registered"):
        Pipeline(load_pipeline(path, registry=registry), registry).run(tmp_path / "out")
    (log,) = EventLog.instances
    assert log.closed == 1 and not registry.plugin_manager.is_registered(log)
    assert not (tmp_path / "out").exists()


def test_observe_adds_an_observer_that_set_can_configure(tmp_path, registry):
    path = _pipeline_file(tmp_path)
    validated = load_pipeline(path, ["observers[0].params.tag=cli"], registry, observe=["event_log", "event_log"])
    assert [(o.spec.name, o.config.tag) for o in validated.observers] == [("event_log", "cli")]
    listed = _pipeline_file(tmp_path, [{"name": "event_log"}])
    assert len(load_pipeline(listed, registry=registry, observe=["event_log"]).observers) == 1  # not twice


def test_unknown_observer_and_bad_params_are_named_by_key(tmp_path, registry):
    path = _pipeline_file(tmp_path, [{"name": "nope"}, {"name": "event_log", "params": {"tagg": 1}}])
    with pytest.raises(ConfigError) as err:
        load_pipeline(path, registry=registry)
    text = str(err.value)
    assert "observers[0].name: no observer named 'nope' (installed: event_log, misnamed, rerun)" in text
    assert "observers[1].params.tagg: extra field (not a parameter of this plugin)" in text


@parametrize_with_checks([EventLog])
def test_observer_conforms(stage_cls, check):
    check(stage_cls)


def _stratamap(*args: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stratamap.core.cli", *args], cwd=cwd, capture_output=True, text=True)


def test_cli_unknown_observer_is_one_line_exit_2(tmp_path):
    path = _pipeline_file(tmp_path)
    result = _stratamap("run", str(path), "--out", str(tmp_path / "out"), "--observe", "nope", cwd=REPO)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "observers[0].name: no observer named 'nope'" in result.stderr
    assert not (tmp_path / "out").exists()


def test_cli_plugins_lists_observers():
    result = _stratamap("plugins", "--json", cwd=REPO)
    entries = json.loads(result.stdout)
    assert {"kind": "observers", "name": "rerun"}.items() <= next(e for e in entries if e["name"] == "rerun").items()
