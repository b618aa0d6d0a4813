"""Per-item work in parallel: threads or worker processes on this machine, or Ray tasks on a
local Ray instance or a cluster, with the same results in the same order whichever runs it.

``map_tasks(fn, items, shared)`` computes ``[fn(shared, item) for item in items]``. ``fn`` is a
module-level function (Ray and worker processes import it by name), ``shared`` the read-only state
every item needs (a model index, a config): on Ray it is put into the object store once and each
worker process fetches it once, whatever the number of items; items and results are plain data
(numpy arrays, dataclasses), pickled both ways. Ray is optional: it is imported on first use, and
a missing Ray is a one-line :class:`~stratamap.core.errors.ConfigError`.

Stage configs take :class:`ExecutorConfig` as a mixin to offer ``executor: local|ray`` and
``ray_address`` (see docs/ray.md).
"""

from __future__ import annotations

import os
import pickle
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Generic, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from stratamap.core.errors import ConfigError
from stratamap.core.lazy import lazy_module

o3d = lazy_module("open3d")

S = TypeVar("S")
T = TypeVar("T")
R = TypeVar("R")

Executor = Literal["local", "processes", "ray"]


class ExecutorConfig(BaseModel):
    """Mixin of stage configs whose per-item work can run as Ray tasks (``class C(StageConfig, ExecutorConfig)``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    executor: Literal["local", "ray"] = Field(
        default="local",
        description=(
            "Where the per-object work runs: local (threads of this process) or ray (Ray tasks; results are identical, "
            "see docs/ray.md)."
        ),
    )
    ray_address: str | None = Field(
        default=None,
        description=(
            "With executor: ray, the address of an existing Ray cluster ('auto', 'HOST:6379' or 'ray://HOST:10001'); "
            "null: the Ray instance this process already joined, else $RAY_ADDRESS, else a local instance started "
            "with `workers` CPUs."
        ),
    )


@dataclass
class Mapped(Generic[R]):
    """What :func:`map_tasks` returns: the results in input order, and what the work cost."""

    results: list[R]
    seconds: list[float]  # per item, measured where it ran
    #: Ray only: bytes pickled for the shared state (once), the items and the results (totals).
    shipped: dict[str, int] = field(default_factory=dict)


def map_tasks(
    fn: Callable[[S, T], R],
    items: Sequence[T],
    shared: S,
    *,
    executor: Executor = "local",
    workers: int = 2,
    ray_address: str | None = None,
) -> Mapped[R]:
    """``[fn(shared, item) for item in items]``, in parallel (``workers`` at a time), results in input order.

    ``local``: threads of this process (for work that releases the GIL: numpy, KD-trees, Open3D);
    ``processes``: fresh worker processes (``shared`` pickled once per process);
    ``ray``: Ray tasks of one CPU each, on the Ray instance this process joined, else on the cluster at
    ``ray_address``, else on a local instance with ``workers`` CPUs started here (and left running
    for later calls; Ray stops it when the process exits).
    """
    items = list(items)
    if executor == "ray":
        return _map_ray(fn, items, shared, workers, ray_address)
    if not items:
        return Mapped([], [])
    if executor == "processes":
        import multiprocessing as mp

        processes = max(1, min(workers, len(items)))
        # spawn, not fork: Open3D and OpenMP threads do not survive a fork.
        with (
            worker_blas_threads(processes),
            ProcessPoolExecutor(
                max_workers=processes,
                mp_context=mp.get_context("spawn"),
                initializer=_set_process_shared,
                initargs=(pickle.dumps(shared, protocol=pickle.HIGHEST_PROTOCOL),),
            ) as pool,
        ):
            timed = list(pool.map(_process_task, [fn] * len(items), items))
    elif executor == "local":
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            timed = list(pool.map(lambda item: _timed(fn, shared, item), items))
    else:
        raise ConfigError([("executor", f"expected 'local', 'processes' or 'ray', got {executor!r}")])
    return Mapped([r for r, _ in timed], [s for _, s in timed])


def _timed(fn: Callable[[Any, Any], Any], shared: Any, item: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    result = fn(shared, item)
    return result, time.perf_counter() - start


# ------------------------------------------------------------------------------- worker processes

_PROCESS_SHARED: list[Any] = []

#: Environment variables that set a BLAS library's threads (OpenBLAS, as numpy and scipy ship it;
#: OpenMP builds; MKL), read once when the library loads.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def worker_blas_threads(workers: int) -> Iterator[None]:
    """Worker processes started inside the block share the cores: each runs its BLAS on
    ``cores // workers`` threads (at least one), as Ray does for its workers. Without it, each of
    ``workers`` processes starts one BLAS thread per core, and OpenBLAS's threads spin between the
    many small matrix calls of the stages. A variable the user set is left as it is; the others
    are restored when the block ends."""
    threads = str(max(1, (os.cpu_count() or 1) // max(1, workers)))
    added = [name for name in BLAS_THREAD_VARIABLES if name not in os.environ]
    os.environ.update(dict.fromkeys(added, threads))
    try:
        yield
    finally:
        for name in added:
            os.environ.pop(name, None)


def _set_process_shared(payload: bytes) -> None:
    _PROCESS_SHARED[:] = [pickle.loads(payload)]


def _process_task(fn: Callable[[Any, Any], Any], item: Any) -> tuple[Any, float]:
    return _timed(fn, _PROCESS_SHARED[0], item)


# ------------------------------------------------------------------------------- Ray

#: In a Ray worker process: the shared state of the current map, by object id, fetched once per process.
_RAY_SHARED: dict[str, Any] = {}
_RAY_LOCK = threading.Lock()
_RAY_TASK: Any = None


def ray_module() -> Any:
    """Ray, imported now; a one-line ConfigError when it is not installed."""
    try:
        import ray
    except ImportError:
        raise ConfigError(
            [("executor", "ray needs the Ray package: pip install 'stratamap[ray]' (or set executor: local)")]
        ) from None
    return ray


def ensure_ray(address: str | None = None, num_cpus: int | None = None) -> bool:
    """Join Ray: the instance this process already joined, else the cluster at ``address`` (or at
    $RAY_ADDRESS, as Ray's own tools do), else a new local instance of ``num_cpus`` CPUs. Returns
    whether this call started or joined it."""
    ray = ray_module()
    with _RAY_LOCK:
        if ray.is_initialized():
            return False
        address = address or os.environ.get("RAY_ADDRESS") or None
        kwargs: dict[str, Any] = {"address": address} if address else {"num_cpus": num_cpus}
        try:
            ray.init(include_dashboard=False, log_to_driver=False, **kwargs)
        except ConnectionError as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError([("ray_address", f"cannot reach a Ray cluster at {address!r}: {first}")]) from None
        return True


def _ray_task(fn: Callable[[Any, Any], Any], shared_box: list[Any], item: Any) -> tuple[Any, float]:
    # The reference travels inside a list so that Ray does not resolve it per task: each worker
    # process fetches (and deserializes) the shared state once and keeps it for the following items.
    ref = shared_box[0]
    key = ref.hex()
    if key not in _RAY_SHARED:
        import ray

        _RAY_SHARED.clear()  # the previous map's state: no task of it is left on this process
        _RAY_SHARED[key] = ray.get(ref)
    return _timed(fn, _RAY_SHARED[key], item)


def _map_ray(
    fn: Callable[[Any, Any], Any], items: list[Any], shared: Any, workers: int, address: str | None
) -> Mapped[Any]:
    global _RAY_TASK
    ray = ray_module()
    if not items:
        return Mapped([], [], {"shared": 0, "items": 0, "results": 0})
    ensure_ray(address, num_cpus=max(1, workers))
    if _RAY_TASK is None:
        # One CPU per task; OMP/BLAS threads of a Ray worker are limited to that CPU.
        _RAY_TASK = ray.remote(num_cpus=1, max_retries=0)(_ray_task)
    dumps = ray.cloudpickle.dumps
    shipped = {"shared": len(dumps(shared)), "items": sum(len(dumps(item)) for item in items)}
    shared_ref = ray.put(shared)
    refs = [_RAY_TASK.remote(fn, [shared_ref], item) for item in items]
    timed = ray.get(refs)  # in input order
    del shared_ref, refs
    shipped["results"] = sum(len(dumps(result)) for result, _ in timed)
    return Mapped([r for r, _ in timed], [s for _, s in timed], shipped)


@contextmanager
def open3d_threads(n: int) -> Iterator[None]:
    """Limit Open3D's CPU (TBB) threads to ``n`` inside the block, then restore the previous limit.
    Some of its parallel loops give results that depend on how the work was split (odometry's
    reductions, point extraction from 16-bit voxels): one thread makes them repeat exactly."""
    previous = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(0)
    default = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(n)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(0 if previous == default else previous)


def ahead(items: Iterator[S] | Sequence[S], fn: Callable[[S], R], depth: int = 2) -> Iterator[tuple[S, R]]:
    """``(item, fn(item))`` for each item, in order, with ``fn`` run up to ``depth`` items ahead in one
    background thread while the caller works on the current one.

    Worth it where ``fn`` spends its time outside the GIL (onnxruntime inference, image decoding,
    file reads) and the caller in numpy: on two cores the two overlap. One thread calls ``fn`` on
    the items in their order, so an ``fn`` with state (a keyframe chooser) sees them as a plain
    loop would, and the results are the same. An exception from ``fn`` is raised here, at its item.
    """
    if depth < 1:
        raise ValueError("depth must be at least 1")
    iterator = iter(items)
    pending: deque = deque()
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stratamap-ahead")
    try:
        for item in iterator:
            pending.append((item, pool.submit(fn, item)))
            if len(pending) > depth:
                first, future = pending.popleft()
                yield first, future.result()
        while pending:
            first, future = pending.popleft()
            yield first, future.result()
    finally:
        # The caller stopped early or failed: drop what is queued and do not wait for the step
        # running. A generator left suspended is closed by the garbage collector at any later time,
        # and a wait there would hold up (and a Ctrl-C there would be lost in) whatever runs then.
        pool.shutdown(wait=False, cancel_futures=True)
