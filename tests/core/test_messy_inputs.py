"""Real recordings are messy (issue 69), framework side: a config that is not UTF-8, a pipeline
that validates but could not run, an output folder behind a link or that cannot be written, and a
Ctrl-C at any point each end in one line and the previous output untouched."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from stratamap.core.documents import read_mapping
from stratamap.core.errors import ConfigError, DataError
from tests.conftest import REPO

LATIN1 = b"source: {plugin: synthetic}  # caf\xe9\nstages: []\n"


def _default_sigint() -> None:
    # A suite started in the background of a shell without job control inherits SIGINT ignored:
    # the command must see Ctrl-C as it does in a terminal.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _stratamap(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "stratamap.core.cli", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        preexec_fn=_default_sigint,
    )


def _one_error_line(result: subprocess.CompletedProcess) -> str:
    """The one line saying why a command failed (stderr also carries the stages' progress)."""
    lines = [line for line in result.stderr.splitlines() if line.startswith(("error:", "interrupted:"))]
    assert "Traceback" not in result.stderr, result.stderr
    assert len(lines) == 1 and lines[0] == result.stderr.rstrip("\n").splitlines()[-1], result.stderr
    return lines[0]


# ------------------------------------------------------------------------------ 1. not UTF-8


@pytest.mark.parametrize(
    "command",
    [
        ["validate", "{file}"],
        ["run", "{file}", "--out", "{out}"],
        ["bench", "{file}", "--out", "{out}"],
        ["synth", "{file}", "--out", "{out}"],
    ],
    ids=lambda c: c[0],
)
@pytest.mark.parametrize("content", [LATIN1, bytes(range(128, 256)) * 3], ids=["latin1", "random"])
def test_a_file_that_is_not_utf8_is_one_line_naming_the_file_and_offset(tmp_path, command, content):
    config = tmp_path / "config.yaml"
    config.write_bytes(content)
    out = tmp_path / "out"
    result = _stratamap(*[arg.format(file=config, out=out) for arg in command])
    assert result.returncode == 2
    line = _one_error_line(result)
    offset = content.index(b"\xe9") if content is LATIN1 else 0
    assert str(config) in line and f"at offset {offset}" in line and "UTF-8" in line
    assert not out.exists()


def test_the_reader_names_line_and_column_and_takes_a_bom(tmp_path):
    from stratamap.core.documents import read_data_text, read_text

    path = tmp_path / "p.yaml"
    path.write_bytes(b"a: 1\nb: \xff\n")
    with pytest.raises(
        ConfigError, match=r"p\.yaml: not a text file in UTF-8: byte 0xff at offset 8 \(line 2, column 4\)"
    ):
        read_text(path, "pipeline file")
    with pytest.raises(DataError, match=r"p\.yaml: not a text file in UTF-8"):
        read_data_text(path)
    path.write_bytes(b"\xef\xbb\xbfa: 1\n")  # what Windows editors write first
    assert read_mapping(path, "pipeline file") == {"a": 1}


def test_a_model_library_class_table_in_latin1_is_a_data_error(tmp_path):
    from stratamap.core.library.models import ModelLibrary

    (tmp_path / "chair.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "classes.csv").write_bytes("file,class\nchair.obj,chaise longue é\n".encode("latin-1"))
    with pytest.raises(DataError, match=r"classes\.csv: not a text file in UTF-8: byte 0xe9"):
        ModelLibrary.load(tmp_path)


@pytest.mark.parametrize(
    "text, message",
    [
        ("a: &a [*a]\n", "a YAML anchor is used inside itself"),
        ("a: " + "[" * 60 + "]" * 60 + "\n", "nested more than 50 levels deep"),
        ("a: " + "[" * 3000 + "]" * 3000 + "\n", "nested too deeply"),
        ("source: {plugin: x\n", "not valid YAML at line 2, column 1"),
        (
            "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
            + "".join(f"{k}: &{k} [{', '.join([f'*{p}'] * 10)}]\n" for p, k in zip("abcdef", "bcdefg", strict=True)),
            "its aliases expand to more than",
        ),
    ],
    ids=["self-reference", "deep", "deeper-than-the-parser", "unclosed", "billion-laughs"],
)
def test_yaml_that_no_document_can_be_is_one_line(tmp_path, text, message):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        read_mapping(path, "pipeline file")
    assert message in str(info.value) and "\n" not in str(info.value)


def test_a_nul_in_a_source_path_is_a_problem_of_its_key(tmp_path):
    from stratamap.core.config import load_pipeline

    (tmp_path / "p.yaml").write_text('source: {plugin: pointcloud, params: {path: "a\\0b"}}\n')
    with pytest.raises(ConfigError, match=r"source\.params\.path: not a valid path"):
        load_pipeline(tmp_path / "p.yaml")


# ------------------------------------------------------------------------------ 2. data flow


def test_a_stage_that_only_updates_a_layer_does_not_provide_it(tmp_path):
    """physical_check adjusts the contact graph when there is one: without contact_graph before it,
    scene_graph has none, and validate says so instead of the run failing in scene_graph."""
    from stratamap.core.config import load_pipeline

    doc = {
        "source": {"plugin": "synthetic"},
        "stages": [{"plugin": "oracle"}, {"plugin": "tsdf"}, {"plugin": "physical_check"}, {"plugin": "scene_graph"}],
    }
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as info:
        load_pipeline(tmp_path / "p.yaml")
    assert "stages[3].plugin: stage 'scene_graph' requires layer 'contact_graph'" in str(info.value)
    assert "physical_check" not in str(info.value).split("could provide it:")[1]
    doc["stages"].insert(2, {"plugin": "contact_graph"})
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    assert [s.spec.plugin for s in load_pipeline(tmp_path / "p.yaml").stages][-1] == "scene_graph"


def _scan_pipeline(tmp_path: Path, stages: list[dict]) -> Path:
    scan = tmp_path / "scan.xyz"
    scan.write_text("\n".join(f"{x * 0.1} {y * 0.1} 0" for x in range(10) for y in range(10)) + "\n")
    doc = {
        "source": {"plugin": "pointcloud", "params": {"path": "scan.xyz", "gravity": "off"}},
        "stages": stages,
        "output": {"save_map": False, "metrics": False},
    }
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text(yaml.safe_dump(doc))
    return pipeline


PLUGINS = '''
import signal

from stratamap.core import Mapper, hookimpl


class Empty(Mapper):
    """Declares a contact graph and makes none."""

    name = "empty_graph"
    requires = frozenset({"frames"})
    provides = frozenset({"contact_graph"})

    def map(self, data):
        return {}


class Swallowed(Mapper):
    """Ctrl-C in library code that swallows it."""

    name = "swallowed_interrupt"
    requires = frozenset({"frames"})

    def map(self, data):
        try:
            signal.raise_signal(signal.SIGINT)
            for _ in range(1000):
                pass
        except BaseException:
            pass
        return {}


class Interrupted(Mapper):
    """Ctrl-C while a stage runs."""

    name = "interrupted"
    requires = frozenset({"frames"})

    def map(self, data):
        signal.raise_signal(signal.SIGINT)
        return {}


@hookimpl
def stratamap_register_mappers():
    return [Empty, Swallowed, Interrupted]
'''


@pytest.fixture
def plugins_env(tmp_path) -> dict[str, str]:
    path = tmp_path / "messy_plugins.py"
    path.write_text(PLUGINS)
    return {"STRATAMAP_PLUGINS": str(path)}


def test_a_layer_declared_but_not_made_is_one_line_at_run_time(tmp_path, plugins_env):
    pipeline = _scan_pipeline(tmp_path, [{"plugin": "empty_graph"}, {"plugin": "scene_graph"}])
    assert _stratamap("validate", str(pipeline), env=plugins_env).returncode == 0
    out = tmp_path / "out"
    result = _stratamap("run", str(pipeline), "--out", str(out), env=plugins_env)
    assert result.returncode == 2
    line = _one_error_line(result)
    assert "stages[1].plugin: stage 'scene_graph' requires layer 'contact_graph'" in line and "empty_graph" in line
    assert not out.exists()


# ------------------------------------------------------------------------------ 3. output folders


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_symlinked_out_is_written_through(tmp_path):
    pipeline = _scan_pipeline(tmp_path, [])
    real = tmp_path / "runs" / "first"
    assert _stratamap("run", str(pipeline), "--out", str(real)).returncode == 0
    (real / "report.json").write_text("{}")  # stale: the next run must replace it
    link = tmp_path / "latest"
    link.symlink_to(real)
    result = _stratamap("run", str(pipeline), "--out", str(link))
    assert result.returncode == 0, result.stderr
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert json.loads((real / "report.json").read_text())["stages"][0]["plugin"] == "pointcloud"
    assert sorted(p.name for p in real.parent.iterdir()) == ["first"]  # no staging or backup left


def _immutable(path: Path) -> bool:
    return shutil.which("chattr") is not None and subprocess.run(["chattr", "+i", str(path)]).returncode == 0


def test_an_output_that_cannot_be_written_fails_before_any_stage(tmp_path, plugins_env):
    """An earlier output that is immutable (read-only for a user) is refused at once, not once the
    whole pipeline ran into a hidden staging folder. (A read-only parent already failed at once:
    the staging folder is made there first.)"""
    # The stage would interrupt the run: reaching it shows the check came too late.
    pipeline = _scan_pipeline(tmp_path, [{"plugin": "interrupted"}])
    out = tmp_path / "parent" / "out"
    out.mkdir(parents=True)
    locked = out
    if os.geteuid() == 0:
        if not _immutable(locked):
            pytest.skip("root ignores read-only modes and chattr +i is not available")
    else:
        locked.chmod(0o555)
    try:
        result = _stratamap("run", str(pipeline), "--out", str(out), env=plugins_env)
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(locked)], check=True)
        locked.chmod(0o755)
    assert result.returncode == 2
    assert f"cannot write {out}" in _one_error_line(result) and "staging" not in result.stderr
    assert sorted(p.name for p in out.parent.iterdir()) == ["out"]


