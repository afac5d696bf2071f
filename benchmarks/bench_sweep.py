"""Sweeps on Dask: speed-up of a CPU-bound sweep from 1 to 2 local worker processes,
and the per-task overhead of the executors.

Both cluster sizes run numba single-threaded per task (one task per worker thread), workers
warmed up (kernels loaded from numba's cache) before timing. Run with
``python -m benchmarks.bench_sweep`` (the ``__main__`` guard matters: worker processes are
spawned).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from benchmarks.common import best_of, table
from bench.store import RunStore
from bench.sweep import dask_client, run_sweep, run_task, sweep_from_dict, warm_up

#: target single-threaded seconds per task of the CPU-bound sweep
TASK_SECONDS = 0.3


def _spec(n_tasks: int, rays: int, collector: str = "equal-psa:9x36", seed: int = 8) -> object:
    wl = [400.0 + 10.0 * k for k in range(n_tasks)]
    return sweep_from_dict({"sweep": {"name": f"bench-{n_tasks}x{rays}", "seed": seed, "instrument": "gonio",
                                      "specimens": ["lambert:albedo=0.6"], "incidences": [30],
                                      "collectors": [collector], "wavelengths": wl, "rays": rays,
                                      "method": "rays"}})


def _rays_for(seconds: float) -> tuple[int, float]:
    """Rays one task shoots in ``seconds`` on one numba thread (measured here, now)."""
    probe = _spec(1, 2_000_000)
    run_task(probe.tasks[0], numba_threads=1)  # load kernels
    t, _ = best_of(lambda: run_task(probe.tasks[0], numba_threads=1), 2)
    rate = 2_000_000 / t
    return int(round(rate * seconds, -5)), rate


def _raw_work(tasks: list) -> float:
    """Run tasks one after another on one numba thread, no Dask, no store (in a pool process)."""
    for t in tasks[:1]:
        run_task(t, numba_threads=1)  # load kernels before the clock starts
    t0 = time.perf_counter()
    for t in tasks:
        run_task(t, numba_threads=1)
    return time.perf_counter() - t0


def _raw(pool: object, tasks: list, k: int) -> float:
    """Wall time for ``k`` plain processes to run ``tasks`` split evenly: the machine's own
    ceiling for the speed-up, measured under the same load as the Dask runs."""
    t0 = time.perf_counter()
    pool.map(_raw_work, [tasks[i::k] for i in range(k)])
    return time.perf_counter() - t0


def _timed(spec: object, store: RunStore, client: object = None, repeat: int = 2) -> tuple[float, float]:
    """Best wall time of ``repeat`` runs, and the mean busy time per task of the last run (from
    the tasks' own start/end stamps: compute and building the rows, on whichever worker)."""
    t, res = best_of(lambda: run_sweep(spec, store, client=client), repeat)
    pts = store.points(res.run_id)
    return t, float((pts["t_end"] - pts["t_start"]).mean())


def run(n_tasks: int = 16, tiny_tasks: int = 64, repeat: int = 3) -> str:
    load0 = os.getloadavg()
    warm_up()
    rays, rate = _rays_for(TASK_SECONDS)
    heavy = _spec(n_tasks, rays)
    tiny = _spec(tiny_tasks, 1_000, "equal-psa:2x4", seed=9)
    rows = []
    tiny_rows = []
    with tempfile.TemporaryDirectory() as d, RunStore(Path(d) / "bench.sqlite") as store:
        t_inproc, busy = _timed(heavy, store, repeat=1)
        rows.append(["in-process (numba, all threads)", n_tasks, t_inproc, n_tasks / t_inproc, busy, "-", "-"])
        run_sweep(tiny, store)
        t_tiny_inproc, _ = _timed(tiny, store, repeat=5)
        tiny_rows.append(["in-process", tiny_tasks, t_tiny_inproc / tiny_tasks * 1e3, "-"])
        # both clusters up at once and runs interleaved (1, 2, 1, 2, ...), so drifting load from
        # other jobs on the machine hits both sizes alike; best of `repeat` each
        best: dict[int, tuple[float, float]] = {}
        raw: dict[int, float] = {}
        from multiprocessing import get_context

        with dask_client(workers=1, threads_per_worker=1, dashboard_address=":0") as c1, \
                dask_client(workers=2, threads_per_worker=1, dashboard_address=":0") as c2, \
                get_context("spawn").Pool(2) as pool:
            clients = {1: c1, 2: c2}
            for k, c in clients.items():
                run_sweep(_spec(k, 10_000), store, client=c)  # warm every worker through a whole task
            pool.map(_raw_work, [list(_spec(1, 10_000).tasks)] * 2)
            for _ in range(repeat):
                for k in (1, 2):
                    raw[k] = min(raw.get(k, float("inf")), _raw(pool, list(heavy.tasks), k))
                for k, c in clients.items():
                    t, busy = _timed(heavy, store, c, repeat=1)
                    if k not in best or t < best[k][0]:
                        best[k] = (t, busy)
            for k, c in clients.items():
                t, busy = best[k]
                rows.append([f"Dask LocalCluster, {k} worker process(es) x 1 thread", n_tasks, t, n_tasks / t, busy,
                             f"{n_tasks * busy / (k * t):.0%}", f"{best[1][0] / t:.2f}x"])
                t_tiny, _ = _timed(tiny, store, c, repeat=5)
                tiny_rows.append([f"Dask, {k} worker(s)", tiny_tasks, t_tiny / tiny_tasks * 1e3,
                                  f"{(t_tiny - t_tiny_inproc) / tiny_tasks * 1e3:+.2f}"])
        t_cluster = {k: v[0] for k, v in best.items()}
    load1 = os.getloadavg()
    speedup = t_cluster[1] / t_cluster[2]
    # what the speed-up would have been had each task run as fast with 2 workers as with 1,
    # i.e. without the other jobs taking cycles: scaling of the executor itself
    corrected = speedup * best[2][1] / best[1][1]
    out = table(
        f"CPU-bound sweep: {n_tasks} tasks x {rays:,} rays (~{TASK_SECONDS} s each on 1 numba thread at "
        f"{rate:.3g} rays/s), Lambertian, equal-psa:9x36, method rays; {os.cpu_count()} cores",
        ["executor", "tasks", "wall s (best)", "tasks/s", "busy s/task", "workers busy", "speed-up vs 1 worker"],
        rows)
    ceiling = raw[1] / raw[2]
    out += (f"\nplain processes without Dask (same tasks, no store), 1 -> 2: {raw[1]:.3g} s -> {raw[2]:.3g} s = "
            f"{ceiling:.2f}x: the machine's ceiling right now; Dask reaches {speedup / ceiling:.0%} of it")
    out += (f"\nspeed-up 1 -> 2 workers: {speedup:.2f}x (target >= 1.7x); {corrected:.2f}x corrected for the "
            f"slower tasks under contention (x busy2/busy1); load average before {load0[0]:.2f}, "
            f"after {load1[0]:.2f} (other jobs share the cores). 'busy s/task' is a task's own wall time on its "
            f"worker: when it grows from 1 to 2 workers the cores were shared, not the work badly spread; "
            f"'workers busy' = tasks x busy / (workers x wall).\n\n")
    out += table(
        f"Per-task overhead: {tiny_tasks} tiny tasks (1,000 rays, equal-psa:2x4), wall per task incl. the "
        f"store write (one transaction per task)",
        ["executor", "tasks", "ms per task", "overhead vs in-process, ms/task"], tiny_rows)
    out += f"\nmeasured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
    return out


if __name__ == "__main__":
    print(run())
