"""The run store: schema and pragmas, one transaction per point, duplicates, statuses, reading
back, concurrency, and crash safety under SIGKILL at random moments."""

from __future__ import annotations

import math
import os
import random
import re
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import bench.store.runstore as runstore_mod
from bench.core.errors import InputError, StoreError
from bench.core.geometry import Geometry
from bench.core.records import BSDF_COLUMNS
from bench.store import SCHEMA_VERSION, RunStore

ROOT = Path(__file__).resolve().parents[1]
WL = [400.0 + 10.0 * k for k in range(31)]
GEO = {"theta_i": 45.0, "phi_i": 0.0, "theta_r": 0.0, "phi_r": 0.0}


def _rows(idx: int, n: int = 31) -> list[dict]:
    return [{"wavelength_nm": 400.0 + 10.0 * j, "signal": idx * 1000.0 + j, "dark": 1.0, "white": 2000.0,
             "value": 0.5, "std": 0.01, "ci_lo": 0.48, "ci_hi": 0.52, "saturated": False} for j in range(n)]


@pytest.fixture
def run_store(tmp_path):
    """An open run store in the test's own directory."""
    with RunStore(tmp_path / "runs.sqlite") as s:
        yield s


# --- schema --------------------------------------------------------------------------------


def test_new_store_is_wal_with_schema_version_and_busy_timeout(tmp_path):
    path = tmp_path / "sub" / "runs.sqlite"
    with RunStore(path, timeout=7.5) as s:
        assert path.exists()
        assert s.pragma("journal_mode") == "wal"
        assert s.pragma("synchronous") == 1  # NORMAL
        assert s.pragma("busy_timeout") == 7500
        assert s.pragma("foreign_keys") == 1
        assert s.schema_version == SCHEMA_VERSION
    with RunStore(path, synchronous="full") as s:
        assert s.pragma("synchronous") == 2  # FULL
    db = sqlite3.connect(path)
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"schema_version", "runs", "points", "readings", "run_events"} <= tables
    cols = {r[1] for r in db.execute("PRAGMA table_info(readings)")}
    assert {"signal", "dark", "white", "value", "std", "ci_lo", "ci_hi", "saturated", "extra"} <= cols
    assert set(BSDF_COLUMNS) - {"theta_i", "phi_i"} <= cols
    db.close()


def test_unknown_schema_version_is_refused(tmp_path):
    path = tmp_path / "runs.sqlite"
    RunStore(path).close()
    db = sqlite3.connect(path)
    db.execute("INSERT INTO schema_version VALUES (?, 'future')", (SCHEMA_VERSION + 1,))
    db.commit()
    db.close()
    with pytest.raises(StoreError, match=r"schema version 2, newer"):
        RunStore(path)


def test_foreign_sqlite_file_and_garbage_are_refused(tmp_path):
    other = tmp_path / "other.sqlite"
    db = sqlite3.connect(other)
    db.execute("CREATE TABLE t (x)")
    db.commit()
    db.close()
    with pytest.raises(StoreError, match="not a goniobench run store"):
        RunStore(other)
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not a database" * 100)
    with pytest.raises(StoreError, match="not a usable run store"):
        RunStore(junk)
    with pytest.raises(StoreError, match="no run store"):
        RunStore(tmp_path / "missing.sqlite", create=False)


def test_bad_options_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="synchronous"):
        RunStore(tmp_path / "a.sqlite", synchronous="OFF")


# --- runs and points -----------------------------------------------------------------------


def test_create_run_records_metadata_versions_and_readable_id(run_store):
    rid = run_store.create_run("scan", plan={"points": np.arange(3)}, bench={"name": "virtual"}, seed=7,
                           meta={"specimen": "lambert"}, n_planned=3, calibration={"white": 0.99})
    assert re.fullmatch(r"\d{8}-\d{4}-[0-9a-f]{4}", rid)
    info = run_store.run(rid)
    assert info["status"] == "running" and info["kind"] == "scan"
    assert info["plan"] == {"points": [0, 1, 2]}
    assert info["bench"] == {"name": "virtual"} and info["seed"] == 7 and info["n_planned"] == 3
    assert info["calibration"] == {"white": 0.99}
    assert info["versions"]["python"] and "numpy" in info["versions"] and "numba" in info["versions"]
    assert info["created_utc"].endswith("Z") and abs(info["created_epoch"] - time.time()) < 60
    assert info["points_done"] == 0 and info["events"][0]["status"] == "running"
    ids = {run_store.create_run("scan") for _ in range(20)}
    assert len(ids) == 20
    with pytest.raises(InputError, match="kind"):
        run_store.create_run("nonsense")
    with pytest.raises(StoreError, match="already exists"):
        run_store.create_run("scan", run_id=rid)


