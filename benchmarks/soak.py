"""Soak: emulated scans under injected transient faults, random SIGKILL and resume.

``python -m benchmarks soak --minutes N [--json] [--seed S] [--rate P] [--points N]`` (``make soak``):
starts the three wire emulators of ``fixtures/benches/emulated.toml`` in this process, turns on
seeded random faults on all three protocols (``rate`` of the replies: Dynamixel statuses dropped,
corrupted -- the rest of the reply then arriving late -- or preceded by a stale status; Ocean
commands NAKed or unanswered and frames corrupted; AZ replies dropped or corrupted), and until the
time is up runs ``bench scan`` of an in-plane plan as a child process on a ``kind = "real"`` bench
file naming the emulators' ports. Some runs are SIGKILLed at a random moment and finished with
``bench resume`` (repeatedly, until completed); in some a stage alarm is raised mid-run, the run
ends interrupted by it, the alarm is cleared with ALM-RST (the operator's part) and the run resumed.

It reports runs, points, faults injected (by the emulators) and recovered (by the drivers, from
the runs' ``device_faults``), kills, resumes, device-fault exits (those from an injected alarm
apart), lost and duplicated points (every completed run holds each planned index exactly once,
with all its readings), leftovers (runs still ``running``, child processes still alive) and the
RSS trend of the scan process (MB per 10,000 points, least squares over each run's samples).
"""

from __future__ import annotations

import json
import os
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "fixtures" / "benches" / "emulated.toml"
#: the default shares of runs killed (then resumed) and of runs given a stage alarm mid-run
KILL_SHARE, ALARM_SHARE = 0.5, 0.15


def _plan(points: int, phi_i: float = 0.0) -> str:
    """An in-plane plan of about ``points`` points (two incidences) at azimuth ``phi_i``: runs
    at different azimuths move the turntable at their start (a stage alarm then shows)."""
    per = max(2, points // 2)
    step = 100.0 / (per - 1)
    return (f'name = "soak"\nkind = "in-plane"\nintegration_s = 0.002\naverages = 1\ndark = "per-incidence"\n'
            f'white = "none"\n[in_plane]\ntheta_i = [30, 45]\n'
            f'theta_r = {{ start = -20, stop = {-20 + step * (per - 1):.6f}, step = {step:.6f} }}\nphi_i = {phi_i:g}\n')


def _rss_kb(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _points(store: Path, run_id: str | None) -> int:
    if run_id is None or not store.exists():
        return 0
    try:
        with sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=5) as db:
            return int(db.execute("SELECT COUNT(*) FROM points WHERE run_id=?", (run_id,)).fetchone()[0])
    except sqlite3.Error:
        return 0


def _newest_run(store: Path, known: set[str]) -> str | None:
    if not store.exists():
        return None
    try:
        with sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=5) as db:
            rows = db.execute("SELECT run_id FROM runs ORDER BY created_epoch").fetchall()
    except sqlite3.Error:
        return None
    new = [r[0] for r in rows if r[0] not in known]
    return new[-1] if new else None


def _slope_mb_per_10k(samples: list[tuple[int, int]], skip: float = 0.2) -> float | None:
    """Least-squares slope of RSS (kB) over points, as MB per 10,000 points, leaving out the
    first ``skip`` of the points (imports, first allocations); None for fewer than 200 points.
    A leak shows as the same slope with ``skip = 0.5``; a warm-up that levels off (measured: +3.4
    MB over a faulted 6,000-point run's first 2,750 points, +0.18 MB over the next 3,200) shows as
    a late slope well below the early one."""
    if not samples:
        return None
    top = max(p for p, _ in samples)
    pts = [(p, r) for p, r in samples if p >= top * skip]
    if len(pts) < 10 or pts[-1][0] - pts[0][0] < 200:
        return None
    n = len(pts)
    mx = sum(p for p, _ in pts) / n
    my = sum(r for _, r in pts) / n
    sxx = sum((p - mx) ** 2 for p, _ in pts)
    sxy = sum((p - mx) * (r - my) for p, r in pts)
    return (sxy / sxx) * 10_000 / 1024 if sxx > 0 else None


