"""The same plan on the virtual and on the emulated bench (real drivers over emulators)."""

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from bench.config import load_bench
from bench.builders.emulated import DEFAULT_EMULATED_CONFIG
from bench.core.parsing import read_toml
from bench.core.errors import PlanError, RunInterrupted
from bench.plans import plan_from_dict
from bench.runner import resume_scan, run_scan
from bench.store import RunStore

ROOT = Path(__file__).parent.parent
BENCHES = ROOT / "fixtures" / "benches"
SHORT = {"name": "short", "kind": "in-plane", "integration_s": 0.02, "averages": 2, "dark": "once", "white": "once",
         "in_plane": {"theta_i": [30, 50], "theta_r": {"start": -10, "stop": 70, "step": 10}}}


def test_the_fixture_and_the_embedded_emulated_bench_agree():
    assert read_toml(BENCHES / "emulated.toml") == DEFAULT_EMULATED_CONFIG


def test_same_plan_same_schema_and_values_within_uncertainty(tmp_path):
    plan = plan_from_dict(SHORT)
    with RunStore(tmp_path / "s.sqlite") as store:
        with load_bench(BENCHES / "virtual.toml", seed=4) as bench:
            v_id = run_scan(bench, plan, store, seed=4).run_id
        with load_bench(BENCHES / "emulated.toml") as bench:
            e_id = run_scan(bench, plan, store).run_id
        v, e = store.readings(v_id), store.readings(e_id)
    assert list(v.columns) == list(e.columns)
    key = ["idx", "wavelength_nm"]
    m = v.merge(e, on=key, suffixes=("_v", "_e"))
    assert len(m) == len(v) == len(e) == len(plan) * 3
    # read-back geometry of the real drivers is within the servo resolution of the plan's
    assert np.all(np.abs(m.theta_r_v - m.theta_r_e) < 0.2)
    # values agree within their combined standard uncertainties: |z| < 4.5 everywhere
    # (Bonferroni over 54 values at two-sided 1e-3 gives 4.4) and the chi-square of all of them
    # is not significant at 1e-3. Both sides include the white standard's 0.5 % in their std;
    # counting it twice only makes the test conservative.
    z = (m.value_v - m.value_e) / np.hypot(m.std_v, m.std_e)
    assert np.all(np.abs(z) < 4.5)
    assert stats.chi2.sf(float(np.sum(z**2)), df=len(z)) > 1e-3


@pytest.mark.slow  # an emulator killed mid-scan and the run resumed (9 s under load)
def test_spectrometer_dies_mid_scan_then_resume_finishes(tmp_path):
    plan = plan_from_dict(SHORT)
    with RunStore(tmp_path / "s.sqlite") as store:
        bench = load_bench(BENCHES / "emulated.toml")
        try:
            def kill(k, idx):
                if k == 4:
                    bench.parts["emulators"].spectrometer.die()

            with pytest.raises(RunInterrupted, match="device fault"):
                run_scan(bench, plan, store, on_point=kill)
        finally:
            bench.close()
        rid = store.runs()[-1]["run_id"]
        info = store.run(rid)
        assert info["status"] == "interrupted"
        assert any(name in info["reason"] for name in ("PortGoneError", "DeviceTimeoutError"))
        assert info["points_done"] == 4
        with load_bench(info["bench"]) as bench:  # the emulator is back (a new process)
            res = resume_scan(bench, store, rid)
        assert res.status == "completed" and store.done_indices(rid) == set(range(len(plan)))
        df = store.readings(rid)
        assert df.groupby("idx").size().eq(3).all() and np.all(np.isfinite(df["value"]))


def test_one_unreachable_point_is_refused_before_any_byte(tmp_path):
    plan = plan_from_dict({"kind": "list", "points": [[30, 0, 20, 180], [30, 0, 60, 0], [40, 0, 10, 180]]})
    with load_bench(BENCHES / "emulated.toml") as bench, RunStore(tmp_path / "s.sqlite") as store:
        arm = bench.parts["arm"]
        sent = []
        write = arm.transport.write
        arm.transport.write = lambda data: (sent.append(bytes(data)), write(data))[1]
        stage_moves = []
        turntable = bench.parts["turntable"]
        move = turntable.move_to_deg
        turntable.move_to_deg = lambda a: (stage_moves.append(a), move(a))[1]
        with pytest.raises(PlanError, match=r"point 1 \(theta_i=30, phi_i=0, theta_r=60, phi_r=0\): arm_collision"):
            run_scan(bench, plan, store)
        assert sent == [] and stage_moves == [] and store.runs() == []
