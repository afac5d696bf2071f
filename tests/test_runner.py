"""The runner on the virtual bench: records, interruption, resume, SIGKILL crash safety."""

import math
import os
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.config import load_bench
from bench.core.errors import DeviceTimeoutError, PlanError, RunInterrupted
from bench.plans import load_plan, plan_from_dict
from bench.runner import resume_scan, run_scan
from bench.store import RunStore
from store_probe import kill_once_committed

ROOT = Path(__file__).parent.parent
BENCH = ROOT / "fixtures" / "benches" / "virtual.toml"
PLAN = {"name": "small", "kind": "in-plane", "integration_s": 0.01, "averages": 1, "dark": "per-incidence",
        "white": "once", "in_plane": {"theta_i": [20, 40], "theta_r": {"start": -10, "stop": 74, "step": 6}}}


def _values(store, run_id):
    df = store.readings(run_id).sort_values(["idx", "wavelength_nm"])
    return df[["idx", "theta_i", "theta_r", "phi_r", "wavelength_nm", "signal", "value", "std"]].reset_index(drop=True)


def test_scan_records_calibrated_brdf_of_the_virtual_specimen(tmp_path):
    plan = plan_from_dict(PLAN)
    with load_bench(BENCH, seed=3) as bench, RunStore(tmp_path / "s.sqlite") as store:
        res = run_scan(bench, plan, store, seed=3)
        assert res.status == "completed" and res.points_done == len(plan) == 30
        df = store.readings(res.run_id)
        assert len(df) == 30 * 3  # 3 wavelengths per point
        # a Lambertian of albedo 0.8 measured against a 0.99 standard: f = 0.8/pi; each value
        # within 5 of its own standard uncertainties (patch counting noise + the white's)
        z = (df["value"] - 0.8 / math.pi) / df["std"]
        assert np.all(np.abs(z) < 5)
        # the mean over all points shares one white reading (a virtual standard measured with the
        # same rays), so its error is dominated by the white's relative uncertainty
        cal = store.run(res.run_id)["calibration"]["white"]
        rel_white = cal["std"][0] / cal["signal"][0]
        rel_mean = math.sqrt(rel_white**2 + np.mean((df["std"] / df["value"]) ** 2) / len(df))
        assert abs(np.mean(df["value"]) * math.pi / 0.8 - 1) < 4 * rel_mean
        assert store.run(res.run_id)["status"] == "completed"


def test_interrupted_then_resumed_equals_an_uninterrupted_run(tmp_path):
    plan = plan_from_dict(PLAN)
    with RunStore(tmp_path / "s.sqlite") as store:
        with load_bench(BENCH, seed=11) as bench:
            full = run_scan(bench, plan, store, seed=11).run_id

        def ctrl_c(k, idx):
            if k == 13:
                raise KeyboardInterrupt

        with load_bench(BENCH, seed=11) as bench:
            with pytest.raises(RunInterrupted, match="resume"):
                run_scan(bench, plan, store, seed=11, on_point=ctrl_c)
        rid = store.runs()[-1]["run_id"]
        info = store.run(rid)
        assert info["status"] == "interrupted" and "Ctrl-C" in info["reason"] and info["points_done"] == 13
        with load_bench(info["bench"], seed=info["seed"]) as bench:  # a fresh process would do this
            res = resume_scan(bench, store, rid)
        assert res.status == "completed" and store.done_indices(rid) == set(range(30))
        a, b = _values(store, full), _values(store, rid)
        assert a.equals(b)  # bit for bit: same seed, same calibration, same rays


def test_device_fault_ends_the_run_cleanly_with_the_reason(tmp_path):
    plan = plan_from_dict(PLAN)

    def fault(k, idx):
        if k == 5:
            raise DeviceTimeoutError("spectrometer did not answer 'S' within 2.0 s")

    with load_bench(BENCH, seed=1) as bench, RunStore(tmp_path / "s.sqlite") as store:
        with pytest.raises(RunInterrupted, match="device fault"):
            run_scan(bench, plan, store, seed=1, on_point=fault)
        info = store.run(store.runs()[-1]["run_id"])
        assert info["status"] == "interrupted" and "DeviceTimeoutError" in info["reason"]
        assert info["points_done"] == 5


def test_a_plan_with_one_unreachable_point_is_refused_before_any_motion(tmp_path):
    d = {"kind": "list", "points": [[10, 0, 20, 180], [95, 0, 20, 180], [30, 0, 40, 180]]}
    plan = plan_from_dict(d)
    with load_bench(BENCH, seed=1) as bench, RunStore(tmp_path / "s.sqlite") as store:
        moves = []
        original = bench.goniometer.move_to
        bench.goniometer.move_to = lambda g: moves.append(g) or original(g)
        with pytest.raises(PlanError, match=r"point 1 .*theta_i=95"):
            run_scan(bench, plan, store, seed=1)
        assert moves == [] and store.runs() == []


@pytest.mark.slow
def test_sigkill_mid_scan_then_resume_gives_exactly_the_uninterrupted_record(tmp_path):
    plan_path = tmp_path / "plan.toml"
    plan_path.write_text(
        'name = "crash"\nkind = "in-plane"\nintegration_s = 0.01\ndark = "once"\nwhite = "once"\n'
        '[in_plane]\ntheta_i = [25, 40, 55]\ntheta_r = { start = -16, stop = 84, step = 2 }\n')
    n_points = len(load_plan(plan_path))
    bench_exe = [sys.executable, "-m", "bench.cli"]
    env = dict(os.environ)
    ref_store = tmp_path / "ref.sqlite"
    subprocess.run(bench_exe + ["scan", str(plan_path), "--bench", str(BENCH), "--store", str(ref_store),
                                "--seed", "5", "-q"], check=True, capture_output=True, env=env)
    with RunStore(ref_store) as store:
        ref = _values(store, store.runs()[0]["run_id"])
    rng = random.Random(20261122)
    mid_scan = 0
    for trial in range(3):
        db = tmp_path / f"crash{trial}.sqlite"
        target = rng.randrange(1, n_points - 1)
        proc = subprocess.Popen(bench_exe + ["scan", str(plan_path), "--bench", str(BENCH), "--store", str(db),
                                             "--seed", "5", "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                env=env)
        kill_once_committed(proc, db, target, poll_s=0.002)
        proc.wait(10)
        with RunStore(db) as store:
            rid = store.runs()[0]["run_id"]
            done = store.done_indices(rid)
            assert len(done) >= min(target, 1)  # killed mid-scan: a prefix of the work is committed
            # every committed point is whole: all its readings are there
            counts = store.readings(rid).groupby("idx").size()
            assert set(counts) <= {3} and len(counts) == len(done)
        if len(done) < n_points:  # killed mid-scan (under heavy load the scan may win the race)
            mid_scan += 1
            r = subprocess.run(bench_exe + ["resume", rid, "--store", str(db), "-q"], capture_output=True,
                               text=True, env=env)
            assert r.returncode == 0, r.stderr
        with RunStore(db) as store:
            assert store.done_indices(rid) == set(range(n_points))
            assert store.run(rid)["status"] == "completed"
            assert _values(store, rid).equals(ref), f"trial {trial}: resumed record differs"
    assert mid_scan >= 1, "no kill landed mid-scan: the test did not test a crash"
