"""Plugin discovery with fake entry points: third-party, broken, duplicate, autoload, local modules."""

from __future__ import annotations

import os
import sys
import textwrap
import types
from importlib.metadata import EntryPoint

import pytest

from stratamap.core import Completer, hookimpl
from stratamap.core.errors import PluginError
from stratamap.core.registry import build_registry


class _Dist:
    def __init__(self, name: str):
        self.name = name


def ep(name: str, value: str, group: str, dist: str) -> EntryPoint:
    return EntryPoint(name=name, value=value, group=group)._for(_Dist(dist))


class FancyCompleter(Completer):
    """A third-party completer."""

    name = "fancy"

    def complete(self, data):
        return {"instances": data.map.instances.copy()}


class ImpostorCompleter(Completer):
    """Another completer that claims the bbox name."""

    name = "bbox"

    def complete(self, data):
        return {"instances": data.map.instances.copy()}


@pytest.fixture
def third_party_module():
    mod = types.ModuleType("acme_fancy")

    @hookimpl
    def stratamap_register_completers():
        return [FancyCompleter]

    mod.stratamap_register_completers = stratamap_register_completers
    sys.modules["acme_fancy"] = mod
    yield "acme_fancy"
    del sys.modules["acme_fancy"]


def test_builtins_register_in_code_without_entry_points():
    reg = build_registry(eps=[], extra_modules=[], autoload=True)
    kinds = {info.kind for info in reg.all()}
    assert kinds == {"sources", "segmenters", "mappers", "completers", "exporters"}
    assert reg.get("completers", "bbox").distribution == "stratamap"
    assert not reg.failures


def test_without_builtins_only_entry_points_register(third_party_module):
    eps = [ep("fancy", third_party_module, "stratamap.completers", "acme-fancy")]
    reg = build_registry(eps=eps, extra_modules=[], autoload=True, builtins=False)
    assert [info.name for info in reg.all()] == ["fancy"]


def test_a_third_party_plugin_adds_a_metric_family(tmp_path):
    from stratamap.core.pipeline import evaluate
    from stratamap.core.stages import PipelineData

    mod = types.ModuleType("acme_metrics")

    @hookimpl
    def stratamap_evaluate(data, details):
        return {"acme": {"frames": 0 if data.stream is None else len(data.stream), "details": details}}

    mod.stratamap_evaluate = stratamap_evaluate
    sys.modules["acme_metrics"] = mod
    try:
        reg = build_registry(
            eps=[ep("acme", "acme_metrics", "stratamap.mappers", "acme-metrics")], extra_modules=[], autoload=True
        )
    finally:
        del sys.modules["acme_metrics"]
    metrics = evaluate(reg.hook, PipelineData(), details=True)
    assert metrics == {"acme": {"frames": 0, "details": True}}  # no ground truth: no built-in family applies


def test_third_party_plugin_is_listed_with_its_distribution(third_party_module):
    eps = [ep("fancy", third_party_module, "stratamap.completers", "acme-fancy")]
    reg = build_registry(eps=eps, extra_modules=[], autoload=True)
    info = reg.get("completers", "fancy")
    assert info.cls is FancyCompleter and info.distribution == "acme-fancy"
    assert info.to_dict()["description"] == "A third-party completer."


def test_entry_point_may_name_a_stage_class():
    eps = [ep("fancy", f"{__name__}:FancyCompleter", "stratamap.completers", "acme-fancy")]
    reg = build_registry(eps=eps, extra_modules=[], autoload=True)
    assert reg.get("completers", "fancy").cls is FancyCompleter


def test_broken_plugin_is_reported_and_the_rest_loads():
    eps = [ep("broken", "acme_does_not_exist.plugin", "stratamap.mappers", "acme-broken")]
    reg = build_registry(eps=eps, extra_modules=[], autoload=True)
    assert reg.get("completers", "bbox")
    assert len(reg.failures) == 1
    text = str(reg.failures[0])
    assert "acme-broken" in text and "broken" in text and "ModuleNotFoundError" in text
    with pytest.raises(PluginError, match="acme-broken"):
        reg.get("mappers", "broken")


def test_duplicate_names_are_an_error_naming_both():
    eps = [ep("bbox2", f"{__name__}:ImpostorCompleter", "stratamap.completers", "acme-impostor")]
    with pytest.raises(PluginError) as exc:
        build_registry(eps=eps, extra_modules=[], autoload=True)
    msg = str(exc.value)
    assert "'bbox'" in msg and "stratamap.plugins.completers.bbox" in msg and "ImpostorCompleter" in msg
    assert "acme-impostor" in msg and "distribution stratamap" in msg


def test_autoload_off_skips_third_party(third_party_module, monkeypatch):
    eps = [ep("fancy", third_party_module, "stratamap.completers", "acme-fancy")]
    monkeypatch.setenv("STRATAMAP_DISABLE_PLUGIN_AUTOLOAD", "1")
    reg = build_registry(eps=eps, extra_modules=[])
    assert "fancy" not in reg.stages["completers"]
    assert "bbox" in reg.stages["completers"]


def test_unpackaged_module_from_environment(tmp_path, monkeypatch):
    plugin = tmp_path / "my_local_plugin.py"
    plugin.write_text(
        textwrap.dedent(
            '''
            from stratamap.core import Completer, hookimpl

            class LocalCompleter(Completer):
                """Loaded from a file path."""
                name = "local"
                def complete(self, data):
                    return {"instances": data.map.instances.copy()}

            @hookimpl
            def stratamap_register_completers():
                return [LocalCompleter]
            '''
        )
    )
    monkeypatch.setenv("STRATAMAP_PLUGINS", f"{plugin},not_a_module_anywhere")
    reg = build_registry(eps=[])
    assert reg.get("completers", "local").distribution == "<STRATAMAP_PLUGINS>"
    assert any("not_a_module_anywhere" in str(f) for f in reg.failures)


def test_installed_registry_has_every_kind():
    from stratamap.core.registry import default_registry

    reg = default_registry(refresh=True)
    assert {i.kind for i in reg.all()} >= {"sources", "segmenters", "mappers", "completers", "exporters"}


def test_a_plugin_that_imports_heavy_libraries_at_load_time_is_named(tmp_path):
    """A third-party plugin that imports trimesh at module level slows every command; `plugins`
    names it and says how to fix it, while a lazily importing one gets no note."""
    import subprocess

    eager = tmp_path / "eager_plugin.py"
    eager.write_text("import trimesh  # noqa: F401\n")
    lazy = tmp_path / "lazy_plugin.py"
    lazy.write_text("from stratamap.core.lazy import lazy_module\n\ntrimesh = lazy_module('trimesh')\n")
    results = {}
    for plugin in (eager, lazy):
        env = {**os.environ, "STRATAMAP_PLUGINS": str(plugin)}
        cmd = [sys.executable, "-m", "stratamap.core.cli", "plugins", "--json"]
        results[plugin.name] = subprocess.run(cmd, capture_output=True, text=True, env=env)
    assert results["eager_plugin.py"].returncode == 0
    note = [line for line in results["eager_plugin.py"].stderr.splitlines() if line.startswith("note:")]
    assert (
        len(note) == 1 and "imports trimesh" in note[0] and "when it is loaded" in note[0] and "lazy_module" in note[0]
    )
    assert results["lazy_plugin.py"].returncode == 0 and "note:" not in results["lazy_plugin.py"].stderr
