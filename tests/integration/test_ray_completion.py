"""Completion on Ray (``executor: ray``) gives byte for byte the completions of the local run, and
``stratamap bench --executor ray --address`` joins an existing Ray cluster and gives the local run's
records. One local Ray instance (two CPUs) serves the whole module: each Ray start costs the suite
a set of worker processes importing stratamap, so the Ray tests live here together."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.evaluation.bench import run_bench
from stratamap.core.evaluation.bench_report import records_equal
from stratamap.core.map.layers import LayeredMap
from stratamap.core.parallel import map_tasks
from stratamap.core.pipeline import Pipeline, run_stages
from stratamap.core.registry import default_registry
from stratamap.core.stages import PipelineData
from tests.conftest import REPO
from tests.core.evaluation.test_bench import tiny_bench

ray = pytest.importorskip("ray")

SCENE = {
    "type": "office",
    "seed": 11,
    "camera": {"width": 160, "height": 120},
    "trajectory": {"frames": 20},
}


@pytest.fixture(scope="module")
def ray_instance():
    """A local Ray instance for this module's tests: the completers and the bench join it."""
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray.get_runtime_context().gcs_address
    if started:
        ray.shutdown()


def pipeline_file(tmp: Path, completer: dict) -> Path:
    """A tiny whole pipeline: synthetic office, oracle, TSDF, contact graph, ``completer``, URDF export."""
    doc = {
        "source": {"plugin": "synthetic", "params": {"scene": SCENE}},
        "stages": [
            {"plugin": "oracle"},
            {"plugin": "tsdf", "params": {"voxel_size": 0.03}},
            {"plugin": "contact_graph"},
            completer,
            {"plugin": "urdf"},
        ],
        "output": {"save_map": True},
    }
    path = tmp / "pipeline.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def saved_files(out: Path) -> dict[str, bytes]:
    """Every file the run saved under map/ and export/ (the map's layers, the URDF and its meshes)."""
    paths = [p for top in ("map", "export") for p in sorted((out / top).rglob("*")) if p.is_file()]
    return {str(p.relative_to(out)): p.read_bytes() for p in paths}


@pytest.fixture(scope="module")
def icp_runs(ray_instance, tmp_path_factory):
    """The pipeline of configs/bench/scaling.yaml on a tiny scene (oracle, tsdf, contact_graph,
    icp_match, then the URDF export), run locally and with completion on Ray."""
    tmp = tmp_path_factory.mktemp("icp")
    config = pipeline_file(tmp, {"plugin": "icp_match", "params": {"library_per_family": 1}})
    local = Pipeline(load_pipeline(config)).run(tmp / "local")
    remote = Pipeline(load_pipeline(config, ["stages[3].params.executor=ray"])).run(tmp / "ray")
    return tmp, local, remote


def test_icp_match_on_ray_saves_the_local_map_and_urdf_bytes(icp_runs):
    tmp, local, remote = icp_runs
    a, b = saved_files(tmp / "local"), saved_files(tmp / "ray")
    assert any(k.startswith("export/") and k.endswith(".urdf") for k in a)
    assert any(k.startswith("export/meshes/") for k in a) and "map/instances.npz" in a
    assert sorted(a) == sorted(b)
    differing = [k for k in a if a[k] != b[k]]
    assert not differing, differing
    notes = remote["notes"]["icp_match"]
    assert notes["objects"]["completed"] >= 10, notes
    shipped = notes["shipped_bytes_match"]  # what the Ray run put into the object store and sent back
    assert shipped["shared"] > 1_000_000 and shipped["objects"] == notes["objects"]["attempted"]
    assert 0 < shipped["results"] < shipped["items"] < shipped["shared"], shipped
    assert "shipped_bytes_match" not in local["notes"]["icp_match"]


@pytest.mark.parametrize("completer", ["plane_box_match", "bbox"])
def test_other_completers_on_ray_save_the_local_bytes(icp_runs, tmp_path, completer):
    """The mapped office of the run above, completed again by ``completer`` locally and on Ray."""
    tmp, _, _ = icp_runs
    params = {"library_per_family": 1} if completer != "bbox" else {}
    saved = {}
    for executor in ("local", "ray"):
        stage = default_registry().get("completers", completer).cls(**params, executor=executor)
        data = run_stages([stage], PipelineData(map=LayeredMap.load(tmp / "local" / "map")))
        saved[executor] = data.map.save(tmp_path / executor)
    a = {p.name: p.read_bytes() for p in sorted(saved["local"].iterdir())}
    b = {p.name: p.read_bytes() for p in sorted(saved["ray"].iterdir())}
    assert sorted(a) == sorted(b) and "instances.npz" in a
    assert [k for k in a if a[k] != b[k]] == []
    completed = LayeredMap.load(saved["ray"]).instances
    assert sum(i.completion is not None and i.completion.completer == completer for i in completed) >= 10


def task_where(shared: dict, item: int) -> tuple[int, int, int]:
    return item * shared["factor"], os.getpid(), id(shared)


def test_ray_tasks_keep_input_order_and_fetch_the_shared_state_once_per_worker(ray_instance):
    items = list(range(40))
    mapped = map_tasks(task_where, items, {"factor": 3}, executor="ray", workers=2)
    assert [r[0] for r in mapped.results] == [3 * i for i in items]
    by_process: dict[int, set[int]] = {}
    for _, pid, shared_id in mapped.results:
        by_process.setdefault(pid, set()).add(shared_id)
    assert pid != os.getpid()
    assert all(len(ids) == 1 for ids in by_process.values()), by_process
    assert mapped.shipped["shared"] > 0 and mapped.shipped["items"] > 0 and len(mapped.seconds) == len(items)


def test_bench_on_an_existing_ray_cluster_gives_the_local_records(ray_instance, tmp_path):
    config = tiny_bench(tmp_path)
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    cmd = [sys.executable, "-m", "stratamap.core.cli", "bench", str(config), "--out", str(tmp_path / "ray")]
    cmd += ["--executor", "ray", "--address", ray_instance]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, env=env, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "2 records (2 run now)" in done.stdout
    # The bench joined this module's instance rather than starting one of its own.
    assert f"Connecting to existing Ray cluster at address: {ray_instance}" in done.stderr, done.stderr[-3000:]
    remote = json.loads((tmp_path / "ray" / "results.json").read_text())["records"]
    assert len(remote) == 2 and all(r["metrics"]["detection"]["recall"] > 0 for r in remote)
    local = run_bench(config, tmp_path / "local", progress=False)
    assert local["records"] == 2
    assert records_equal(json.loads((tmp_path / "local" / "results.json").read_text())["records"], remote)
