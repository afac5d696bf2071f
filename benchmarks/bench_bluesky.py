"""Overhead per point of the Bluesky path against ``bench scan``.

The same 200-point plan (one geometry visited again and again, 1 ms integration, so nothing moves
and the emulated detector integrates 1 ms / time_scale) runs on the emulated bench three ways:

* ``bench scan``: :func:`bench.runner.run_scan` into a run store;
* Bluesky + store: :func:`bench.bluesky.plan_from_toml` under a ``RunEngine`` with a
  :class:`bench.bluesky.StoreWriter` subscribed (the same rows in the same store);
* Bluesky alone: the same plan with no subscriber (RunEngine, documents, device layer).

The difference per point is what the RunEngine, the ophyd-async devices, the worker-thread
hand-offs and the documents cost. A second row pair runs the in-plane fixture plan (63 points
that move) both ways, to set that overhead beside motion. Run: ``python -m benchmarks.bench_bluesky``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks.common import table
from bench.config import load_bench
from bench.core.parsing import read_toml
from bench.plans import load_plan, plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "benches"
N_POINTS = 200


def _plan_dict(n: int) -> dict:
    return {"name": "overhead", "kind": "list", "integration_s": 0.001, "averages": 1, "dark": "once",
            "white": "once", "order": "as-given", "points": [[30.0, 0.0, 20.0, 180.0]] * n}


IN_PLANE = FIXTURES.parent / "plans" / "in-plane.toml"


def _bench_scan(config: dict, tmp: Path) -> tuple[float, float]:
    with load_bench(config, seed=1) as bench, RunStore(tmp / "scan.sqlite") as store:
        run_scan(bench, plan_from_dict(_plan_dict(5)), store)  # warm up
        t0 = time.perf_counter()
        res = run_scan(bench, plan_from_dict(_plan_dict(N_POINTS)), store)
        still = (time.perf_counter() - t0) / res.points_done
        t0 = time.perf_counter()
        res = run_scan(bench, load_plan(IN_PLANE), store)
        return still, (time.perf_counter() - t0) / res.points_done


def _bluesky(config: dict, tmp: Path) -> tuple[float, float, float]:
    from bluesky import RunEngine

    from bench.bluesky import StoreWriter, connect, plan_from_toml

    RE = RunEngine({})
    with connect(config, run_engine=RE, seed=1) as devs:
        RE(plan_from_toml(_plan_dict(5), devs))  # warm up
        t0 = time.perf_counter()
        RE(plan_from_toml(_plan_dict(N_POINTS), devs))
        alone = (time.perf_counter() - t0) / N_POINTS
        token = RE.subscribe(StoreWriter(tmp / "bluesky.sqlite"))
        t0 = time.perf_counter()
        RE(plan_from_toml(_plan_dict(N_POINTS), devs))
        stored = (time.perf_counter() - t0) / N_POINTS
        t0 = time.perf_counter()
        RE(plan_from_toml(IN_PLANE, devs))
        moving = (time.perf_counter() - t0) / len(load_plan(IN_PLANE))
        RE.unsubscribe(token)
    return alone, stored, moving


def run() -> str:
    config = read_toml(FIXTURES / "emulated.toml")
    with tempfile.TemporaryDirectory() as tmp:
        scan, scan_moving = _bench_scan(config, Path(tmp))
        alone, stored, moving = _bluesky(config, Path(tmp))
    rows = [["bench scan (runner + store)", scan * 1e3, 0.0],
            ["Bluesky plan_from_toml + StoreWriter", stored * 1e3, (stored - scan) * 1e3],
            ["Bluesky plan_from_toml, no subscriber", alone * 1e3, (alone - scan) * 1e3],
            ["in-plane.toml (63 moves): bench scan", scan_moving * 1e3, 0.0],
            ["in-plane.toml (63 moves): Bluesky + StoreWriter", moving * 1e3, (moving - scan_moving) * 1e3]]
    return table(f"Bluesky path against bench scan on the emulated bench, {N_POINTS} points at one geometry, "
                 f"1 ms integration (the whole wall time per point, calibration included once)",
                 ["path", "ms per point", "extra ms per point"], rows)


if __name__ == "__main__":
    print(run())
