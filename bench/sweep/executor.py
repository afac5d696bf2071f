"""Running a sweep into the run store: in-process or on Dask (:func:`run_sweep`,
:func:`resume_sweep`, :func:`dask_client`), one transaction per task from the client process only,
and reading a sweep run back with its task table (:func:`sweep_readings`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping

import pandas as pd
from tqdm import tqdm

from bench.store import RunStore
from bench.core.errors import BenchError, InputError, RunInterrupted, SimulationError, StoreError
from bench.sweep.spec import SweepSpec, SweepTask, sweep_from_dict, task_table
from bench.sweep.task import TaskResult, run_task, warm_up

log = logging.getLogger("bench.sweep")

__all__ = ["SweepResult", "run_sweep", "resume_sweep", "sweep_readings", "dask_client"]


# --- running a sweep -------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepResult:
    """How a sweep (or its resumption) ended."""
    run_id: str
    status: str
    tasks_done: int
    tasks_planned: int
    tasks_run: int
    duplicates_skipped: int
    seconds: float
    executor: str


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, *,
                threads_per_worker: int = 1, **cluster_kw: Any) -> Iterator[Any]:
    """A ``distributed.Client`` for a scheduler address, or for a local cluster of ``workers``
    processes (``threads_per_worker`` threads each); closed (and the local cluster shut down)
    on exit. Needs ``dask[distributed]`` (the ``scale`` extra). A local cluster's scheduler and
    dashboard listen on loopback (127.0.0.1) unless ``host``/``dashboard_address`` say otherwise.

    Raises
    ------
    InputError
        Neither or both of ``scheduler`` and ``workers``, or Dask not installed.
    SimulationError
        The scheduler cannot be reached.
    """
    if (scheduler is None) == (workers is None):
        raise InputError("give either a scheduler address or a number of local workers")
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InputError("running a sweep on Dask needs dask[distributed]: pip install 'goniobench[scale]'") from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=cluster_kw.pop("timeout", "20s"), set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise SimulationError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            yield client
        return
    if not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be an integer >= 1, got {workers!r}")
    cluster_kw.setdefault("processes", True)
    cluster_kw.setdefault("host", "127.0.0.1")  # services bind loopback unless the caller says otherwise
    cluster_kw["dashboard_address"] = cluster_kw.get("dashboard_address") or "127.0.0.1:8787"
    cluster_kw.setdefault("silence_logs", logging.ERROR)
    with LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, **cluster_kw) as cluster, \
            Client(cluster, set_as_default=False) as client:
        yield client


def run_sweep(spec: SweepSpec, store: RunStore, *, client: Any = None, progress: bool = False,
              numba_threads: int | None = None, window: int | None = None, retries: int = 1,
              on_task: Callable[[int, int], None] | None = None) -> SweepResult:
    """Create a ``sweep`` run in ``store`` and run every task of ``spec``.

    Parameters
    ----------
    spec : SweepSpec
    store : bench.store.RunStore
        Only this process writes it: one transaction per task (point index = task index).
    client : distributed.Client, optional
        Run on this Dask cluster; default: in-process.
    progress : bool
        A tqdm progress bar on stderr.
    numba_threads : int, optional
        numba threads per task: default 1 on Dask (one task per worker thread), all in-process.
    window : int, optional
        Tasks in flight on Dask (default: 4 x the cluster's threads, at least 8): bounds the
        client's and scheduler's memory for sweeps of any size.
    retries : int
        Extra attempts of a task that raised (a worker that died does not count; the scheduler
        reschedules its tasks by itself).
    on_task : callable, optional
        ``on_task(k, idx)`` after task number ``k`` (index ``idx``) is committed (tests use it).

    Raises
    ------
    RunInterrupted
        Ctrl-C, or a task that failed after its retries: the run is stored as interrupted with
        the reason, every committed task kept; :func:`resume_sweep` finishes it.
    """
    executor = _executor(client)
    task_runs: dict[str, list[Any]] = {"worker": [None] * len(spec), "compute_s": [None] * len(spec)}
    meta = {"sweep": spec.name, "instrument": spec.instrument, "n_tasks": len(spec),
            "seeding": "series_seed = SeedSequence(seed, spawn_key=(blake2b64(series parameters),)); "
                       "wavelength stream = measurement_seed(series_seed, [specimen hash,] pm, mdeg theta_i, "
                       "mdeg phi_i); rays batched over wavelengths (gonio Lambertian, single-roughness GGX): one "
                       "stream measurement_seed(series_seed, [specimen hash,] mdeg theta_i, mdeg phi_i)",
            "tasks": task_table(spec), "task_runs": task_runs,
            "executions": [executor]}
    run_id = store.create_run(kind="sweep", plan=spec.source, bench={"kind": "virtual", "instrument": spec.instrument},
                              seed=spec.seed, meta=meta, n_planned=len(spec))
    log.info("sweep %s: run %s, %d tasks, %s", spec.name, run_id, len(spec), executor["kind"])
    return _execute(spec, store, run_id, set(), client, progress, numba_threads, window, retries, on_task, executor,
                    task_runs)


def resume_sweep(store: RunStore, run_id: str, *, client: Any = None, progress: bool = False,
                 numba_threads: int | None = None, window: int | None = None, retries: int = 1,
                 on_task: Callable[[int, int], None] | None = None) -> SweepResult:
    """Finish an interrupted (or crashed) sweep run: run exactly the tasks it lacks, rebuilt
    from the stored spec, so the stored results equal an uninterrupted run's."""
    info = store.run(run_id)
    if info["kind"] != "sweep":
        raise StoreError(f"run {run_id} is a {info['kind']}, not a sweep; resume it with `bench resume`")
    if info["status"] == "completed":
        raise StoreError(f"run {run_id} is already completed")
    spec = sweep_from_dict(info["plan"])
    stored_keys = ((info.get("meta") or {}).get("tasks") or {}).get("task_key")
    if len(spec) != info["n_planned"] or (stored_keys is not None and stored_keys != task_table(spec)["task_key"]):
        raise StoreError(f"run {run_id}: its stored sweep no longer gives the same tasks ({len(spec)} tasks, "
                         f"{info['n_planned']} planned, or other task keys: a different goniobench version?); "
                         f"refusing to mix results")
    done = set(store.done_indices(run_id))
    executor = _executor(client)
    executions = list((info.get("meta") or {}).get("executions", [])) + [executor]
    store.update_meta(run_id, executions=executions)
    store.set_status(run_id, "running", None)
    return _execute(spec, store, run_id, done, client, progress, numba_threads, window, retries, on_task, executor,
                    (info.get("meta") or {}).get("task_runs"))


def _executor(client: Any) -> dict[str, Any]:
    t = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    if client is None:
        return {"kind": "in-process", "host": socket.gethostname(), "pid": os.getpid(), "started_utc": t}
    info = client.scheduler_info()
    workers = info.get("workers", {})
    return {"kind": "dask", "scheduler": info.get("address"), "workers": len(workers),
            "threads": sum(int(w.get("nthreads", 1)) for w in workers.values()), "started_utc": t}


def _progress(total: int, initial: int, enabled: bool, desc: str) -> Any:
    return tqdm(total=total, initial=initial, disable=not enabled, desc=desc, unit="task", dynamic_ncols=True,
                leave=True)


def sweep_readings(store: RunStore, run_id: str) -> Any:
    """The tidy readings of a sweep run (:meth:`bench.store.RunStore.readings`) with the per-task
    metadata joined on ``idx``: :data:`TASK_COLUMNS` (``quantity`` of a spectro "T" row is
    ``transmittance``) and :data:`RUN_COLUMNS` (the worker that stored it and its compute
    seconds; None for tasks whose run info was not flushed before a crash)."""
    info = store.run(run_id)
    meta = info.get("meta") or {}
    if info["kind"] != "sweep" or "tasks" not in meta:
        raise StoreError(f"run {run_id} is a {info['kind']} run, not a sweep")
    df = store.readings(run_id)
    tasks = pd.DataFrame({**meta["tasks"], **meta.get("task_runs", {})})
    tasks.insert(0, "idx", range(len(tasks)))
    out = df.merge(tasks.dropna(axis=1, how="all"), on="idx", how="left", validate="many_to_one")
    if "quantity" in out.columns:
        out.loc[out["hemisphere"] == "T", "quantity"] = "transmittance"
    return out


class _Sink:
    """The client side: stores each result once, counts, reports progress, and keeps who ran
    each task (flushed to the run's meta every ``flush_s`` seconds and at the end: diagnostic
    metadata, not results, so it does not cost a second transaction per task)."""
    def __init__(self, store: RunStore, run_id: str, done: set[int], bar: Any,
                 on_task: Callable[[int, int], None] | None, n_tasks: int | None = None,
                 task_runs: Mapping[str, list[Any]] | None = None, flush_s: float = 10.0) -> None:
        self.store, self.run_id, self.done, self.bar, self.on_task = store, run_id, done, bar, on_task
        self.run = 0
        self.duplicates = 0
        n = n_tasks if n_tasks is not None else 0
        runs = dict(task_runs or {})
        self.workers = list(runs.get("worker") or [None] * n)
        self.compute = list(runs.get("compute_s") or [None] * n)
        self.flush_s = flush_s
        self._dirty = False
        self._last_flush = time.monotonic()

    def flush(self) -> None:
        if self._dirty and self.workers:
            self.store.update_meta(self.run_id, task_runs={"worker": self.workers, "compute_s": self.compute})
            self._dirty = False
        self._last_flush = time.monotonic()

    def put(self, r: TaskResult) -> None:
        if r.idx in self.done:
            self.duplicates += 1
            log.info("run %s: task %d already stored; duplicate result skipped", self.run_id, r.idx)
            return
        try:
            self.store.add_point(self.run_id, r.idx, r.geometry, r.rows, t_start=r.t_start, t_end=r.t_end)
        except StoreError:
            if r.idx not in self.store.done_indices(self.run_id):  # not a duplicate: a real refusal
                raise
            self.duplicates += 1
            self.done.add(r.idx)
            log.info("run %s: task %d stored meanwhile by another process; skipped", self.run_id, r.idx)
            return
        self.done.add(r.idx)
        self.run += 1
        if r.idx < len(self.workers):
            self.workers[r.idx], self.compute[r.idx] = r.worker, round(r.compute_s, 6)
            self._dirty = True
            if time.monotonic() - self._last_flush > self.flush_s:
                self.flush()
        self.bar.update(1)
        if self.on_task is not None:
            self.on_task(len(self.done), r.idx)


def _execute(spec: SweepSpec, store: RunStore, run_id: str, done: set[int], client: Any, progress: bool,
             numba_threads: int | None, window: int | None, retries: int,
             on_task: Callable[[int, int], None] | None, executor: dict[str, Any],
             task_runs: Mapping[str, list[Any]] | None) -> SweepResult:
    t_run = time.perf_counter()
    todo = [t for t in spec.tasks if t.idx not in done]
    bar = _progress(len(spec), len(done), progress, f"sweep {run_id}")
    sink = _Sink(store, run_id, done, bar, on_task, len(spec), task_runs)
    try:
        if client is None:
            for t in todo:
                sink.put(run_task(t, numba_threads))
        else:
            _on_dask(spec, todo, client, sink, run_id, 1 if numba_threads is None else numba_threads, window,
                     retries)
    except KeyboardInterrupt:
        store.set_status(run_id, "interrupted", "interrupted by the user (Ctrl-C)")
        raise RunInterrupted.by_the_user(f"sweep run {run_id} interrupted by the user after {len(done)} of "
                                         f"{len(spec)} tasks; finish it with: bench sweep --resume {run_id}") from None
    except _TaskFailed as exc:
        store.set_status(run_id, "interrupted", str(exc))
        raise RunInterrupted(f"sweep run {run_id} interrupted after {len(done)} of {len(spec)} tasks: {exc}; "
                             f"fix it, then: bench sweep --resume {run_id}") from exc.__cause__
    except BenchError as exc:
        store.set_status(run_id, "interrupted", f"{type(exc).__name__}: {exc}")
        raise
    except BaseException as exc:  # anything else (a store that lost a table, a bug): never left `running`
        store.record_failure(run_id, exc)
        raise
    finally:
        bar.close()
        sink.flush()
    store.set_status(run_id, "completed", None)
    return SweepResult(run_id, "completed", len(done), len(spec), sink.run, sink.duplicates,
                       time.perf_counter() - t_run, executor["kind"])


class _TaskFailed(Exception):
    pass


def _warm_workers(client: Any, instrument: str) -> None:
    """Run :func:`warm_up` once on every worker, as an ordinary task pinned to it (so a slow
    numba compile after a source change never blocks a worker's event loop), and fail early
    with a clear message if the workers cannot import goniobench. A worker that joins later
    warms up on its first task."""
    addrs = list(client.scheduler_info().get("workers", {}))
    futs = {a: client.submit(warm_up, instrument, workers=[a], allow_other_workers=False, pure=False,
                             key=f"goniobench-warm-up-{a}-{time.time_ns()}") for a in addrs}
    took = {}
    for a, f in futs.items():
        try:
            took[a] = round(f.result(), 2)
        except ModuleNotFoundError as exc:
            raise SimulationError(f"Dask worker {a} cannot import {exc.name!r}: install goniobench (the same "
                                  f"version) in every worker's environment") from None
        except Exception as exc:  # a worker lost during warm-up: its tasks go elsewhere
            log.warning("warm-up on worker %s failed: %s: %s", a, type(exc).__name__, exc)
        finally:
            f.release()
    log.info("workers warmed up (s): %s", took)


def _on_dask(spec: SweepSpec, todo: list[SweepTask], client: Any, sink: _Sink, run_id: str, numba_threads: int,
             window: int | None, retries: int) -> None:
    from distributed import as_completed

    log.info("Dask scheduler %s, dashboard %s", client.scheduler_info().get("address"), client.dashboard_link)
    _warm_workers(client, spec.instrument)
    threads = sum(int(w.get("nthreads", 1)) for w in client.scheduler_info().get("workers", {}).values())
    limit = window if window is not None else max(8, 4 * max(threads, 1))
    queue = list(reversed(todo))
    tag = f"goniobench-sweep-{run_id}"

    def submit() -> Any:
        t = queue.pop()
        return client.submit(run_task, t, numba_threads, key=f"{tag}-{t.idx}", pure=False, retries=retries)

    ac = as_completed(loop=client.loop, with_results=True, raise_errors=False)
    try:
        ac.update([submit() for _ in range(min(limit, len(queue)))])
        for fut, res in ac:
            if fut.status == "error" or isinstance(res, BaseException):
                exc = fut.exception() if fut.status == "error" else res
                idx = fut.key.rsplit("-", 1)[-1]
                raise _TaskFailed(f"task {idx} failed: {type(exc).__name__}: {exc}") from exc
            sink.put(res)
            fut.release()
            if queue:
                ac.add(submit())
    finally:
        remaining = list(ac.futures)
        if remaining:
            client.cancel(remaining)
