"""Conformance cells of ownership: one process per instrument.

Cells: the emulated body served by ``bench emulate`` (the real drivers over the wire-level
emulators, as a lab shares one bench) x ``bench scan`` of a 303-point in-plane plan x a second
process on the same devices (``bench scan``, ``bench home``) x the owner ending cleanly or killed
(SIGKILL).

Invariant: the second process is refused in one line naming the owner (pid, run) and exits 2
before any motion (it creates no run); the first run completes with every planned point stored
once, no reading lost or duplicated; read-only commands (``plan``, ``show``, ``runs``, ``export``)
work beside the owner; after a SIGKILL the next process takes the devices over with a note naming the
dead owner, and ``bench resume`` completes the run with every point exactly once.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import tomli_w

from tests.helpers.cli import ROOT, run_bench

pytestmark = pytest.mark.slow  # each cell runs a 303-point scan on emulators (tens of seconds)

PLAN = """name = "two-owners"
kind = "in-plane"
integration_s = 0.08
averages = 4
dark = "none"
white = "none"

[in_plane]
theta_i = [30, 45, 60]
theta_r = { start = -20, stop = 80, step = 1 }
phi_i = 0
"""
N_POINTS = 303
N_BANDS = 3  # fixtures/benches/emulated.toml: bands 450:650:100
GIVE_UP_S = 300.0  # a guard against a hung child, not a speed bound


@pytest.fixture(scope="module")
def shared_bench(tmp_path_factory):
    """``bench emulate`` in its own process, and the real-bench file it prints."""
    d = tmp_path_factory.mktemp("owners")
    env = {**os.environ, "GONIOBENCH_LOCK_DIR": str(d / "locks")}
    emu = subprocess.Popen([sys.executable, "-m", "bench.cli", "emulate", str(ROOT / "fixtures/benches/emulated.toml"),
                            "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        line = emu.stdout.readline()
        assert line, emu.stderr.read()
        (d / "bench.toml").write_text(tomli_w.dumps(json.loads(line)["real_bench"]))
        (d / "plan.toml").write_text(PLAN)
        yield d, env
    finally:
        emu.send_signal(signal.SIGTERM)  # bench emulate stops its emulators on SIGTERM
        emu.wait(30)


def _scan(d: Path, env: dict, store: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "bench.cli", "scan", str(d / "plan.toml"), "--bench",
                             str(d / "bench.toml"), "--store", str(store), "--json", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)


def _owner(d: Path, env: dict, store: Path) -> tuple[subprocess.Popen, str]:
    """A first scan into ``store`` once it owns the devices and has started its run: (the
    process, its run id); the process is killed when it never gets there."""
    first = _scan(d, env, store)
    try:
        return first, _owner_run(d, first)
    except BaseException:
        first.kill()
        first.wait()
        raise


def _owner_run(d: Path, proc: subprocess.Popen) -> str:
    """Wait until ``proc`` owns the devices and has started its run; return the run id."""
    end = time.monotonic() + GIVE_UP_S
    while time.monotonic() < end:
        for f in (d / "locks").glob("*.lock") if (d / "locks").is_dir() else ():
            try:
                rec = json.loads(f.read_text() or "{}")
            except ValueError:
                continue
            if rec.get("pid") == proc.pid and rec.get("run"):
                return str(rec["run"])
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    pytest.fail("the first scan never started its run")


def _together(env: dict, *commands: tuple) -> list[subprocess.CompletedProcess]:
    """Run ``bench`` commands side by side (the first scan is short on a fast host); wait for all."""
    procs = [subprocess.Popen([sys.executable, "-m", "bench.cli", *map(str, c)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env) for c in commands]
    done = []
    for c, p in zip(commands, procs):
        out, err = p.communicate(timeout=GIVE_UP_S)
        done.append(subprocess.CompletedProcess(c, p.returncode, out, err))
    return done


def _points(store: Path, run_id: str) -> tuple[list[int], dict[int, int]]:
    db = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
    try:
        idx = [r[0] for r in db.execute("SELECT idx FROM points WHERE run_id=? ORDER BY idx", (run_id,))]
        per = dict(db.execute("SELECT idx, COUNT(*) FROM readings WHERE run_id=? GROUP BY idx", (run_id,)).fetchall())
        runs = [r[0] for r in db.execute("SELECT run_id FROM runs")]
    finally:
        db.close()
    assert runs == [run_id], "a refused process created a run"
    return idx, per


def _refused(proc: subprocess.CompletedProcess, owner_pid: int, run_id: str) -> None:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and "is in use by" in lines[0], proc.stderr
    assert f"pid {owner_pid}" in lines[0] and f"run {run_id}" in lines[0] and "bench scan" in lines[0]


def test_a_second_owner_is_refused_and_the_first_run_loses_nothing(shared_bench, tmp_path):
    d, env = shared_bench
    store = tmp_path / "runs.db"
    first, run_id = _owner(d, env, store)
    try:
        # all at once, while the first scan runs: a second scan, a homing, and read-only commands
        # (which never open or lock hardware, so they work beside the owner)
        second, home, show, runs, plan = _together(
            env, ("scan", d / "plan.toml", "--bench", d / "bench.toml", "--store", tmp_path / "other.db", "--json",
                  "--quiet"),
            ("home", "--bench", d / "bench.toml"), ("show", run_id, "--store", store, "--json"),
            ("runs", "--store", store), ("plan", d / "plan.toml", "--bench", d / "bench.toml", "--json"))
        alive_meanwhile = first.poll() is None
        out, err = first.communicate(timeout=GIVE_UP_S)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert alive_meanwhile, "the first scan ended before the others were tried: the cell tested nothing"
    _refused(second, first.pid, run_id)
    assert second.stdout == "" and not (tmp_path / "other.db").exists()
    _refused(home, first.pid, run_id)
    assert show.returncode == 0 and runs.returncode == 0, (show.stderr, runs.stderr)
    assert plan.returncode == 0 and json.loads(plan.stdout)["refused"] == [], plan.stderr  # planned from the description
    assert first.returncode == 0, err
    result = json.loads(out)
    assert (result["status"], result["points_done"], result["points_planned"]) == ("completed", N_POINTS, N_POINTS)
    idx, per = _points(store, run_id)
    assert idx == list(range(N_POINTS)) and set(per.values()) == {N_BANDS}
    export = run_bench("export", run_id, "--store", store, "--out", tmp_path / "run.csv", env=env)
    assert export.returncode == 0, export.stderr


def test_a_killed_owner_is_taken_over_and_its_run_resumed_whole(shared_bench, tmp_path):
    d, env = shared_bench
    store = tmp_path / "runs.db"
    first, run_id = _owner(d, env, store)
    first.send_signal(signal.SIGKILL)
    first.wait()
    home = run_bench("home", "--bench", d / "bench.toml", env=env)
    assert home.returncode == 0, home.stderr
    assert "taking over the lock" in home.stderr and f"pid {first.pid}" in home.stderr and "no longer runs" in home.stderr
    resume = run_bench("resume", run_id, "--store", store, "--json", "--quiet", env=env)
    assert resume.returncode == 0, resume.stderr
    assert "taking over" not in resume.stderr  # bench home released the devices cleanly
    assert json.loads(resume.stdout)["status"] == "completed"
    idx, per = _points(store, run_id)
    assert idx == list(range(N_POINTS)) and set(per.values()) == {N_BANDS}
