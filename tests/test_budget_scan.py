"""GUM budgets of a scan: stored with each point, shown by ``bench show --json``, exported as u_c, U
and k, read back into the full covariance; old stores still read; the Monte Carlo method from the
command line; and the same budget structure on the virtual and the emulated body of one
description (the components are the declared effects, whichever body runs them).
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import load_bench
from bench.core.budget import COMPONENT_KEYS, readings_and_covariance
from bench.io import export_record
from bench.io.tidy import read_tidy_csv
from bench.plans import plan_from_dict
from bench.runner import point_rows, run_scan
from bench.store import RunStore

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"

#: every optional component declared: the [instrument] effects the virtual body simulates, and
#: the type-B knowledge of the [uncertainty] table
DECLARED = {"instrument": {"dark_counts": 100.0, "read_noise": 4.0, "shot_noise": True, "lamp_drift": 0.001,
                           "positioning_error_deg": 0.05, "seed": 3},
            "uncertainty": {"nonlinearity": 0.001, "aperture": 0.002}}
NAMES = ["counting noise", "read noise", "dark reading", "white reference reading", "white standard certificate",
         "lamp drift", "nonlinearity", "detector solid angle", "positioning theta_i", "positioning phi_i",
         "positioning theta_r", "positioning phi_r"]
PLAN = {"name": "three", "kind": "list", "integration_s": 0.05, "averages": 2, "dark": "once",
        "list": {"points": [[30, 0, 20, 180], [30, 0, 40, 180], [30, 0, 60, 180]]}}
VIRTUAL = {"name": "budget", "kind": "virtual", "specimen": {"spec": "lambert:albedo=0.8"},
           "white": {"reflectance_factor": 0.99, "uncertainty": 0.005},
           "virtual": {"collector": "equal-psa:9x36", "rays": 10_000_000, "wavelengths": "450:650:100"}, **DECLARED}


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    path = tmp_path_factory.mktemp("budget") / "runs.sqlite"
    with RunStore(path) as store, load_bench(copy.deepcopy(VIRTUAL), seed=5) as bench:
        run = run_scan(bench, plan_from_dict(PLAN), store, seed=5).run_id
    return path, run


def test_each_reading_of_a_scan_carries_its_budget(scanned):
    path, run = scanned
    with RunStore(path, create=False) as store:
        rows = store.reading_budgets(run)
        record = store.to_record(run)
    assert len(rows) == 9
    for r in rows:
        b = r["uncertainty_budget"]
        assert [c["name"] for c in b["components"]] == NAMES
        assert all(set(COMPONENT_KEYS) <= set(c) for c in b["components"])
        assert b["combined"] == pytest.approx(math.sqrt(sum(c["contribution"] ** 2 for c in b["components"])), rel=1e-12)
        assert r["std"] == pytest.approx(b["combined"], rel=1e-12) and b["expanded"] == pytest.approx(2 * b["combined"])
    # lamp drift: the k-th lit reading after the white is off by lamp_drift * k (the virtual body's model)
    drift = [next(c for c in r["uncertainty_budget"]["components"] if c["name"] == "lamp drift") for r in rows]
    assert sorted({round(d["standard_uncertainty"], 12) for d in drift}) == [0.001, 0.002, 0.003]
    np.testing.assert_allclose(record.table.u_c, record.table["std"])
    np.testing.assert_allclose(record.table.U, 2 * record.table.u_c)


def test_show_json_and_the_tidy_export_carry_the_budget(scanned, tmp_path, capsys):
    path, run = scanned
    assert main(["show", run, "--store", str(path)]) == 0
    assert "uncertainty: GUM budgets on 9 of 9 readings (linear, k = 2)" in capsys.readouterr().out
    assert main(["show", run, "--store", str(path), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    b = shown["points"][0]["uncertainty_budget"]
    assert set(b) >= {"components", "combined", "expanded", "k"} and b["k"] == 2.0
    with RunStore(path, create=False) as store:
        record = store.to_record(run)
    out = export_record(record, tmp_path / "scan.csv", "csv")
    back = read_tidy_csv(out)
    assert {"u_c", "U", "k"} <= set(back.table.columns)
    values, cov = readings_and_covariance(back)
    values0, cov0 = readings_and_covariance(record)
    np.testing.assert_array_equal(values, values0)
    np.testing.assert_allclose(cov, cov0, rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), back.table["std"], rtol=1e-12)
    off = cov[~np.eye(len(values), dtype=bool)]
    assert (off > 0).all()  # every pair shares at least the white standard's certificate


def test_a_store_without_budgets_reads_as_before(scanned, tmp_path):
    path, run = scanned
    with RunStore(path, create=False) as store:
        rec = store.to_record(run)
        cal_info = store.run(run)["calibration"]
    from bench.core.calibration import Calibration
    from bench.core.geometry import Geometry

    cal = Calibration.from_dict(cal_info)
    old = tmp_path / "old.sqlite"
    with RunStore(old) as store:  # points written as before the budgets: no budget argument
        rid = store.create_run(kind="scan", n_planned=1)
        store.add_point(rid, 0, Geometry(30, 0, 20, 180).as_dict(),
                        point_rows(cal.white, cal, Geometry(30, 0, 20, 180), None, None), t_start=0.0, t_end=1.0)
        store.set_status(rid, "completed", None)
        r = store.to_record(rid)
        assert [x["uncertainty_budget"] for x in store.reading_budgets(rid)] == [None] * 3
    assert "u_c" not in r.table.columns and "uncertainty_budget" not in r.table.columns
    values, cov = readings_and_covariance(r)
    np.testing.assert_allclose(cov, np.diag(r.table["std"].to_numpy() ** 2))
    assert len(rec.table) == 9


def test_uncertainty_method_mc_from_the_command_line(tmp_path, capsys):
    import tomli_w

    bench = tmp_path / "bench.toml"
    bench.write_bytes(tomli_w.dumps({**copy.deepcopy(VIRTUAL), "seed": 5}).encode())
    plan = tmp_path / "plan.toml"
    plan.write_bytes(tomli_w.dumps({**PLAN, "list": {"points": PLAN["list"]["points"][:1]}}).encode())
    store = tmp_path / "runs.sqlite"
    assert main(["scan", str(plan), "--bench", str(bench), "--store", str(store), "-q", "--json",
                 "--uncertainty-method", "mc"]) == 0
    run = json.loads(capsys.readouterr().out)["run_id"]
    with RunStore(store, create=False) as s:
        budgets = [r["uncertainty_budget"] for r in s.reading_budgets(run)]
    assert {b["method"] for b in budgets} == {"mc"}
    # nearly linear at these uncertainties: k close to 2 (20000 draws)
    assert all(abs(b["k"] - 2.0) < 0.1 for b in budgets)


def test_a_misspelt_uncertainty_key_is_one_line(tmp_path, capsys):
    import tomli_w

    bench = tmp_path / "bench.toml"
    bench.write_bytes(tomli_w.dumps({**copy.deepcopy(VIRTUAL), "uncertainty": {"nonlinarity": 0.01}}).encode())
    assert main(["plan", str(FIXTURES / "plans" / "in-plane.toml"), "--bench", str(bench)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nonlinarity" in err


@pytest.mark.slow
def test_virtual_and_emulated_bodies_give_budgets_of_the_same_components(tmp_path):
    """One description (the shipped emulated bench with every component declared) on both bodies."""
    from bench.core.parsing import read_toml

    desc = {**read_toml(FIXTURES / "benches" / "emulated.toml"), **DECLARED}
    names = {}
    for body in ("virtual", "emulated"):
        with RunStore(tmp_path / f"{body}.sqlite") as store, load_bench(copy.deepcopy(desc), seed=5, body=body) as b:
            run = run_scan(b, plan_from_dict(PLAN), store, seed=5).run_id
            names[body] = {tuple(c["name"] for c in r["uncertainty_budget"]["components"])
                           for r in store.reading_budgets(run)}
    assert names["virtual"] == names["emulated"] == {tuple(NAMES)}
