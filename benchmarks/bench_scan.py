"""Per-point overhead of a scan beyond motion and integration.

The plan visits one geometry many times with a 1 ms integration, so nothing moves and the
emulated detector integrates for 1 ms / time_scale: what remains per point is the overhead of
the drivers (sync write and settle poll of the servos, the Modbus turntable check, the spectrometer
frame), the calibration and the store commit. Measured on the emulated bench (real drivers over
emulators, targets <= 5 ms per point) and on the virtual bench (simulations cached).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from benchmarks.common import table
from bench.config import load_bench
from bench.core.parsing import read_toml
from bench.plans import plan_from_dict
from bench.runner import point_rows, run_scan
from bench.store import RunStore

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "benches"
N_POINTS = 200


def _plan(n: int):
    return plan_from_dict({"name": "overhead", "kind": "list", "integration_s": 0.001, "averages": 1,
                           "dark": "once", "white": "once", "order": "as-given",
                           "points": [[30.0, 0.0, 20.0, 180.0]] * n})


def _parts(bench, n: int = 100) -> dict[str, float]:
    """Mean seconds of the pieces of one point, measured apart."""
    from bench.core.geometry import Geometry

    g = Geometry(30.0, 0.0, 20.0, 180.0)
    bench.goniometer.move_to(g)
    t0 = time.perf_counter()
    for _ in range(n):
        bench.goniometer.move_to(g)
    move = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for _ in range(n):
        r = bench.spectrometer.acquire(0.001, 1)
    acquire = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for _ in range(n):
        point_rows(r, None, g, None, None)
    rows = (time.perf_counter() - t0) / n
    return {"move_to (no motion)": move, "acquire (1 ms)": acquire, "rows": rows}


def run() -> str:
    rows = []
    for kind in ("emulated", "virtual"):
        with load_bench(read_toml(FIXTURES / f"{kind}.toml"), seed=1) as bench, \
                tempfile.TemporaryDirectory() as tmp, RunStore(Path(tmp) / "s.sqlite") as store:
            run_scan(bench, _plan(5), store)  # warm up: compile, connect, first simulation
            t0 = time.perf_counter()
            res = run_scan(bench, _plan(N_POINTS), store)
            wall = time.perf_counter() - t0
            per_point = wall / res.points_done
            # the emulated detector integrates 1 ms / time_scale; a virtual one does not wait
            integration = 0.001 / float(bench.config["emulated"]["time_scale"]) if kind == "emulated" else 0.0
            parts = _parts(bench)
            rows.append([kind, per_point * 1e3, (per_point - integration) * 1e3,
                         ", ".join(f"{k} {v * 1e3:.2f}" for k, v in parts.items())])
    return table(f"Scan overhead per point beyond motion and integration, {N_POINTS} points at one geometry, "
                 f"1 ms integration (target <= 5 ms on the emulated bench)",
                 ["bench", "ms per point", "overhead ms", "pieces (ms)"], rows)


if __name__ == "__main__":
    print(run())
