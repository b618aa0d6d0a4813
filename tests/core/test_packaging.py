"""The wheel contains every package folder; built-in plugins are not entry points."""

from __future__ import annotations

import ast
import tomllib

import pytest

from tests.conftest import REPO

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


def test_builtin_plugins_are_not_entry_points():
    """Built-ins are registered in code from one list; entry points are for third parties."""
    groups = PYPROJECT["project"].get("entry-points", {})
    assert not [g for g in groups if g.startswith("stratamap.")], groups


@pytest.mark.slow
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