def test_one_transaction_per_point(run_store):
    rid = run_store.create_run("scan")
    statements: list[str] = []
    run_store._db.set_trace_callback(statements.append)
    for i in range(3):
        run_store.add_point(rid, i, GEO, _rows(i), t_start=100.0 + i, t_end=100.5 + i)
    run_store._db.set_trace_callback(None)
    begins = [s for s in statements if s.strip().upper().startswith("BEGIN")]
    commits = [s for s in statements if s.strip().upper() == "COMMIT"]
    assert len(begins) == 3 and all("IMMEDIATE" in b.upper() for b in begins)
    assert len(commits) == 3
    # every statement of a point lies between its BEGIN and COMMIT
    first_begin = statements.index(begins[0])
    assert not any("INSERT" in s for s in statements[:first_begin])


def test_a_failure_inside_the_transaction_leaves_no_trace(run_store, monkeypatch):
    rid = run_store.create_run("scan")
    run_store.add_point(rid, 0, GEO, _rows(0))
    good = runstore_mod._reading_tuples

    def broken(run_id, idx, rows):  # the last tuple has a wrong arity: executemany fails mid-way
        t = good(run_id, idx, rows)
        return t[:-1] + [t[-1][:-1]]

    monkeypatch.setattr(runstore_mod, "_reading_tuples", broken)  # where add_point looks it up
    with pytest.raises(sqlite3.ProgrammingError):
        run_store.add_point(rid, 1, GEO, _rows(1))
    monkeypatch.undo()
    assert run_store.done_indices(rid) == {0}
    assert len(run_store.readings(rid)) == 31
    run_store.add_point(rid, 1, GEO, _rows(1))  # the store is still usable
    assert run_store.done_indices(rid) == {0, 1}