class Soak:
    """One soak session: the emulators, the store, the counters (see the module docstring)."""

    def __init__(self, minutes: float, seed: int, rate: float, points: int, workdir: Path,
                 kill_share: float = KILL_SHARE, alarm_share: float = ALARM_SHARE) -> None:
        import tomli_w

        from bench.builders.emulated import Emulators
        from bench.core.parsing import read_toml

        self.minutes, self.seed, self.rate, self.points_per_run = minutes, seed, rate, points
        self.kill_share, self.alarm_share = kill_share, alarm_share
        self.rng = random.Random(seed)
        self.workdir = workdir = workdir.resolve()
        self.store = workdir / "soak.sqlite"
        self.plan = workdir / "plan.toml"
        d = read_toml(BENCH, "bench config")
        d.setdefault("emulated", {})["seed"] = seed
        self.emu = Emulators(d, seed)
        self.bench = workdir / "bench.toml"
        self.bench.write_text(tomli_w.dumps(self.emu.real_bench_config()))
        self._faults_on()
        self.runs: list[dict[str, Any]] = []
        self.kills = self.resumes = self.alarms = 0
        self.exits: list[str] = []       # exit 1: a run that failed on its own (device faults)
        self.refusals: list[str] = []    # exit 2: refused input (none expected)
        self.rss: list[float] = []
        self.child_cpu_s = 0.0

    def _faults_on(self) -> None:
        from virtual.wire.dynamixel_bus import BusControl

        third = self.rate / 3
        with BusControl(self.emu.ports()["dynamixel_control"]) as bus:
            bus.faults(drop_rate=third, corrupt_rate=third, stale_rate=third, late_s=0.02)
        self.emu.spectrometer.fault_rate(self.rate, self.seed)
        self.emu.stage.fault_rate(self.rate, self.seed)

    def injected(self) -> dict[str, dict[str, int]]:
        from virtual.wire.dynamixel_bus import BusControl

        with BusControl(self.emu.ports()["dynamixel_control"]) as bus:
            f = bus.faults()["faults"]
        return {"dynamixel": {k: int(f[k]) for k in ("dropped", "corrupted", "late", "stale")},
                "spectrometer": self.emu.spectrometer.injected(), "stage": self.emu.stage.injected()}

    # -- one child process -------------------------------------------------------------------------
    def _child(self, argv: list[str], run_id: str | None, kill_after: float | None,
               alarm_after: float | None) -> tuple[int, str, str | None, list[tuple[int, int]]]:
        """Run ``bench ARGV``; SIGKILL it after ``kill_after`` s, raise a stage alarm after
        ``alarm_after`` s; return (exit status, stderr, run id, (points, RSS kB) samples)."""
        known = {r["run_id"] for r in self.runs}
        cmd = [sys.executable, "-m", "bench.cli", *argv, "--store", str(self.store), "--quiet"]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        err_path = self.workdir / "stderr.txt"
        with open(err_path, "w") as err:
            proc = subprocess.Popen(cmd, cwd=self.workdir, stdout=subprocess.DEVNULL, stderr=err, env=env)
            t0, samples = time.monotonic(), []
            while proc.poll() is None:
                time.sleep(0.25)
                run_id = run_id or _newest_run(self.store, known)
                rss = _rss_kb(proc.pid)
                if rss is not None and run_id is not None:
                    samples.append((_points(self.store, run_id), rss))
                elapsed = time.monotonic() - t0
                if alarm_after is not None and elapsed > alarm_after and run_id is not None:
                    self.emu.stage.alarm(0x30)
                    self.alarms += 1
                    alarm_after = None
                if kill_after is not None and elapsed > kill_after and run_id is not None:
                    proc.send_signal(signal.SIGKILL)
                    self.kills += 1
                    kill_after = None
            proc.wait()
        return proc.returncode, err_path.read_text(), run_id or _newest_run(self.store, known), samples

    def one_run(self) -> None:
        """A scan, then resumes until the run is completed (or the time is up)."""
        kill = self.rng.random() < self.kill_share
        alarm = not kill and self.rng.random() < self.alarm_share
        expected_s = max(2.0, self.points_per_run * 0.05)
        self.plan.write_text(_plan(self.points_per_run, self.rng.choice((0.0, 20.0, 40.0))))
        argv = ["scan", str(self.plan), "--bench", str(self.bench)]
        run_id, rec = None, {"run_id": None, "exits": [], "samples": []}
        for attempt in range(20):
            code, err, run_id, samples = self._child(
                argv, run_id, self.rng.uniform(1.0, expected_s) if kill and attempt < 2 else None,
                self.rng.uniform(1.0, expected_s) if alarm and attempt == 0 else None)
            rec["run_id"], rec["samples"] = run_id, rec["samples"] + samples
            rec["exits"].append(code)
            if code == 0:
                break
            line = err.strip().splitlines()[-1] if err.strip() else f"exit {code}"
            if code == 2 and "already completed" in line:
                break  # killed after its last commit: the resume finds it complete
            if code == 2:  # refused (bad input), not a device fault
                self.refusals.append(line[:300])
            if code > 0 and code != 2:  # a failure the run reported itself (1), or an internal error (70)
                injected_alarm = "HardwareError" in line and "alarm 0x30" in line
                self.exits.append(("alarm: " if injected_alarm else "") + line[:300])
                if injected_alarm:
                    from drivers.modbus import ModbusStageAxis

                    ax = ModbusStageAxis(self.emu.stage.url, name="turntable")
                    ax.reset_alarm()  # the operator clears the alarm
                    ax.close()
            if code == 2 or (code > 0 and run_id is None):
                break  # refused, or failed before a run existed: nothing to resume
            if run_id is None:
                break
            argv = ["resume", run_id]
            self.resumes += 1
        self.runs.append(rec)

    def run(self) -> dict[str, Any]:
        """Runs until the time is up (at least one)."""
        t0 = time.monotonic()
        while not self.runs or time.monotonic() < t0 + self.minutes * 60.0:
            self.one_run()
        return self.report(time.monotonic() - t0)

    # -- the account -------------------------------------------------------------------------------
    def report(self, seconds: float) -> dict[str, Any]:
        import resource

        from bench.store import RunStore

        lost = dup = incomplete = points = 0
        recovered: dict[str, int] = {}
        with RunStore(self.store, readonly=True) as store:
            statuses = {r["run_id"]: r["status"] for r in store.runs()}
            for rec in self.runs:
                rid = rec["run_id"]
                if rid is None:
                    continue
                info = store.run(rid)
                if info["status"] != "completed":
                    incomplete += 1
                    continue
                readings = store.readings(rid)
                per_point = readings.groupby("idx").size()
                planned = int(info["n_planned"])
                done = set(int(i) for i in per_point.index)
                lost += planned - len(done & set(range(planned)))
                dup += int((per_point != per_point.max()).sum()) + max(0, len(per_point) - planned)
                points += len(done)
                for k, v in ((info.get("meta") or {}).get("device_faults") or {}).get("total", {}).items():
                    recovered[k] = recovered.get(k, 0) + int(v)
        slopes = [s for s in (_slope_mb_per_10k(r["samples"]) for r in self.runs) if s is not None]
        longest = max(self.runs, key=lambda r: len(r["samples"]), default=None)
        transient = [e for e in self.exits if not e.startswith("alarm: ")]
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return {
            "minutes": round(seconds / 60.0, 2), "seed": self.seed, "rate": self.rate,
            "runs": len(self.runs), "runs_completed": len(self.runs) - incomplete, "points": points,
            "kills": self.kills, "resumes": self.resumes, "alarms_injected": self.alarms,
            "device_fault_exits": len(transient), "device_fault_exit_lines": transient[:10],
            "alarm_exits": len(self.exits) - len(transient), "refusals": self.refusals[:10],
            "faults_injected": self.injected(),
            "faults_seen_by_drivers": {k: v for k, v in sorted(recovered.items()) if ".fault." in k},
            # counted per measured point (open, calibration and killed points are not in a run's record)
            "recovered": sum(v for k, v in recovered.items() if k.endswith(".recovered")),
            "failed_transactions": sum(v for k, v in recovered.items() if k.endswith(".failed")),
            "lost_points": lost, "duplicated_points": dup,
            "leftover_running_runs": sum(1 for s in statuses.values() if s == "running"),
            "rss_mb_per_10k_points": {"max": max(slopes) if slopes else None,
                                      "longest_run": _slope_mb_per_10k(longest["samples"]) if longest else None,
                                      "longest_run_second_half": (_slope_mb_per_10k(longest["samples"], 0.5)
                                                                  if longest else None)},
            "children_cpu_s": round(ru.ru_utime + ru.ru_stime, 1),
            "wall_s_per_point": round(seconds / points, 4) if points else None,
        }

    def close(self) -> int:
        """Stop the emulators; the number of child processes still alive after that (leftovers)."""
        import multiprocessing

        self.emu.close()
        time.sleep(0.2)
        return len([p for p in multiprocessing.active_children() if p.is_alive()])


