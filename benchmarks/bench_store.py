"""Run-store throughput: points committed per second (one transaction each) against the target.

Each point carries 31 wavelengths (400-700 nm every 10 nm) of a physical scan (signal, dark,
white, value, std, interval, saturation flag). Measured in one run, for ``synchronous=NORMAL``
(durable against process crashes) and ``FULL`` (fsync per commit, durable against power loss),
beside a floor: the same transactions issued straight through sqlite3 with pre-built tuples
(what the store costs over SQLite itself). Also: reading the run back as a tidy DataFrame.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from benchmarks.common import best_of, table
from bench.store import RunStore
from bench.store.rows import _INSERT_READING, _reading_tuples

TARGET = 2000.0
N_WL = 31
GEO = {"theta_i": 45.0, "phi_i": 0.0, "theta_r": 0.0, "phi_r": 0.0}


def _rows(i: int) -> list[dict]:
    return [{"wavelength_nm": 400.0 + 10.0 * j, "signal": i * 1000.0 + j, "dark": 12.0, "white": 40_000.0,
             "value": 0.31, "std": 0.002, "ci_lo": 0.306, "ci_hi": 0.314, "saturated": False} for j in range(N_WL)]


def _store_rate(folder: Path, sync: str, n: int, repeat: int) -> tuple[float, float, float]:
    """(store points/s, store points per CPU-second, raw sqlite3 points/s), best of ``repeat``
    alternating runs so that a change of machine load hits both alike. Only the loop of
    commits is timed. CPU seconds (user + system of this process) leave out time spent waiting
    for a busy CPU, so they estimate what an idle machine reaches (fsync waits are not CPU)."""
    rows = [_rows(i) for i in range(n)]
    store_times: list[float] = []
    store_cpu: list[float] = []
    raw_times: list[float] = []
    for k in range(repeat):
        with RunStore(folder / f"s-{sync}-{k}.sqlite", synchronous=sync) as s:
            rid = s.create_run("scan", n_planned=n)
            t0, c0 = time.perf_counter(), time.process_time()
            for i in range(n):
                s.add_point(rid, i, GEO, rows[i])
            store_times.append(time.perf_counter() - t0)
            store_cpu.append(time.process_time() - c0)
        rid = f"raw-{k}"
        tuples = [_reading_tuples(rid, i, rows[i]) for i in range(n)]  # built outside the timed loop
        with RunStore(folder / f"r-{sync}-{k}.sqlite", synchronous=sync) as s:
            s.create_run("scan", n_planned=n, run_id=rid)
            db = s._db
            t0 = time.perf_counter()
            for i in range(n):
                db.execute("BEGIN IMMEDIATE")
                db.execute("INSERT INTO points (run_id, idx, theta_i, phi_i, theta_r, phi_r, t_start, t_end, "
                           "status, n_readings) VALUES (?,?,45,0,0,0,0,0,'ok',?)", (rid, i, N_WL))
                db.executemany(_INSERT_READING, tuples[i])
                db.execute("COMMIT")
            raw_times.append(time.perf_counter() - t0)
    return n / min(store_times), n / min(store_cpu), n / min(raw_times)


def run(n_normal: int = 2000, n_full: int = 200, repeat: int = 3) -> str:
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-store-") as tmp:
        folder = Path(tmp)
        for sync, n in (("NORMAL", n_normal), ("FULL", n_full)):
            rate, cpu_rate, floor = _store_rate(folder, sync, n, repeat)
            rows.append([sync, n, rate, rate * N_WL, rate / TARGET, cpu_rate, floor, rate / floor])
        path = folder / "read.sqlite"
        with RunStore(path) as s:
            rid = s.create_run("scan")
            for i in range(n_normal):
                s.add_point(rid, i, GEO, _rows(i))
            t_read, df = best_of(lambda: s.readings(rid), repeat)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    out = table(f"Run store: points committed per second, one transaction per point, {N_WL} wavelengths per point "
                f"(target >= {TARGET:,.0f} points/s with NORMAL; load average {load:.1f} on {os.cpu_count()} CPUs)",
                ["synchronous", "points", "points/s", "readings rows/s", "vs target", "points/CPU-s",
                 "raw sqlite3 points/s", "store/raw"], rows)
    out += (f"\nreadings() of {n_normal:,} points x {N_WL} wavelengths ({len(df):,} rows) as a tidy DataFrame: "
            f"{t_read * 1e3:.0f} ms")
    return out


if __name__ == "__main__":
    t0 = time.perf_counter()
    print(run())
    print(f"({time.perf_counter() - t0:.1f} s)")