class _InterruptingConnection:
    """Delegates to a real connection; ``executemany`` inserts some rows, then Ctrl-C arrives."""

    def __init__(self, db):
        self._real = db

    def __getattr__(self, name):
        return getattr(self._real, name)

    def executemany(self, sql, rows):
        rows = list(rows)
        self._real.executemany(sql, rows[: len(rows) // 2])
        raise KeyboardInterrupt


def test_ctrl_c_in_the_middle_of_a_point_rolls_it_back(run_store):
    rid = run_store.create_run("scan")
    run_store.add_point(rid, 0, GEO, _rows(0))
    real = run_store._db
    run_store._db = _InterruptingConnection(real)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_store.add_point(rid, 1, GEO, _rows(1))
    finally:
        run_store._db = real
    assert not real.in_transaction
    assert run_store.done_indices(rid) == {0} and len(run_store.readings(rid)) == 31
    run_store.add_point(rid, 1, GEO, _rows(1))
    assert len(run_store.readings(rid)) == 62


def test_duplicate_index_is_refused_without_duplicate_rows(run_store):
    rid = run_store.create_run("scan")
    run_store.add_point(rid, 0, GEO, _rows(0))
    with pytest.raises(StoreError, match=rf"run '{rid}' already has point 0"):
        run_store.add_point(rid, 0, GEO, _rows(0))
    assert len(run_store.readings(rid)) == 31
    assert run_store.run(rid)["points_done"] == 1


def test_done_indices_and_bad_rows(run_store):
    rid = run_store.create_run("scan", n_planned=10)
    for i in (0, 1, 2, 5, 7):
        run_store.add_point(rid, i, Geometry(45, 0, 10 * i, 180), _rows(i, 3))
    assert run_store.done_indices(rid) == {0, 1, 2, 5, 7}
    with pytest.raises(InputError, match="no wavelength_nm"):
        run_store.add_point(rid, 3, GEO, [{"signal": 1.0}])
    with pytest.raises(InputError, match="signal must be a number"):
        run_store.add_point(rid, 3, GEO, [{"wavelength_nm": 500.0, "signal": "lots"}])
    with pytest.raises(InputError, match="index"):
        run_store.add_point(rid, -1, GEO, _rows(0))
    with pytest.raises(StoreError, match="unknown run 'nope'.*bench runs"):
        run_store.add_point("nope", 0, GEO, _rows(0))
    assert run_store.done_indices(rid) == {0, 1, 2, 5, 7}


def test_status_transitions_and_history(run_store):
    rid = run_store.create_run("scan", n_planned=2)
    run_store.add_point(rid, 0, GEO, _rows(0))
    run_store.set_status(rid, "interrupted", "Ctrl-C")
    info = run_store.run(rid)
    assert info["status"] == "interrupted" and info["reason"] == "Ctrl-C" and info["finished_utc"]
    run_store.set_status(rid, "running", "resumed")
    assert run_store.run(rid)["finished_utc"] is None
    run_store.add_point(rid, 1, GEO, _rows(1))
    run_store.set_status(rid, "completed")
    assert [e["status"] for e in run_store.run(rid)["events"]] == ["running", "interrupted", "running", "completed"]
    with pytest.raises(StoreError, match="cannot go from 'completed' to 'running'"):
        run_store.set_status(rid, "running")
    with pytest.raises(StoreError, match="is completed"):
        run_store.add_point(rid, 2, GEO, _rows(2))
    with pytest.raises(InputError):
        run_store.set_status(rid, "paused")
    other = run_store.create_run("scan")
    run_store.set_status(other, "failed", "HardwareError: overload")
    run_store.set_status(other, "running")
    run_store.set_status(other, "interrupted")
    with pytest.raises(StoreError, match="cannot go from 'interrupted' to 'completed'"):
        run_store.set_status(other, "completed")


def test_runs_run_summary_and_unknown_id(run_store):
    a = run_store.create_run("scan", n_planned=4, seed=3)
    for i in range(3):
        run_store.add_point(a, i, {"theta_i": 10.0 * i, "phi_i": 0, "theta_r": 45, "phi_r": 180},
                        [{"wavelength_nm": w, "value": 0.1 * i + w / 1e4, "saturated": w == 700.0} for w in WL],
                        t_start=1000.0 + i, t_end=1000.25 + i)
    b = run_store.create_run("sweep")
    listed = run_store.runs()
    assert [r["run_id"] for r in listed] == [a, b]
    assert listed[0]["points_done"] == 3 and listed[0]["n_planned"] == 4
    s = run_store.summary(a)
    assert s["status"] == "running" and s["points_done"] == 3 and s["points_planned"] == 4
    assert s["points_missing"] == 1 and s["first_missing"] == 3
    assert s["wavelengths"] == {"n": 31, "min": 400.0, "max": 700.0}
    assert s["geometry"]["theta_i"] == [0.0, 20.0] and s["geometry"]["theta_r"] == [45.0, 45.0]
    assert s["timing"]["mean_point_s"] == pytest.approx(0.25)
    assert s["value"]["min"] == pytest.approx(0.04) and s["value"]["max"] == pytest.approx(0.27)
    assert s["saturated"] == 3 and s["readings"] == 93
    with pytest.raises(StoreError, match=r"unknown run 'x'.*bench runs --store"):
        run_store.run("x")
    with pytest.raises(StoreError):
        run_store.summary("x")
    run_store.delete_run(b)
    assert [r["run_id"] for r in run_store.runs()] == [a]


def test_readings_are_tidy_with_geometry_extra_and_nan(run_store):
    rid = run_store.create_run("scan")
    rows = [{"wavelength_nm": np.float32(500.0), "signal": np.int64(12), "value": float("nan"),
             "saturated": np.bool_(True), "integration_s": 0.1, "note": "x"},
            {"wavelength_nm": 510.0, "signal": 13.0, "value": 0.2, "saturated": False}]
    run_store.add_point(rid, 4, Geometry(30, 0, 20, 180), rows, t_start=1.0, t_end=2.0)
    df = run_store.readings(rid)
    assert list(df.idx) == [4, 4]
    assert list(df.theta_i) == [30.0, 30.0] and list(df.theta_r) == [20.0, 20.0] and list(df.phi_r) == [180.0] * 2
    assert list(df.wavelength_nm) == [500.0, 510.0] and list(df.signal) == [12.0, 13.0]
    assert math.isnan(df.value[0]) and df.value[1] == 0.2
    assert list(df.saturated) == [1, 0]
    assert df.integration_s[0] == 0.1 and df.note[0] == "x" and pd.isna(df.note[1])
    assert list(df.t_start) == [1.0, 1.0]


def test_virtual_record_round_trips_through_the_store(run_store):
    from virtual.goniophotometer import VirtualGoniophotometer

    g = VirtualGoniophotometer("lambert:albedo=0.8", collector="equal-psa:5x12", rays=20_000, seed=2,
                               wavelengths=[450, 550], method="rays")
    rec = g.measure_bsdf(30.0)
    rec2 = g.measure_bsdf(60.0, 90.0)
    both = pd.concat([rec.table, rec2.table], ignore_index=True)
    rid = run_store.create_run("virtual", meta={"operator": "ci"})
    idx = run_store.add_record(rid, type(rec)(both, rec.meta))
    assert idx == [0, 1]
    back = run_store.to_record(rid)
    pd.testing.assert_frame_equal(back.table[BSDF_COLUMNS], both[BSDF_COLUMNS])
    assert back.meta["seed"] == 2 and back.meta["specimen"] == rec.meta["specimen"]
    assert back.meta["operator"] == "ci" and back.meta["run_id"] == rid
    assert back.meta["totals"] == rec.meta["totals"]
    assert run_store.add_record(rid, rec2, merge_meta=False) == [2]


def test_physical_scan_to_record_fills_hemisphere_and_keeps_signal(run_store):
    rid = run_store.create_run("scan")
    run_store.add_point(rid, 0, Geometry(45, 0, 0, 0), [{"wavelength_nm": 550.0, "value": 0.3, "signal": 9.0}])
    run_store.add_point(rid, 1, Geometry(45, 0, 170, 0), [{"wavelength_nm": 550.0, "value": 0.1, "signal": 3.0}])
    rec = run_store.to_record(rid)
    assert list(rec.table.hemisphere) == ["R", "T"]
    assert list(rec.table.signal) == [9.0, 3.0] and list(rec.table.idx) == [0, 1]
    assert rec.table.psa.isna().all()


# --- concurrency ---------------------------------------------------------------------------


def test_reader_is_not_blocked_by_an_open_write_transaction(tmp_path):
    path = tmp_path / "runs.sqlite"
    writer = RunStore(path)
    rid = writer.create_run("scan")
    writer.add_point(rid, 0, GEO, _rows(0))
    writer._db.execute("BEGIN IMMEDIATE")  # a point being written right now
    writer._db.execute("INSERT INTO points (run_id, idx, n_readings) VALUES (?, 1, 0)", (rid,))
    try:
        with RunStore(path, timeout=0.5) as reader:
            # a read that had to wait for the writer would fail with "database is locked" after
            # the 0.5 s timeout; in WAL mode it does not wait and sees committed points only
            assert reader.done_indices(rid) == {0}
            assert reader.summary(rid)["points_done"] == 1
            assert len(reader.readings(rid)) == 31
            with pytest.raises(StoreError, match="could not start a write transaction"):
                reader.add_point(rid, 2, GEO, _rows(2))
    finally:
        writer._db.execute("ROLLBACK")
        writer.close()


# --- crash safety --------------------------------------------------------------------------

_WRITER = textwrap.dedent("""
    import sys
    from bench.store import RunStore
    path, rid, start = sys.argv[1], sys.argv[2], int(sys.argv[3])
    s = RunStore(path)
    geo = {"theta_i": 45.0, "phi_i": 0.0, "theta_r": 0.0, "phi_r": 0.0}
    out = sys.stdout
    out.write("ready\\n"); out.flush()
    i = start
    while True:
        rows = [{"wavelength_nm": 400.0 + j, "signal": i * 1000.0 + j, "value": 0.5, "std": 0.01,
                 "saturated": False} for j in range(400)]
        out.write(f"b {i}\\n"); out.flush()
        s.add_point(sys.argv[2], i, geo, rows)
        out.write(f"c {i}\\n"); out.flush()
        i += 1
""")


def _check_prefix(path: Path, rid: str) -> int:
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    idx = sorted(r[0] for r in db.execute("SELECT idx FROM points WHERE run_id=?", (rid,)))
    k = len(idx)
    assert idx == list(range(k)), "stored points are not a prefix 0..k-1"
    per = dict(db.execute("SELECT idx, COUNT(*) FROM readings WHERE run_id=? GROUP BY idx", (rid,)).fetchall())
    assert set(per) == set(idx) and all(per[i] == 400 for i in idx), "a point has partial readings"
    n_read = dict(db.execute("SELECT idx, n_readings FROM points WHERE run_id=?", (rid,)).fetchall())
    assert all(n_read[i] == 400 for i in idx)
    bad = db.execute("SELECT COUNT(*) FROM readings WHERE run_id=? AND signal != idx * 1000.0 + "
                     "(wavelength_nm - 400.0)", (rid,)).fetchone()[0]
    assert bad == 0
    db.close()
    return k


def test_sigkill_mid_scan_leaves_a_complete_prefix_and_the_run_resumes(tmp_path):
    path = tmp_path / "crash.sqlite"
    with RunStore(path) as s:
        rid = s.create_run("scan", n_planned=10**6)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    killed_in_flight = 0
    k = 0
    for trial, seed in enumerate((11, 12, 13, 14, 15, 16)):
        delay = random.Random(seed).uniform(0.05, 0.5)
        proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(path), rid, str(k)], cwd=ROOT, env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        time.sleep(delay)
        os.kill(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate(timeout=30)
        assert proc.returncode == -signal.SIGKILL
        last = out.strip().splitlines()[-1].split() if out.strip() else ["c", str(k - 1)]
        new_k = _check_prefix(path, rid)
        j = int(last[1])
        if last[0] == "c":
            assert new_k == j + 1
        else:  # killed between starting point j and reporting its commit
            assert new_k in (j, j + 1)
            killed_in_flight += new_k == j
        assert new_k > k, f"trial {trial}: the writer committed nothing in {delay:.2f} s"
        k = new_k
    # a transaction was cut short at least once (the writer spends most of its time inside
    # add_point), and never left a trace
    assert killed_in_flight >= 1, killed_in_flight
    with RunStore(path) as s:  # the run can be appended to again, duplicates still refused
        assert s.done_indices(rid) == set(range(k))
        s.add_point(rid, k, GEO, [{"wavelength_nm": 400.0, "signal": k * 1000.0}])
        with pytest.raises(StoreError, match="already has point"):
            s.add_point(rid, k - 1, GEO, _rows(0))
        s.set_status(rid, "interrupted", "killed")


def test_leaving_a_with_block_closes_the_store_and_checkpoints_its_file(tmp_path):
    """``with RunStore(...)`` closes the connection on leaving (the class's own ``close``, not a
    base's no-op under the same name), so the file alone -- copied, without its WAL -- holds the
    runs (a leaked connection kept them in the WAL: a copy was "an empty file")."""
    import shutil
    import sqlite3

    path = tmp_path / "s.sqlite"
    with RunStore(path) as s:
        rid = s.create_run("scan", n_planned=1)
        s.set_status(rid, "completed")
    with pytest.raises(sqlite3.ProgrammingError):
        s._db.execute("SELECT 1")  # closed
    copy = tmp_path / "copy.sqlite"
    shutil.copy(path, copy)  # the file alone
    with RunStore(copy, create=False, readonly=True) as c:
        assert [r["run_id"] for r in c.runs()] == [rid]
    for name in ("close", "runs", "create_run"):  # every public method wrapped around its own definition
        assert getattr(RunStore, name).__wrapped__.__qualname__.split(".")[0] in ("RunStore", "RunReader"), name
