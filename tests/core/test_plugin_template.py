"""The plugin template, installed: stratamap finds it, and `plugins` and `validate` still load no
heavy library (the template imports trimesh on first use, as the built-in stages do)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import REPO
from tests.core.test_cli import HEAVY

TEMPLATE = REPO / "examples" / "plugin-template"


def test_the_installed_template_loads_no_heavy_library(tmp_path):
    # Installed as pip would leave it (a dist-info declaring its entry point on the path), without
    # touching the environment the suite runs in.
    dist = tmp_path / "site" / "stratamap_hull-0.1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: stratamap-hull\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text("[stratamap.completers]\nhull = stratamap_hull\n")
    code = (
        "import json, sys; from stratamap.core.config import load_pipeline; "
        "from stratamap.core.registry import default_registry; "
        f"v = load_pipeline({str(REPO / 'configs' / 'demo.yaml')!r}, ['stages[2].plugin=hull']); "
        "from stratamap.core.cli import app; "
        "hull = default_registry().get('completers', 'hull'); "
        f"heavy = [m for m in {HEAVY!r} if m in sys.modules]; "
        "print(json.dumps([v.stages[2].info.distribution, hull.distribution, heavy]))"
    )
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(tmp_path / "site"), str(TEMPLATE), os.environ.get("PYTHONPATH", "")]),
    }
    env.pop("STRATAMAP_DISABLE_PLUGIN_AUTOLOAD", None)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout) == ["stratamap-hull", "stratamap-hull", []]


@pytest.mark.slow
def test_the_template_completes_with_trimesh_once_it_runs():
    """The lazy import is no stub: the stage does load trimesh and make hulls when it runs."""
    code = (
        "import sys; from stratamap_hull import HullCompleter; from stratamap.core.testing import example_data; "
        "before = 'trimesh' in sys.modules; "
        "out = HullCompleter().complete(example_data({'instances'}))['instances']; "
        "print(before, 'trimesh' in sys.modules, all(i.completion.mesh.is_watertight for i in out.completed()), "
        "len(out.completed()) > 0)"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TEMPLATE), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert result.stdout.split() == ["False", "True", "True", "True"]
