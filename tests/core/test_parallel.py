"""core/parallel.py: per-item work in threads or processes gives the serial results in input order;
the executor choice is a described, validated stage setting; a missing Ray is a one-line ConfigError.
(Ray itself: tests/integration/test_ray_completion.py.)"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import yaml

from stratamap.core.config import load_pipeline
from stratamap.core.errors import ConfigError
from stratamap.core.parallel import BLAS_THREAD_VARIABLES, ExecutorConfig, ensure_ray, map_tasks
from stratamap.plugins.completers.bbox import BBoxCompleter
from stratamap.plugins.completers.icp_match import ICPMatchCompleter
from tests.conftest import REPO


def scaled_sum(shared: dict, item: np.ndarray) -> tuple[float, int, int]:
    """A numpy reduction of the item against the shared array, and where it ran."""
    return float(np.sum(item * shared["weights"])), os.getpid(), id(shared)


@pytest.fixture
def work():
    rng = np.random.default_rng(0)
    return {"weights": rng.normal(size=100)}, [rng.normal(size=100) for _ in range(12)]


def test_threads_give_the_serial_results_in_input_order(work):
    shared, items = work
    mapped = map_tasks(scaled_sum, items, shared, executor="local", workers=3)
    assert [r[0] for r in mapped.results] == [scaled_sum(shared, i)[0] for i in items]
    assert len(mapped.seconds) == len(items) and all(s >= 0 for s in mapped.seconds)
    assert mapped.shipped == {}  # nothing leaves the process
    assert map_tasks(scaled_sum, [], shared).results == []


def test_processes_get_the_shared_state_once_each_and_give_the_same_bytes(work):
    shared, items = work
    mapped = map_tasks(scaled_sum, items, shared, executor="processes", workers=2)
    assert [r[0] for r in mapped.results] == [scaled_sum(shared, i)[0] for i in items]
    by_process: dict[int, set[int]] = {}
    for _, pid, shared_id in mapped.results:
        by_process.setdefault(pid, set()).add(shared_id)
    assert os.getpid() not in by_process and 1 <= len(by_process) <= 2
    assert all(len(ids) == 1 for ids in by_process.values())


def openblas_threads(shared: None, item: int) -> int | None:
    """The threads numpy's OpenBLAS runs in this process (None where it is not found)."""
    import ctypes

    libraries = {line.split()[-1] for line in open("/proc/self/maps") if "openblas" in line and "numpy" in line}
    for path in sorted(libraries):
        lib = ctypes.CDLL(path)
        for symbol in ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads"):
            if hasattr(lib, symbol):
                return int(getattr(lib, symbol)())
    return None


def blas_variables() -> dict[str, str]:
    return {k: os.environ[k] for k in BLAS_THREAD_VARIABLES if k in os.environ}


