"""The wheel contains every package folder, and built-in plugins are declared as entry points."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

from stratamap.core.registry import BUILTIN_PLUGINS, group_name

REPO = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
MAPPING = {"core": "stratamap.core", "plugins": "stratamap.plugins"}


def _packages_on_disk() -> set[str]:
    found = set()
    for top, namespace in MAPPING.items():
        for init in (REPO / top).rglob("__init__.py"):
            rel = init.parent.relative_to(REPO / top)
            found.add(".".join([namespace, *rel.parts]) if rel.parts else namespace)
    return found


def test_package_list_matches_folders():
    setuptools = PYPROJECT["tool"]["setuptools"]
    assert setuptools["package-dir"] == {v: k for k, v in MAPPING.items()}
    assert set(setuptools["packages"]) == _packages_on_disk()


def test_every_python_folder_is_a_package():
    for top in MAPPING:
        for py in (REPO / top).rglob("*.py"):
            assert (py.parent / "__init__.py").exists(), f"{py.parent} has modules but no __init__.py"


def test_builtin_plugins_are_declared_as_entry_points():
    declared = PYPROJECT["project"]["entry-points"]
    for kind, modules in BUILTIN_PLUGINS.items():
        group = declared[group_name(kind)]
        assert sorted(group.values()) == sorted(modules)
        for name, module in group.items():
            assert module.rsplit(".", 1)[1] == name


def test_no_bare_core_or_plugins_imports():
    offenders = []
    for folder in ("core", "plugins", "tests", "benchmarks", "examples"):
        for py in (REPO / folder).rglob("*.py"):
            tree = ast.parse(py.read_text(), filename=str(py))
            for node in ast.walk(tree):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                for n in names:
                    if n.split(".")[0] in ("core", "plugins"):
                        offenders.append(f"{py.relative_to(REPO)}:{node.lineno} imports {n}")
    assert not offenders, offenders


def test_one_stage_per_plugin_module():
    from stratamap.core.registry import build_registry, builtin_entry_points

    registry = build_registry(eps=builtin_entry_points(), extra_modules=[], autoload=True)
    modules = [info.cls.__module__ for info in registry.all()]
    assert len(modules) == len(set(modules))
