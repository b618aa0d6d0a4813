"""The command line: fast to start, clear errors, output folders that are never mixed or lost."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest
import yaml

from tests.conftest import REPO

HEAVY = ("open3d", "trimesh", "scipy.spatial", "networkx", "onnxruntime", "matplotlib")


def _stratamap(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", *args], cwd=cwd or REPO, capture_output=True, text=True
    )


def test_help_validate_and_plugins_load_no_heavy_library():
    """`stratamap --help`, `validate` and `plugins` answer in well under a second because they never
    import Open3D, trimesh or SciPy's spatial module (their import alone takes longer)."""
    code = (
        "import sys; from stratamap.core.config import load_pipeline; "
        f"load_pipeline({str(REPO / 'configs' / 'demo.yaml')!r}); "
        "from stratamap.core.cli import app; "
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_version():
    result = _stratamap("--version")
    assert result.returncode == 0 and result.stdout.startswith("stratamap ")


def test_unfilled_placeholder_is_named_by_key():
    result = _stratamap("validate", "configs/map_tum.yaml")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "source.params.path: still the placeholder REQUIRED" in result.stderr


def test_missing_input_is_named_by_key(tmp_path):
    result = _stratamap("validate", "configs/map_tum.yaml", "--set", f"source.params.path={tmp_path / 'nothing'}")
    assert result.returncode == 2 and "source.params.path:" in result.stderr and "does not exist" in result.stderr


def test_relative_paths_resolve_against_the_pipeline_file(tmp_path):
    from stratamap.core.config import load_pipeline

    folder = tmp_path / "pipelines"
    folder.mkdir()
    (tmp_path / "scan.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    doc = {"source": {"plugin": "pointcloud", "params": {"path": "../scan.xyz", "gravity": "off"}}}
    (folder / "p.yaml").write_text(yaml.safe_dump(doc))
    cwd = os.getcwd()
    os.chdir(REPO)  # the working folder plays no part
    try:
        v = load_pipeline(folder / "p.yaml")
        assert v.source.config.path == str(tmp_path / "scan.xyz")
        v = load_pipeline(folder / "p.yaml", ["source.params.path=configs/demo.yaml"])
        assert v.source.config.path == "configs/demo.yaml"  # --set values stay as typed
    finally:
        os.chdir(cwd)


def test_yaml_off_is_the_word_off(tmp_path):
    from stratamap.core.config import load_pipeline

    (tmp_path / "scan.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    (tmp_path / "p.yaml").write_text("source: {plugin: pointcloud, params: {path: scan.xyz, gravity: off}}\n")
    assert load_pipeline(tmp_path / "p.yaml").source.config.gravity == "off"


@pytest.mark.slow
@pytest.mark.parametrize(
    "command", [["synth", "configs/scenes/office.yaml", "--frames", "2"], ["models", "build", "-n", "1"]]
)
def test_commands_never_empty_a_folder_they_did_not_write(tmp_path, command):
    keep = tmp_path / "mine.txt"
    keep.write_text("a user's file")
    result = _stratamap(*command, "--out", str(tmp_path))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "holds files that are not" in result.stderr
    assert keep.read_text() == "a user's file" and sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_out_naming_a_file_is_an_error(tmp_path):
    target = tmp_path / "report.txt"
    target.write_text("x")
    result = _stratamap("run", "configs/demo.yaml", "--out", str(target))
    assert result.returncode == 2 and "is a file, not a folder" in result.stderr and "Traceback" not in result.stderr
    assert target.read_text() == "x"


@pytest.mark.slow  # a whole pipeline run (make test runs it; make test-fast does not)
def test_a_failing_run_leaves_no_folder_and_the_previous_output_intact(tmp_path):
    """A run is staged beside its output folder and swapped in at the end: a source that fails
    creates nothing, and a failed re-run leaves the earlier output exactly as it was."""
    scan = tmp_path / "scan.xyz"
    scan.write_text("\n".join(f"{x * 0.1} {y * 0.1} 0" for x in range(20) for y in range(20)) + "\n")
    pipeline = tmp_path / "p.yaml"
    doc = {
        "source": {"plugin": "pointcloud", "params": {"path": "scan.xyz", "gravity": "off"}},
        "stages": [{"plugin": "points"}],
    }
    pipeline.write_text(yaml.safe_dump(doc))
    out = tmp_path / "out" / "run"
    old_umask = os.umask(0o022)
    try:
        assert _stratamap("run", str(pipeline), "--out", str(out)).returncode == 0
    finally:
        os.umask(old_umask)
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert (out / "report.json").is_file() and (out / "map" / "manifest.json").is_file()
    for path in [out, out / "map", out / "report.json", out / "map" / "geometry.npz"]:
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode == (0o755 if path.is_dir() else 0o644), (path, oct(mode))

    scan.write_text("0 0\n")  # now unreadable: the re-run fails in its source
    failed = _stratamap("run", str(pipeline), "--out", str(out))
    assert failed.returncode == 2 and "Traceback" not in failed.stderr
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert sorted(p.name for p in out.parent.iterdir()) == ["run"]  # no staging folder left behind

    fresh = tmp_path / "new" / "deeper"
    assert _stratamap("run", str(pipeline), "--out", str(fresh)).returncode == 2
    assert not (tmp_path / "new").exists()


@pytest.mark.slow  # a whole pipeline run (make test runs it; make test-fast does not)
def test_rerun_replaces_the_whole_output(tmp_path):
    scan = tmp_path / "scan.xyz"
    scan.write_text("\n".join(f"{x * 0.1} {y * 0.1} 0" for x in range(20) for y in range(20)) + "\n")
    pipeline = tmp_path / "p.yaml"
    doc = {
        "source": {"plugin": "pointcloud", "params": {"path": "scan.xyz", "gravity": "off"}},
        "stages": [{"plugin": "points"}, {"plugin": "ply"}],
    }
    pipeline.write_text(yaml.safe_dump(doc))
    out = tmp_path / "out"
    assert _stratamap("run", str(pipeline), "--out", str(out)).returncode == 0
    assert any((out / "export").iterdir())
    doc["stages"] = [{"plugin": "points"}]
    pipeline.write_text(yaml.safe_dump(doc))
    assert _stratamap("run", str(pipeline), "--out", str(out)).returncode == 0
    assert not (out / "export").exists()  # nothing of the earlier run's exports is left beside the new output
    report = json.loads((out / "report.json").read_text())
    assert [s["plugin"] for s in report["stages"]] == ["pointcloud", "points"]


@pytest.mark.parametrize("command", [["plugins"], ["schema"], ["validate", "configs/demo.yaml"]])
def test_two_plugins_with_one_name_is_a_clean_error(tmp_path, command):
    plugin = tmp_path / "impostor.py"
    plugin.write_text(
        "from stratamap.core import Completer, hookimpl\n\n\n"
        "class Impostor(Completer):\n"
        '    """Claims a built-in name."""\n\n'
        '    name = "bbox"\n\n\n'
        "@hookimpl\n"
        "def stratamap_register_completers():\n"
        "    return [Impostor]\n"
    )
    env = {**os.environ, "STRATAMAP_PLUGINS": str(plugin)}
    result = subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", *command], cwd=REPO, capture_output=True, text=True, env=env
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "two completers plugins are named 'bbox'" in result.stderr


@pytest.mark.slow
def test_a_killed_run_leaves_the_output_intact_and_its_staging_is_swept(tmp_path):
    """SIGKILL in the middle of a run: the output folder keeps the earlier run, and the next run
    removes the killed run's staging folder."""
    import signal
    import time

    out = tmp_path / "out"
    assert (
        _stratamap(
            "run", "configs/demo.yaml", "--out", str(out), "--set", "source.params.scene.trajectory.frames=8"
        ).returncode
        == 0
    )
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    proc = subprocess.Popen(
        [sys.executable, "-m", "stratamap.core.cli", "run", "configs/demo.yaml", "--out", str(out)],
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not list(tmp_path.glob(".out.*.staging")):
        time.sleep(0.02)
    time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert list(tmp_path.glob(".out.*.staging"))
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert (
        _stratamap(
            "run", "configs/demo.yaml", "--out", str(out), "--set", "source.params.scene.trajectory.frames=8"
        ).returncode
        == 0
    )
    assert not list(tmp_path.glob(".out.*.staging"))