@pytest.mark.skipif(not sys.platform.startswith("linux") or (os.cpu_count() or 1) < 2, reason="Linux, 2+ cores")
def test_worker_processes_share_the_cores_between_their_blas_threads(monkeypatch):
    """Two workers on N cores run numpy's BLAS on N // 2 threads each, not N each (OpenBLAS's
    threads spin between small calls); the parent's environment is as it was afterwards."""
    for name in BLAS_THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    threads = map_tasks(openblas_threads, [0, 1], None, executor="processes", workers=2).results
    if None in threads:
        pytest.skip("numpy's OpenBLAS not found in the worker")
    assert threads == [max(1, os.cpu_count() // 2)] * 2
    assert blas_variables() == {}


@pytest.mark.skipif(not sys.platform.startswith("linux") or (os.cpu_count() or 1) < 2, reason="Linux, 2+ cores")
def test_a_blas_thread_count_the_user_set_is_kept(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    threads = map_tasks(openblas_threads, [0], None, executor="processes", workers=1).results
    if None in threads:
        pytest.skip("numpy's OpenBLAS not found in the worker")
    assert threads == [1]  # one worker alone would get every core
    assert blas_variables() == {"OPENBLAS_NUM_THREADS": "1"}


def test_unknown_executor_is_a_config_error(work):
    shared, items = work
    with pytest.raises(ConfigError, match="executor: expected 'local', 'processes' or 'ray', got 'dask'"):
        map_tasks(scaled_sum, items, shared, executor="dask")  # type: ignore[arg-type]


def test_missing_ray_is_a_one_line_config_error(monkeypatch, work):
    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` meets where Ray is not installed
    shared, items = work
    for call in (lambda: map_tasks(scaled_sum, items, shared, executor="ray"), lambda: ensure_ray()):
        with pytest.raises(ConfigError) as err:
            call()
        assert "\n" not in str(err.value) and "pip install 'stratamap[ray]'" in str(err.value)


def test_executor_fields_are_described_and_validated_in_pipelines():
    for field in ExecutorConfig.model_fields.values():
        assert field.description
    for completer in (ICPMatchCompleter, BBoxCompleter):
        assert {"executor", "ray_address"} <= set(completer.Config.model_fields)
        assert completer(executor="ray", ray_address="auto").config.executor == "ray"
    demo = REPO / "configs" / "demo.yaml"
    at = [s["plugin"] for s in yaml.safe_load(demo.read_text())["stages"]].index("bbox")
    assert load_pipeline(demo, [f"stages[{at}].params.executor=ray"]).stages[at].config.executor == "ray"
    with pytest.raises(ConfigError, match=rf"stages\[{at}\]\.params\.executor: .*'local' or 'ray'"):
        load_pipeline(demo, [f"stages[{at}].params.executor=dask"])


def test_a_closure_cannot_go_to_ray():
    from stratamap.core.geometry.boxes import gravity_aligned_box
    from stratamap.core.map.layers import ObjectInstance

    pts = np.random.default_rng(1).uniform(0, 1, size=(60, 3))
    inst = ObjectInstance(1, "chair", pts, gravity_aligned_box(pts))
    local = ICPMatchCompleter()
    assert local.map_objects([inst], lambda i: len(i.points)) == [(inst, 60)]
    with pytest.raises(ConfigError, match="executor: icp_match matches objects in a closure"):
        ICPMatchCompleter(executor="ray").map_objects([inst], lambda i: len(i.points))


def test_no_cluster_at_the_address_is_a_one_line_config_error(monkeypatch):
    ray = pytest.importorskip("ray")
    if ray.is_initialized():
        pytest.skip("this process already joined a Ray instance")
    # 'auto' joins any Ray instance running on this machine (another test process's, in the suite),
    # and that process's end would then end this one.
    psutil = pytest.importorskip("psutil")
    if any(proc.info["name"] == "gcs_server" for proc in psutil.process_iter(["name"])):
        pytest.skip("a Ray instance runs on this machine: 'auto' would join it")
    monkeypatch.setenv("RAY_ADDRESS", "auto")  # what `ray_address: null` falls back to, as Ray's tools do
    with pytest.raises(ConfigError, match="ray_address: cannot reach a Ray cluster at 'auto'") as err:
        ensure_ray()
    assert "\n" not in str(err.value)


def test_ahead_gives_every_result_in_order_and_calls_fn_in_order_in_one_thread():
    import threading

    from stratamap.core.parallel import ahead

    seen: list[tuple[int, str]] = []

    def fn(k: int) -> int:
        seen.append((k, threading.current_thread().name))
        return k * k

    assert list(ahead(range(7), fn, depth=2)) == [(k, k * k) for k in range(7)]
    assert [k for k, _ in seen] == list(range(7))
    assert len({name for _, name in seen}) == 1 and seen[0][1] != threading.current_thread().name


def test_ahead_raises_at_the_failing_item_and_stops_when_the_caller_stops():
    from stratamap.core.parallel import ahead

    calls: list[int] = []

    def fn(k: int) -> int:
        calls.append(k)
        if k == 3:
            raise ValueError("bad frame 3")
        return k

    got = []
    with pytest.raises(ValueError, match="bad frame 3"):
        for item, _ in ahead(range(10), fn, depth=1):
            got.append(item)
    assert got == [0, 1, 2]
    calls.clear()
    for item, _ in ahead(range(100), lambda k: calls.append(k) or k, depth=2):
        if item == 1:
            break
    assert max(calls) <= 4  # at most depth items beyond the last one taken (plus the one running)
    with pytest.raises(ValueError, match="depth"):
        list(ahead(range(3), fn, depth=0))
