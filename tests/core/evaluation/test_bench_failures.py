"""A benchmark run that fails costs only itself: its error is listed in results.json/.md and the other
runs' results are written; a worker process that dies fails only its scene; Ctrl-C stops the bench."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import threading
import time
from pathlib import Path

import pytest
import yaml

from stratamap.core.errors import DataError
from stratamap.core.evaluation.bench import failure_path, one_line, record_path, run_bench
from tests.conftest import REPO

EMPTY = "stages[1].params.depth_max=0.11"  # the schema accepts it; no frame sees anything that near


def bench_file(tmp_path: Path, variants: list[dict], seeds=(3,)) -> Path:
    doc = {
        "name": "failures",
        "scenes": [
            {
                "synthetic": {
                    "scene_file": str(REPO / "configs/scenes/office.yaml"),
                    "seeds": list(seeds),
                    "frames": 4,
                    "camera": {"width": 160, "height": 120},
                }
            }
        ],
        "pipeline": {"stages": [{"plugin": "oracle"}, {"plugin": "tsdf", "params": {"voxel_size": 0.08}}]},
        "physics": False,
        "variants": variants,
    }
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_one_line_errors():
    assert one_line(DataError("tsdf: no frame\nat all")) == "tsdf: no frame; at all"
    assert (
        one_line(RuntimeError("\x1b[1;31m[Open3D Error] No block\x1b[0;m\n")) == "RuntimeError: [Open3D Error] No block"
    )
    assert len(one_line(ValueError("x" * 1000))) == 300


@pytest.mark.slow  # a whole benchmark or CLI run
def test_a_failing_variant_is_listed_and_the_others_results_are_written(tmp_path):
    """The variant whose TSDF sees nothing used to kill the worker: no results.json, no results.md."""
    config = bench_file(tmp_path, [{"name": "good"}, {"name": "empty", "set": [EMPTY]}])
    out = tmp_path / "out"
    summary = run_bench(config, out, progress=False)
    results = json.loads((out / "results.json").read_text())
    assert [(r["scene"], r["variant"]) for r in results["records"]] == [("office-s3", "good")]
    (failure,) = results["failures"]
    assert failure["scene"] == "office-s3" and failure["variant"] == "empty" and failure["stage"] == "stages[1]:tsdf"
    assert failure["error"].startswith("tsdf: no usable RGB-D frame in its 4 frames") and "\n" not in failure["error"]
    assert summary["records"] == 1 and summary["ran"] == 2
    assert summary["failed"] == [f"office-s3 / empty failed at stages[1]:tsdf: {failure['error']}"]
    md = (out / "results.md").read_text()
    assert "## failed runs" in md and f"| office-s3 | empty | stages[1]:tsdf | {failure['error']} |" in md
    assert "Failed: 1 of 2 runs" in md and "| metric | good | empty |" in md
    assert "failed runs" in (out / "report.html").read_text()
    assert (out / "runs" / "office-s3" / "good" / "report.html").is_file()
    assert not (out / "runs" / "office-s3" / "empty").exists()
    # The next bench tries the failure again, and only it.
    good = record_path(out, "office-s3", "good").stat().st_mtime_ns
    again = run_bench(config, out, progress=False)
    assert again["ran"] == 1 and again["records"] == 1 and len(again["failed"]) == 1
    assert record_path(out, "office-s3", "good").stat().st_mtime_ns == good


@pytest.mark.slow  # a whole benchmark or CLI run
def test_a_bench_whose_every_run_failed_is_an_error_after_writing_why(tmp_path):
    config = bench_file(tmp_path, [{"name": "near", "set": [EMPTY]}])
    out = tmp_path / "out"
    with pytest.raises(DataError, match=r"^bench failures: all 1 runs failed \(office-s3 / near failed at stages"):
        run_bench(config, out, progress=False)
    assert json.loads((out / "results.json").read_text())["failures"][0]["variant"] == "near"
    assert "| office-s3 | near | stages[1]:tsdf |" in (out / "results.md").read_text()


def _when_a_worker_starts(act) -> threading.Thread:
    """``act(worker)`` once the bench has started a worker process (from a thread, as a user would)."""

    def watch():
        while True:
            workers = [p for p in multiprocessing.active_children() if p.name.startswith("bench ")]
            if workers:
                act(workers[0])
                return
            time.sleep(0.02)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.slow  # two scenes, a worker process each
def test_a_worker_that_dies_fails_its_scene_only(tmp_path):
    """A worker killed by the system (out of memory) used to break the whole pool: no results at all."""
    config = bench_file(tmp_path, [{"name": "good"}], seeds=(3, 4))
    out = tmp_path / "out"
    killed: list[str] = []

    def kill(worker):
        killed.append(worker.name)
        os.kill(worker.pid, signal.SIGKILL)

    watcher = _when_a_worker_starts(kill)
    summary = run_bench(config, out, progress=False)
    watcher.join()
    assert killed == ["bench office-s3"]
    results = json.loads((out / "results.json").read_text())
    assert [(r["scene"], r["variant"]) for r in results["records"]] == [("office-s4", "good")]
    assert results["failures"] == [
        {
            "scene": "office-s3",
            "variant": "good",
            "failed": True,
            "stage": None,
            "error": "the worker process was killed by SIGKILL (out of memory?)",
        }
    ]
    assert summary["records"] == 1


def test_ctrl_c_ends_the_workers_and_writes_no_results(tmp_path):
    """Ctrl-C while a scene runs: the worker is ended at once (its scene writes nothing), and the
    bench raises KeyboardInterrupt without writing results."""
    config = bench_file(tmp_path, [{"name": "good"}])
    out = tmp_path / "out"
    # As in a terminal, whatever this test process inherited: a shell starts a background job with
    # SIGINT ignored, and Python then keeps it ignored (the suite run with `make test &`).
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _when_a_worker_starts(lambda worker: os.kill(os.getpid(), signal.SIGINT))
        with pytest.raises(KeyboardInterrupt):
            run_bench(config, out, progress=False)
    finally:
        signal.signal(signal.SIGINT, inherited)
    assert not multiprocessing.active_children()
    assert not (out / "results.json").exists()
    assert not record_path(out, "office-s3", "good").exists() and not failure_path(out, "office-s3", "good").exists()


def test_a_mistyped_override_is_an_error_before_anything_runs(tmp_path):
    from stratamap.core.errors import ConfigError

    config = bench_file(tmp_path, [{"name": "good"}, {"name": "typo", "set": ["stages[1].params.voxel_sise=0.1"]}])
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match=r"voxel_sise"):
        run_bench(config, out, progress=False)
    assert not out.exists()
