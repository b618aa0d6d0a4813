"""The three rules of the source tree (see docs/architecture.md), checked on the code itself:

1. ``core/`` root is the framework; nothing in ``core/`` imports a plugin or the CLI, and domain
   subpackages depend downwards only: evaluation -> library, synthetic, simulation, io -> map ->
   geometry -> errors, atomic.
2. An algorithm lives beside the stage that uses it; no plugin imports another plugin (code shared
   by stages of one kind is an underscore module of that kind).
3. Every non-underscore entry of ``plugins/<kind>/`` registers exactly one stage (of ``plugins/observers/``:
   exactly one observer), named like the entry.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from stratamap.core.registry import PLUGIN_KINDS, build_registry
from tests.conftest import REPO

PACKAGES = {"core": "stratamap.core", "plugins": "stratamap.plugins"}

#: Rank of each part of core/: a module may import only modules of its own rank or lower.
CORE_RANKS = {
    "errors": 0,
    "atomic": 0,
    "paths": 0,
    "documents": 0,
    "lazy": 0,
    "parallel": 0,
    "geometry": 1,
    "map": 2,
    "io": 3,
    "simulation": 3,
    "library": 3,
    "synthetic": 3,
    "furniture": 3,
    # the framework: stage protocols carry map layers; the kit and pipeline run stages
    "hookspecs": 4,
    "stages": 4,
    "registry": 4,
    "config": 4,
    "schema": 4,
    "pipeline": 4,
    "checkpoints": 4,
    "testing": 4,
    "evaluation": 5,
    "viewer": 5,
    "cli": 6,
}


def _module_name(path: Path) -> str:
    top, *rest = path.relative_to(REPO).with_suffix("").parts
    parts = [PACKAGES[top], *rest]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """Every module ``path`` imports, at module level or inside functions."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [(node.lineno, node.module)]
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]  # `from pkg import module`
    return [(line, name) for line, name in out if name.startswith("stratamap.")]


def _sources(top: str) -> list[Path]:
    return sorted(p for p in (REPO / top).rglob("*.py") if "__pycache__" not in p.parts)


def _core_part(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "core" else None


def test_core_imports_no_plugin_and_not_the_cli():
    offenders = []
    for path in _sources("core"):
        if path.name == "cli.py" and path.parent == REPO / "core":
            continue
        for line, name in _imports(path):
            if name.startswith(("stratamap.plugins", "stratamap.core.cli")):
                offenders.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    assert not offenders, offenders


def test_core_dependencies_point_down():
    offenders = []
    for path in _sources("core"):
        me = (
            _core_part(_module_name(path) + ".x")
            if path.name != "__init__.py" or path.parent != REPO / "core"
            else None
        )
        if me is None:
            continue
        assert me in CORE_RANKS, f"core/{me} has no rank: place it in CORE_RANKS (and docs/architecture.md)"
        for line, name in _imports(path):
            other = _core_part(name)
            if other in CORE_RANKS and CORE_RANKS[other] > CORE_RANKS[me]:
                offenders.append(f"{path.relative_to(REPO)}:{line} ({me}) imports {name} ({other})")
    assert not offenders, offenders


def _plugin_entry(module: str) -> tuple[str, str] | None:
    """(kind, entry) of a module under stratamap.plugins, e.g. ('mappers', 'tsdf')."""
    parts = module.split(".")
    if len(parts) < 4 or parts[1] != "plugins":
        return None
    return parts[2], parts[3]


def test_no_plugin_imports_another_plugin():
    offenders = []
    for path in _sources("plugins"):
        mine = _plugin_entry(_module_name(path) + ".x")
        if mine is None:
            continue
        for line, name in _imports(path):
            other = _plugin_entry(name)
            if other is None or other == mine:
                continue
            shared = other[0] == mine[0] and other[1].startswith("_")
            if not shared:
                offenders.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    assert not offenders, offenders


def _entries(kind: str) -> list[str]:
    folder = REPO / "plugins" / kind
    names = [p.stem for p in folder.glob("*.py")] + [p.name for p in folder.iterdir() if (p / "__init__.py").exists()]
    return sorted(n for n in names if not n.startswith("_"))


def test_every_plugin_folder_is_a_kind():
    folders = sorted(p.name for p in (REPO / "plugins").iterdir() if (p / "__init__.py").exists())
    assert folders == sorted(PLUGIN_KINDS)


@pytest.mark.parametrize("kind", PLUGIN_KINDS)
def test_each_plugin_entry_registers_exactly_one_stage(kind):
    registry = build_registry(eps=[], extra_modules=[], autoload=True)
    by_module: dict[str, list[str]] = {}
    for info in registry.stages[kind].values():
        by_module.setdefault(info.module, []).append(info.name)
    for entry in _entries(kind):
        module = f"stratamap.plugins.{kind}.{entry}"
        assert by_module.get(module) == [entry], f"{module} registers {by_module.get(module)}"
    assert sorted(by_module) == [f"stratamap.plugins.{kind}.{e}" for e in _entries(kind)]