def run_soak(minutes: float, seed: int = 7, rate: float = 0.01, points: int = 120, kill_share: float = KILL_SHARE,
             alarm_share: float = ALARM_SHARE, workdir: Path | None = None) -> dict[str, Any]:
    """Run the soak (see the module docstring) and return its report."""
    with tempfile.TemporaryDirectory(prefix="goniobench-soak-") as tmp:
        soak = Soak(minutes, seed, rate, points, Path(workdir or tmp), kill_share, alarm_share)
        try:
            out = soak.run()
        finally:
            leftovers = soak.close()
        out["leftover_processes"] = leftovers
        return out


def main(argv: list[str]) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m benchmarks soak", description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=60.0)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--rate", type=float, default=0.01, help="share of replies with an injected fault")
    p.add_argument("--points", type=int, default=120, help="points per run")
    p.add_argument("--kill-share", type=float, default=KILL_SHARE, help="share of runs SIGKILLed and resumed")
    p.add_argument("--alarm-share", type=float, default=ALARM_SHARE, help="share of runs given a stage alarm")
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    if not (0 < a.minutes <= 24 * 60 and 0 <= a.rate <= 0.2 and 4 <= a.points <= 100_000
            and 0 <= a.kill_share <= 1 and 0 <= a.alarm_share <= 1):
        print("soak: --minutes in (0, 1440], --rate in [0, 0.2], --points in [4, 100000], shares in [0, 1]",
              file=sys.stderr)
        return 2
    out = run_soak(a.minutes, a.seed, a.rate, a.points, a.kill_share, a.alarm_share)
    print(json.dumps(out, indent=None if a.json else 2))
    bad = out["device_fault_exits"] or out["refusals"] or out["lost_points"] or out["duplicated_points"] or \
        out["leftover_running_runs"] or out["leftover_processes"]
    return 1 if bad else 0