@pytest.mark.parametrize("stage", ["interrupted", "swallowed_interrupt"])
def test_ctrl_c_leaves_the_previous_output_and_exits_130(tmp_path, plugins_env, stage):
    """Ctrl-C while a stage runs, also when the stage's code swallows the KeyboardInterrupt: the
    run stops with one line and status 130, and the previous output is as it was."""
    out = tmp_path / "out"
    assert _stratamap("run", str(_scan_pipeline(tmp_path, [])), "--out", str(out)).returncode == 0
    before = _files(out)
    pipeline = _scan_pipeline(tmp_path, [{"plugin": stage}, {"plugin": "points"}])
    result = _stratamap("run", str(pipeline), "--out", str(out), env=plugins_env)
    assert result.returncode == 130, result.stderr
    assert _one_error_line(result).startswith("interrupted:")
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_ctrl_c_swallowed_inside_an_atomic_directory_still_stops_it(tmp_path):
    from stratamap.core.atomic import atomic_directory

    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    # As in a terminal, whatever this test process inherited (xdist workers, background shells).
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), atomic_directory(out) as staging:
            (staging / "new.txt").write_text("new")
            try:
                signal.raise_signal(signal.SIGINT)
                for _ in range(1000):
                    pass
            except KeyboardInterrupt:
                pass  # what a library's bare except does
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the guard is gone
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
