"""Lamp drift from repeated white readings (a plan's ``white = "repeated"``): the Type A estimate
of the drift per lit reading, the drift-corrected readings, their budgets and covariance, the
white reference file that keeps the repeats, and bad input.

The scans run on a virtual bench that simulates the lamp as ``signal *= 1 + a * m`` (``m``-th lit
reading, :mod:`bench.builders.instrument`) with a Lambertian specimen of known BRDF ``0.8 / pi``;
the white standard's certificate uncertainty is 0 (the virtual standard is exactly 0.99), so the
chi-square below tests the budget's Type A part. Cost: two 12-point scans, about 2 CPU-s.
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from scipy import stats

from bench.cli import main
from bench.config import load_bench
from bench.core.budget import readings_and_covariance
from bench.core.calibration import Calibration, WhiteStandard, estimate_lamp_drift
from bench.core.errors import CalibrationRefused, ConfigError
from bench.core.roles import Reading
from bench.io.white import WhiteReference, read_white_reference, write_white_reference
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore

N = 6  # white repeats
A = 0.003  # the simulated drift per lit reading
TRUTH = 0.8 / math.pi
POINTS = [[30, 0, t, 180] for t in range(5, 65, 5)]
PLAN = {"name": "drift", "kind": "list", "integration_s": 0.05, "averages": 4, "dark": "once", "white": "repeated",
        "white_repeats": N, "order": "as-given", "list": {"points": POINTS}}


def description(a: float) -> dict:
    inst = {"dark_counts": 100.0, "read_noise": 4.0, "shot_noise": True, "seed": 3}
    if a:
        inst["lamp_drift"] = a
    return {"name": "drift", "kind": "virtual", "specimen": {"spec": "lambert:albedo=0.8"},
            "white": {"reflectance_factor": 0.99, "uncertainty": 0.0}, "instrument": inst,
            "virtual": {"collector": "equal-psa:9x36", "rays": 10_000_000, "wavelengths": "450:650:100",
                        "gain": 1e8}}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """``{a: (store path, run id)}`` for a lamp that drifts (A) and one that does not (0)."""
    path = tmp_path_factory.mktemp("drift") / "runs.sqlite"
    out = {}
    with RunStore(path) as store:
        for a in (0.0, A):
            with load_bench(copy.deepcopy(description(a)), seed=5) as bench:
                out[a] = (path, run_scan(bench, plan_from_dict(PLAN), store, seed=5).run_id)
    return out


def _run(runs, a):
    path, run = runs[a]
    with RunStore(path, create=False) as store:
        info = store.run(run)
        return info, store.reading_budgets(run), store.to_record(run)


def _by_hand(info) -> tuple[float, float]:
    """delta and u(delta) from the stored repeats, by scipy.stats.linregress (not our code)."""
    cal = info["calibration"]
    dark = np.asarray(cal["white_dark"]["signal"], float)
    y = [np.sum(np.asarray(w["signal"], float) - dark) / w["integration_s"] for w in cal["white_repeats"]]
    fit = stats.linregress(np.arange(len(y)), y)
    return fit.slope / np.mean(y), fit.stderr / np.mean(y)


def _drift_component(budget):
    (c,) = [c for c in budget["components"] if c["name"] == "lamp drift"]
    return c


def test_the_estimated_slope_contains_the_simulated_one(runs):
    """The virtual lamp gives ``(1 + a m)``: relative to the repeats' centroid ``c = (N-1)/2`` the
    drift per lit reading is ``a / (1 + a c)``. Two-sided 99 % Student-t interval on N-2 degrees of
    freedom: false-alarm rate 1 % per run. Power: the steady lamp's interval excludes the
    drifting one's slope, and the drifting lamp's excludes 0."""
    t99 = stats.t.ppf(0.995, N - 2)
    est = {}
    for a in (0.0, A):
        info, _, _ = _run(runs, a)
        d = info["meta"]["calibration_steps"]["lamp_drift"]
        assert d["type"] == "A" and d["repeats"] == N and d["dof"] == N - 2 and d["centroid"] == (N - 1) / 2
        delta, se = _by_hand(info)
        assert d["per_lit_reading"] == pytest.approx(delta, rel=1e-9)
        assert d["standard_uncertainty"] == pytest.approx(se, rel=1e-9)
        est[a] = (delta, se)
    for a in (0.0, A):
        truth = a / (1 + a * (N - 1) / 2)
        assert abs(est[a][0] - truth) <= t99 * est[a][1]
    assert abs(est[0.0][0] - A / (1 + A * (N - 1) / 2)) > t99 * est[0.0][1]
    assert abs(est[A][0]) > t99 * est[A][1]


def test_corrected_readings_are_unbiased_where_uncorrected_ones_are_biased(runs):
    """Chi-square of the readings against the known BRDF with the budgets' full covariance, at
    the 99 % quantile (false-alarm rate 1 % per check). The uncorrected readings (the correction
    undone by hand) fail it on the drifting lamp and pass it on the steady one."""
    for a in (0.0, A):
        info, _, record = _run(runs, a)
        v, cov = readings_and_covariance(record)
        delta = info["meta"]["calibration_steps"]["lamp_drift"]["per_lit_reading"]
        lit = N + record.table["idx"].to_numpy()  # as-given order: point i is lit reading N + i
        uncorrected = v * (1 + delta * (lit - (N - 1) / 2))
        limit = stats.chi2.ppf(0.99, v.size)

        def chi2(x):
            r = x - TRUTH
            return float(r @ np.linalg.solve(cov, r))

        assert chi2(v) < limit, a
        if a:
            assert chi2(uncorrected) > limit  # a 1-4 % bias against 0.6 % per reading
        else:
            assert chi2(uncorrected) < limit


def test_the_budgets_lamp_drift_is_type_a_with_k_times_the_slopes_standard_error(runs):
    info, rows, _ = _run(runs, A)
    delta, se = _by_hand(info)
    assert len(rows) == len(POINTS) * 3
    for r in rows:
        b = r["uncertainty_budget"]
        c = _drift_component(b)  # one lamp drift: the Type A estimate replaces the declared Type B
        k = N + r["idx"] - (N - 1) / 2  # lit readings since the repeats' centroid
        assert c["type"] == "A" and c["shared"] == "run"
        assert c["standard_uncertainty"] == pytest.approx(k * se, rel=1e-9)
        # d f / d d_drift of f_raw / (1 + d_drift) at d_drift = delta k
        assert c["sensitivity"] == pytest.approx(-b["value"] / (1 + delta * k), rel=1e-9)
        assert b["value"] == pytest.approx(r["value"], rel=1e-12)
        assert b["combined"] == pytest.approx(math.sqrt(sum(x["contribution"] ** 2 for x in b["components"])),
                                              rel=1e-12)
        assert r["std"] == pytest.approx(b["combined"], rel=1e-12)


def test_the_covariance_shares_the_drift_term_across_the_run(runs):
    """Two readings at different points and wavelengths share only the drift estimate (the
    certificate's u is 0 here; darks and white readings are per wavelength)."""
    _, rows, record = _run(runs, A)
    _, cov = readings_and_covariance(record)
    i = 0
    j = next(n for n, r in enumerate(rows) if r["idx"] == 9 and r["wavelength_nm"] != rows[0]["wavelength_nm"])
    ci, cj = (_drift_component(rows[n]["uncertainty_budget"]) for n in (i, j))
    expected = ci["sensitivity"] * ci["standard_uncertainty"] * cj["sensitivity"] * cj["standard_uncertainty"]
    assert expected > 0 and cov[i, j] == pytest.approx(expected, rel=1e-9)
    assert cov[i, i] == pytest.approx(rows[i]["std"] ** 2, rel=1e-9)


def test_bench_show_json_shows_the_estimate_and_the_type_a_component(runs, capsys):
    path, run = runs[A]
    info, _, _ = _run(runs, A)
    delta, se = _by_hand(info)
    assert main(["show", run, "--store", str(path)]) == 0
    assert f"lamp drift: {delta:.3g} +- {se:.2g} per lit reading (Type A, {N} white readings, {N - 2} dof)" \
        in capsys.readouterr().out
    assert main(["show", run, "--store", str(path), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["calibration_steps"]["white"] == "repeated" and shown["calibration_steps"]["white_repeats"] == N
    assert shown["calibration_steps"]["lamp_drift"]["type"] == "A"
    assert {_drift_component(p["uncertainty_budget"])["type"] for p in shown["points"]} == {"A"}


def _reading(signal, std=None):
    s = np.asarray(signal, float)
    return Reading(wavelengths=np.array([450.0, 550.0, 650.0]), signal=s, saturated=np.zeros(3, bool),
                   integration_s=0.1, averages=1, timestamp=1_764_504_000.0,
                   std=None if std is None else np.asarray(std, float))


def test_the_estimate_is_least_squares_on_the_band_sum_and_a_once_calibration_is_unchanged():
    rng = np.random.default_rng(1)
    base = np.array([1000.0, 2000.0, 3000.0])
    reps = [_reading(base * (1 + 0.01 * j) + rng.normal(0, 5, 3), [5.0] * 3) for j in range(5)]
    dark = _reading([10.0, 10.0, 10.0], [1.0] * 3)
    d = estimate_lamp_drift(reps, dark)
    y = [np.sum(r.signal - dark.signal) / 0.1 for r in reps]
    fit = stats.linregress(np.arange(5), y)
    assert d.per_lit_reading == pytest.approx(fit.slope / np.mean(y)) and d.standard_uncertainty == pytest.approx(
        fit.stderr / np.mean(y))
    cal = Calibration.from_repeats(WhiteStandard(), reps, dark)
    np.testing.assert_allclose(cal.white.signal, np.mean([r.signal for r in reps], axis=0))
    g = WhiteStandard().geometry
    # the mean white read at its centroid calibrates to the standard's own BRDF, drift or not
    assert np.allclose(cal.apply(cal.white, g, dark, lit_index=2).brdf, 0.99 / math.pi)
    assert np.allclose(cal.apply(reps[4], g, dark, lit_index=4).brdf, 0.99 / math.pi, rtol=0.01)
    once = Calibration(WhiteStandard(), reps[0], dark)
    assert once.lamp_drift is None and once.n_whites == 1
    np.testing.assert_array_equal(once.apply(reps[3], g, dark, lit_index=3).brdf, once.apply(reps[3], g, dark).brdf)
    back = Calibration.from_dict(json.loads(json.dumps(cal.as_dict())))
    assert back.lamp_drift == cal.lamp_drift and "white_repeats" not in once.as_dict()


@pytest.mark.parametrize("value", [1, 0, 2, 2.5, "five", True])
def test_bad_white_repeats_name_the_key(value, tmp_path, capsys):
    with pytest.raises(ConfigError, match="white_repeats"):
        plan_from_dict({**PLAN, "white_repeats": value})
    import tomli_w

    plan = tmp_path / "plan.toml"
    plan.write_bytes(tomli_w.dumps({**PLAN, "white_repeats": value}).encode())
    bench = tmp_path / "bench.toml"
    bench.write_bytes(tomli_w.dumps(description(A)).encode())
    assert main(["plan", str(plan), "--bench", str(bench)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "white_repeats" in err


def test_white_repeats_without_repeated_whites_is_refused():
    with pytest.raises(ConfigError, match="white_repeats: needs white = \"repeated\""):
        plan_from_dict({**PLAN, "white": "once"})
    assert plan_from_dict({k: v for k, v in PLAN.items() if k != "white_repeats"}).white_repeats == 5


def test_the_estimate_counts_every_white_reading():
    from bench.plans import MotionProfile, estimate

    once = plan_from_dict({k: v for k, v in PLAN.items() if k != "white_repeats"} | {"white": "once"})
    rep = plan_from_dict(PLAN)
    per = 0.05 * 4 + 0.01 + MotionProfile({}, {}).overhead_s  # one reading; the standard is mounted once
    e1, e2 = (estimate(p, MotionProfile({}, {}), reading_overhead_s=0.01) for p in (once, rep))
    assert e2["references_s"] - e1["references_s"] == pytest.approx((N - 1) * per)


def test_white_reference_file_keeps_the_repeats_and_runs_must_match_it(tmp_path, capsys):
    import tomli_w

    bench = tmp_path / "bench.toml"
    bench.write_bytes(tomli_w.dumps(description(A)).encode())
    out = tmp_path / "white.csv"
    assert main(["white", "--bench", str(bench), "--out", str(out), "--repeats", str(N), "--integration-s", "0.05",
                 "--averages", "4", "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["repeats"] == N and shown["lamp_drift"]["type"] == "A"
    ref = read_white_reference(out)
    assert len(ref.repeats) == N
    cal = ref.calibration(WhiteStandard(0.99, 0.0))
    assert cal.lamp_drift.per_lit_reading == pytest.approx(shown["lamp_drift"]["per_lit_reading"], rel=1e-12)
    # a file of one white (version 1) reads as before, with no repeats
    one = write_white_reference(tmp_path / "one.csv", WhiteReference(ref.white, ref.dark, ref.date, ""))
    assert read_white_reference(one).repeats == () and one.read_text().startswith("# goniobench-white 1\n")
    # a run whose plan asks another number of whites than the file holds is refused before motion
    from bench.preflight import check_calibration_steps

    with load_bench({**description(A), "white": {"reflectance_factor": 0.99, "uncertainty": 0.0,
                                                 "reference_file": str(out)}}) as b:
        check_calibration_steps(b, plan_from_dict(PLAN), ref)
        for other in ({**PLAN, "white_repeats": N + 1}, {k: v for k, v in PLAN.items() if k != "white_repeats"}
                      | {"white": "once"}):
            with pytest.raises(CalibrationRefused, match=f"holds {N} white reading"):
                check_calibration_steps(b, plan_from_dict(other), ref)
    assert main(["white", "--bench", str(bench), "--out", str(out), "--repeats", "2", "--force"]) == 2
    assert "--repeats" in capsys.readouterr().err
    from bench.cli.white import MAX_WHITE_REPEATS as cli_max
    from bench.core.schemas import MAX_WHITE_REPEATS

    assert cli_max == MAX_WHITE_REPEATS  # the CLI's copy (it starts without pydantic)


def test_a_real_bench_without_an_operator_is_refused_before_motion_naming_the_repeats():
    """The real body needs the operator to mount the standard (once, for every repeat): with no
    terminal and no stored reading the plan is refused, and the refusal says how to take the file."""
    from bench.preflight import check_calibration_steps

    with load_bench(copy.deepcopy(description(A))) as b:
        b.white_needs_operator = True  # what the real builder sets
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr("sys.stdin.isatty", lambda: False)
            with pytest.raises(CalibrationRefused, match=f"--repeats {N}`"):
                check_calibration_steps(b, plan_from_dict(PLAN), None)


@pytest.mark.slow
def test_the_drift_interval_covers_at_its_level_over_seeds():
    """Coverage of the Type A estimate: 200 instrument seeds of the drifting lamp (calibration
    only, no scan; about 5 CPU-s). The 95 % Student-t interval on N-2 dof misses in Binomial(200,
    0.05) runs: mean 10; more than 20 has probability 0.0016 (the false-alarm rate). Power: the
    same intervals around the steady lamp's slope (0) miss in nearly every run."""
    from bench.runner import measure_calibration

    plan = plan_from_dict(PLAN)  # with its dark: the described detector reads a dark level (100 counts)
    t95 = stats.t.ppf(0.975, N - 2)
    truth = A / (1 + A * (N - 1) / 2)
    miss = miss0 = 0
    for seed in range(200):
        d = description(A)
        d["instrument"]["seed"] = seed
        with load_bench(d, seed=5) as b:
            est = measure_calibration(b, plan).lamp_drift
        miss += abs(est.per_lit_reading - truth) > t95 * est.standard_uncertainty
        miss0 += abs(est.per_lit_reading) > t95 * est.standard_uncertainty
    assert miss <= 20 and stats.binom.sf(20, 200, 0.05) < 0.002
    assert miss0 >= 190


@pytest.mark.slow
def test_virtual_and_emulated_bodies_take_the_repeated_whites_alike(tmp_path):
    """The shipped emulated description with a declared drift on both bodies (emulators start:
    about 10 s): each takes N white readings after one mounting and gives budgets of the same
    components, the lamp drift Type A. (The emulators make their own noise and do not simulate
    the lamp's drift: their estimate is a steady lamp's.)"""
    from pathlib import Path

    from bench.core.parsing import read_toml

    fixtures = Path(__file__).resolve().parents[1] / "fixtures"
    desc = {**read_toml(fixtures / "benches" / "emulated.toml"), "instrument": {"lamp_drift": A}}
    plan = plan_from_dict({**PLAN, "integration_s": 0.02, "averages": 2,
                           "list": {"points": [[30, 0, 20, 180], [30, 0, 40, 180]]}})
    names, repeats = {}, {}
    for body in ("virtual", "emulated"):
        with RunStore(tmp_path / f"{body}.sqlite") as store, load_bench(copy.deepcopy(desc), seed=5, body=body) as b:
            run = run_scan(b, plan, store, seed=5).run_id
            info = store.run(run)
            repeats[body] = len(info["calibration"]["white_repeats"])
            names[body] = {tuple((c["name"], c["type"]) for c in r["uncertainty_budget"]["components"])
                           for r in store.reading_budgets(run) if r["uncertainty_budget"]}
    assert repeats == {"virtual": N, "emulated": N}
    assert names["virtual"] == names["emulated"] and len(names["virtual"]) == 1
    assert ("lamp drift", "A") in next(iter(names["virtual"]))


@pytest.mark.hil
@pytest.mark.slow
def test_the_real_body_over_the_emulators_takes_the_repeats_after_one_mounting(tmp_path, capsys):
    """The real drivers on the emulators (a ``kind = "real"`` bench, about 10 s): `bench white
    --yes --repeats N` stores N readings of the once-mounted standard; a repeated-white plan then
    runs from the file with a Type A lamp drift in every budget, and its values hold the emulated
    Lambertian's 0.8/pi: |z| below the two-sided Bonferroni bound of a family-wise false-alarm
    rate of 1e-3 over the run's values. A plan asking another number of whites is refused."""
    import tomli_w
    from scipy.stats import norm

    from bench.builders.emulated import DEFAULT_EMULATED_CONFIG, Emulators

    emu = Emulators(DEFAULT_EMULATED_CONFIG)
    try:
        config = emu.real_bench_config()
        lab = tmp_path / "lab.toml"
        lab.write_bytes(tomli_w.dumps(config).encode())
        white = tmp_path / "white.csv"
        emu.mount_white(True)  # what the operator confirms with --yes
        try:
            assert main(["white", "--bench", str(lab), "--out", str(white), "--yes", "--integration-s", "0.02",
                         "--averages", "2", "--repeats", str(N)]) == 0
        finally:
            emu.mount_white(False)
        assert len(read_white_reference(white).repeats) == N
        lab.write_bytes(tomli_w.dumps({**config, "white": {**config["white"], "reference_file": str(white)}}).encode())
        plan = tmp_path / "plan.toml"
        table = {**PLAN, "integration_s": 0.02, "averages": 2, "list": {"points": [[30, 0, t, 180] for t in (10, 30, 50)]}}
        plan.write_bytes(tomli_w.dumps(table).encode())
        store = tmp_path / "runs.sqlite"
        capsys.readouterr()
        assert main(["scan", str(plan), "--bench", str(lab), "--store", str(store), "--quiet", "--json"]) == 0
        run = json.loads(capsys.readouterr().out)["run_id"]
        with RunStore(store, create=False) as s:
            rows = s.reading_budgets(run)
            steps = s.run(run)["meta"]["calibration_steps"]
        assert steps["white_source"] == "file" and steps["lamp_drift"]["repeats"] == N
        assert {_drift_component(r["uncertainty_budget"])["type"] for r in rows} == {"A"}
        z = np.array([(r["value"] - TRUTH) / r["std"] for r in rows])
        assert np.max(np.abs(z)) < norm.isf(1e-3 / 2 / z.size)
        plan.write_bytes(tomli_w.dumps({**table, "white_repeats": N - 1}).encode())
        assert main(["scan", str(plan), "--bench", str(lab), "--store", str(store), "--quiet"]) == 2
        assert f"holds {N} white reading(s)" in capsys.readouterr().err
    finally:
        emu.close()


def test_a_repeated_white_file_round_trips_exactly_and_bad_ones_are_one_line(tmp_path):
    from bench.core.errors import InputError

    reps = [_reading([1000.0 + j, 2000.5 - j, 3000.25], [1.5, 2.0, 2.5]) for j in range(4)]
    cal = Calibration.from_repeats(WhiteStandard(), reps, _reading([10.0, 11.0, 12.0], [0.1, 0.2, 0.3]))
    path = write_white_reference(tmp_path / "w.csv", WhiteReference.from_calibration(cal, bench="lab"))
    back = read_white_reference(path)
    assert len(back.repeats) == 4 and back.provenance()["white_repeats"] == 4
    for a, b in zip(back.repeats, reps):
        assert np.array_equal(a.signal, b.signal) and np.array_equal(a.std, b.std)
    assert back.calibration(WhiteStandard()).lamp_drift == cal.lamp_drift
    good = path.read_text()
    for why, text in {"at least 3 repeated": good.replace('"repeats": [{', '"repeats": [', 1).replace(
                          '"repeats": [', '"repeats": [{"integration_s": 0.1}], "x": [{', 1),
                      "column header": good.replace(",signal_4,std_4", ""),
                      "signal_2 must be finite": good.replace(",1001.0,1.5,", ",-1.0,1.5,", 1)}.items():
        (tmp_path / "bad.csv").write_text(text)
        with pytest.raises(InputError, match=why):
            read_white_reference(tmp_path / "bad.csv")
