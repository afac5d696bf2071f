"""Records carry their keys and the report decides.

* comparing a record with itself, or with a re-run under another seed, is judged consistent
  (verdict ``accept``) for scans, sweeps, spectra (CSV, spectro sweeps, spectral scans) and the
  imports of every export format;
* a twice-rougher model is rejected with a named failing group;
* the HTML report shows every incidence (its group table and small-multiple figures), checked
  in headless Chromium (verdict rows and figure ids of the rendered DOM).

False alarms: the verdict tests every group at alpha / n_groups with family-wise alpha = 0.01,
so a right model is rejected with probability <= 1 %; the seeds are fixed, so the outcome is
deterministic. Power: the twice-rougher model (and a 20 % albedo change) are rejected.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from bench.core.records import BSDFRecord
from bench.io import export_record, load_run, read_record
from bench.store import RunStore
from bench.sweep import run_sweep, sweep_from_dict
from compare.align import NoOverlapError, align
from compare.report import compare_records
from compare.verdict import Criterion
from tests.helpers.cli import run_bench, run_main

CHROMIUM = Path("/usr/bin/chromium")


def _verdict(actual, candidate, tmp_path, name="model", **kw):
    """The verdict only: no figures drawn (tests/test_report.py checks them)."""
    s = compare_records(actual, {name: candidate}, tmp_path, draw_figures=False, **kw)
    return s, s["verdicts"][name]


# --- sweeps: the 18.75 % bug ----------------------------------------------------------------


def _gonio_sweep(seed):
    return sweep_from_dict({"sweep": {
        "name": "keys", "seed": seed, "instrument": "gonio",
        "specimens": ["lambert:albedo=0.5", "lambert:albedo=0.8"], "incidences": [0, 30],
        "collectors": ["equal-psa:4x8"], "wavelengths": [450, 550], "rays": 20_000, "method": "rays"}})


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweeps")
    store = RunStore(d / "runs.sqlite")
    ids = {}
    for label, seed in (("a", 5), ("a2", 5), ("b", 7)):
        ids[label] = run_sweep(_gonio_sweep(seed), store).run_id
    spectro = {"sweep": {"name": "cc", "seed": 7, "instrument": "spectro",
                         "specimens": ["colorchecker:dark skin", "colorchecker:foliage"],
                         "geometries": ["8/d", "45/0"], "wavelengths": "400:700:20", "wavelengths_per_task": 0,
                         "rays": 20_000}}
    for label, seed in (("s", 7), ("s2", 7), ("t", 8)):
        spectro["sweep"]["seed"] = seed
        ids[label] = run_sweep(sweep_from_dict(spectro), store).run_id
    yield store, ids, d
    store.close()


def test_sweep_records_carry_specimen_and_collector_columns(sweeps):
    store, ids, _ = sweeps
    rec = load_run(store, ids["a"])
    assert {"specimen", "collector", "quantity", "theta_i", "phi_i", "wavelength_nm"} <= set(rec.table.columns)
    assert set(rec.table.specimen) == {"lambert:albedo=0.5", "lambert:albedo=0.8"}
    assert set(rec.table.collector) == {"equal-psa:4x8"} and set(rec.table.quantity) == {"BSDF"}


def test_identical_sweeps_compare_as_identical_and_reseeded_as_consistent(sweeps, tmp_path):
    store, ids, _ = sweeps
    a, a2, b = (load_run(store, ids[k]) for k in ("a", "a2", "b"))
    s, v = _verdict(a, a2, tmp_path / "same")
    c = s["candidates"]["model"]
    # before: 18.75 % apart, chi2 1.25e6 (rows of one specimen paired with the other's)
    assert c["mean_abs_discrepancy_pct"] == 0 and c["chi2"] == 0 and v["verdict"] == "accept"
    assert c["n_unmatched"] == 0 and c["n_points"] == len(a.table[a.table.hemisphere == "R"])
    s, v = _verdict(a, b, tmp_path / "reseed")
    assert v["verdict"] == "accept", v["reason"]
    groups = pd.DataFrame(v["groups"])
    assert set(groups.specimen) == {"lambert:albedo=0.5", "lambert:albedo=0.8"} and len(groups) == 8


def test_a_candidate_matching_no_key_is_an_error_naming_the_keys(sweeps):
    store, ids, _ = sweeps
    a = load_run(store, ids["a"])
    other = a.table.copy()
    other["specimen"] = "lambert:albedo=0.3"
    with pytest.raises(NoOverlapError, match=r"matches no key.*specimen=lambert:albedo=0\.5"):
        align(a, BSDFRecord(other, dict(a.meta)))
    # a keyless table cannot be told apart: an error, never a silent pairing
    keyless = a.table.drop(columns=["specimen"])
    with pytest.raises(NoOverlapError, match="no specimen column"):
        align(a, BSDFRecord(keyless, {}))
    # one specimen of two: the other's rows are unmatched, named
    half = BSDFRecord(a.table[a.table.specimen == "lambert:albedo=0.5"], dict(a.meta))
    al = align(a, half)
    um = al.unmatched[al.unmatched.side == "actual"]
    assert len(um) and set(um.specimen) == {"lambert:albedo=0.8"}
    assert any("specimen=lambert:albedo=0.8" in w for w in al.warnings)


# --- spectra -----------------------------------------------------------------------------


def test_spectro_sweeps_compare_as_spectra_with_ciede2000(sweeps, tmp_path):
    store, ids, _ = sweeps
    s_, s2, t = (load_run(store, ids[k]) for k in ("s", "s2", "t"))
    assert isinstance(s_, tuple) and len(s_) == 4
    s, v = _verdict(s_, s2, tmp_path / "same")
    assert s["kind"] == "spectrum" and s["candidates"]["model"]["delta_e2000_mean"] == 0 and v["verdict"] == "accept"
    s, v = _verdict(s_, t, tmp_path / "reseed")
    c = s["candidates"]["model"]
    assert v["verdict"] == "accept", v["reason"]
    assert len(c["delta_e2000"]) == 4 and all(v > 0 for v in c["delta_e2000"].values())  # one per spectrum
    # 8/d integrates the hemisphere (many rays): close; 45/0 counts rays in a small cone: noisier
    assert c["delta_e2000"]["colorchecker:foliage 8/d reflectance"] < 0.5
    assert {g["geometry"] for g in v["groups"]} == {"8/d", "45/0"}
    assert len(s["breakdown"]["model"]["by_wavelength"]) == 16  # per-wavelength statistics


def test_cli_compares_spectrum_csvs_and_spectro_sweeps(sweeps, tmp_path, capsys):
    """In this process (run_main): the command's own work, not five interpreter start-ups."""
    store, ids, d = sweeps
    for seed in (1, 2):
        code, _, err = run_main(capsys, "spectro", "--specimen", "colorchecker:dark skin", "--geometry", "8/d",
                                "--wavelengths", "400:700:20", "--rays", "20000", "--seed", str(seed), "--csv",
                                tmp_path / f"s{seed}.csv")
        assert code == 0, err
    s1, s2 = tmp_path / "s1.csv", tmp_path / "s2.csv"
    code, out, err = run_main(capsys, "compare", s1, s1, "--out", tmp_path / "self", "--json")
    assert code == 0, err
    js = json.loads(out)
    assert js["verdicts"]["s1"]["verdict"] == "accept" and js["candidates"]["s1"]["delta_e2000_mean"] == 0
    code, out, err = run_main(capsys, "compare", s1, s2, "--out", tmp_path / "re", "--no-figures")
    assert code == 0, err
    assert re.search(r"#1 s2: ACCEPT", out) and "delta_e2000_mean" in out
    code, out, err = run_main(capsys, "compare", ids["s"], ids["t"], "--store", d / "runs.sqlite", "--out",
                              tmp_path / "sw", "--json", "--no-figures")
    assert code == 0, err
    js = json.loads(out)
    assert js["kind"] == "spectrum" and list(js["verdicts"].values())[0]["verdict"] == "accept"


# --- scans -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scans(tmp_path_factory):
    from bench.config import load_bench
    from bench.core.parsing import read_toml
    from bench.plans import plan_from_dict
    from bench.runner import run_scan

    d = tmp_path_factory.mktemp("scans")
    root = Path(__file__).resolve().parent.parent
    plan = plan_from_dict({"name": "small", "kind": "in-plane", "integration_s": 0.02,
                           "in_plane": {"theta_i": [30, 60], "theta_r": {"start": -20, "stop": 80, "step": 10}}})
    spectral = plan_from_dict({"name": "cie", "kind": "spectral", "integration_s": 0.02,
                               "spectral": {"geometries": ["45/0", "0/45"]}})
    ids = {}
    with RunStore(d / "runs.sqlite") as store:
        for label, seed, p in (("a", 1, plan), ("b", 2, plan), ("sa", 1, spectral), ("sb", 2, spectral)):
            cfg = read_toml(root / "fixtures" / "benches" / "virtual.toml")
            cfg["specimen"] = {"spec": "lambert:albedo=0.6"}
            with load_bench(cfg, seed=seed) as bench:
                ids[label] = run_scan(bench, p, store, seed=seed).run_id
    return d / "runs.sqlite", ids


def test_scans_self_and_reseeded_are_consistent(scans, tmp_path):
    path, ids = scans
    with RunStore(path, create=False) as store:
        a, b = load_run(store, ids["a"]), load_run(store, ids["b"])
        sa, sb = load_run(store, ids["sa"]), load_run(store, ids["sb"])
    assert set(a.table.specimen) == {"lambert:albedo=0.6"}
    for cand, label in ((a, "self"), (b, "reseed")):
        s, v = _verdict(a, cand, tmp_path / label)
        assert v["verdict"] == "accept", (label, v["reason"])
        assert sorted({round(g["theta_i"]) for g in v["groups"]}) == [30, 60]  # a verdict per incidence
    # a spectral scan is read as spectra (reflectance factor per CIE geometry)
    assert isinstance(sa, tuple) and {x.geometry for x in sa} == {"45/0", "0/45"}
    for cand, label in ((sa, "sself"), (sb, "sreseed")):
        s, v = _verdict(sa, cand, tmp_path / label)
        assert s["kind"] == "spectrum" and v["verdict"] == "accept", (label, v["reason"])


# --- imports of every export format ----------------------------------------------------------


@pytest.fixture(scope="module")
def virtual_pair():
    from virtual.goniophotometer import VirtualGoniophotometer

    def rec(seed):
        g = VirtualGoniophotometer("lambert:albedo=0.6", collector="equal-psa:6x24", rays=100_000, seed=seed,
                                   wavelengths=[550.0], method="rays")
        return g.measure_bsdf(30.0)

    return rec(11), rec(12)


@pytest.mark.parametrize("fmt", ["csv", "parquet", "astm", "zemax"])
def test_imports_of_every_export_format_are_consistent(virtual_pair, fmt, tmp_path):
    a, b = virtual_pair
    fa = export_record(a, tmp_path / f"a.{fmt}", fmt, **({"wavelength_nm": 550.0} if fmt == "zemax" else {}))
    fb = export_record(b, tmp_path / f"b.{fmt}", fmt, **({"wavelength_nm": 550.0} if fmt == "zemax" else {}))
    ia, ib = read_record(fa), read_record(fb)
    assert {"specimen", "collector", "quantity"} <= set(ia.table.columns)
    for cand, label in ((ia, "self"), (ib, "reseed"), (b, "original")):
        s, v = _verdict(ia, cand, tmp_path / label, criterion=Criterion(instrument_uncertainty=0.0))
        assert v["verdict"] == "accept", (fmt, label, v["reason"])


# --- power: a twice-rougher model --------------------------------------------------------------


@pytest.fixture(scope="module")
def glossy_report(tmp_path_factory):
    from virtual.goniophotometer import VirtualGoniophotometer

    def rec(spec, seed):
        g = VirtualGoniophotometer(spec, collector="equal-psa:9x36", rays=400_000, seed=seed, wavelengths=[550.0],
                                   method="rays")
        return BSDFRecord(pd.concat([g.measure_bsdf(t, 0.0).table for t in (0.0, 20.0, 40.0, 60.0)],
                                    ignore_index=True), g.measure_bsdf(0.0).meta)

    actual = rec("plastic:alpha=0.3,eta=1.5,kd=0.5", 4)
    cands = {"same model": rec("plastic:alpha=0.3,eta=1.5,kd=0.5", 5),
             "twice rougher": rec("plastic:alpha=0.6,eta=1.5,kd=0.5", 3)}
    out = tmp_path_factory.mktemp("glossy")
    return out, compare_records(actual, cands, out)


@pytest.mark.slow  # the glossy report: 3 x 4 incidences x 4e5 rays and its figures (~30 CPU-s)
def test_twice_rougher_model_is_rejected_with_a_named_failing_group(glossy_report):
    out, s = glossy_report
    assert s["verdicts"]["same model"]["verdict"] == "accept", s["verdicts"]["same model"]["reason"]
    v = s["verdicts"]["twice rougher"]
    assert v["verdict"] == "reject" and v["failing_groups"]
    assert re.match(r"theta_i = \d+ deg, phi_i = 0 deg, 550 nm", v["failing_groups"][0])
    assert any(w.startswith("twice rougher (rank") and "rejected" in w for w in s["warnings"])
    assert s["criterion"]["alpha"] == 0.01 and "alpha = 0.01" in s["criterion"]["statement"]


@pytest.mark.slow  # the glossy report: 3 x 4 incidences x 4e5 rays and its figures (~30 CPU-s)
def test_html_report_shows_every_incidence(glossy_report):
    out, s = glossy_report
    html = (out / "report.html").read_text()
    for t in (0, 20, 40, 60):
        assert html.count(f"theta_i = {t} deg, phi_i = 0 deg, 550 nm") >= 2  # in both models' group tables
    for name in ("same-model", "twice-rougher"):
        assert f'id="fig-sigma-grid-{name}"' in html
    assert 'id="fig-value-grid"' in html and "one panel per incidence (4)" in html
    assert html.index('id="verdicts"') < html.index('id="ranking"')  # the decision comes first


@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed (CI: apt-get install -y chromium)")
@pytest.mark.slow  # the glossy report: 3 x 4 incidences x 4e5 rays and its figures (~30 CPU-s)
def test_rendered_report_has_verdict_rows_and_figure_ids(glossy_report, tmp_path):
    out, s = glossy_report
    cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
           "--disable-background-networking", f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom",
           (out / "report.html").resolve().as_uri()]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    dom = proc.stdout
    table = dom[dom.index('class="verdicts"'):]
    table = table[:table.index("</table>")]
    rows = re.findall(r"<tr><td>(.*?)</td><td>(.*?)</td><td>(.*?)</td>", table)
    assert ("same model", "1", "accept") in rows or ("same model", "2", "accept") in rows
    assert any(r[0] == "twice rougher" and r[2] == "reject" for r in rows)
    for fid in s["figures"]:
        assert re.search(rf'<img id="{re.escape(fid)}"[^>]*src="data:image/png;base64,', dom), fid


def test_criterion_from_a_config_file_and_flags(tmp_path, virtual_pair):
    a, b = virtual_pair
    export_record(a, tmp_path / "a.csv")
    export_record(b, tmp_path / "b.csv")
    cfg = tmp_path / "compare.toml"
    cfg.write_text("[criterion]\nalpha = 0.05\ntolerance = 0.03\n[compare]\nmetric = \"rmse\"\n")
    r = run_bench("compare", "a.csv", "b.csv", "--config", str(cfg), "--k", "3", "--json", "--out", "r",
                  "--no-figures", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    js = json.loads(r.stdout)
    assert js["criterion"]["alpha"] == 0.05 and js["criterion"]["tolerance"] == 0.03 and js["criterion"]["k"] == 3
    assert js["primary_metric"] == "rmse" and "alpha = 0.05" in js["criterion"]["statement"]
    cfg.write_text("[criterion]\nalfa = 0.05\n")
    r = run_bench("compare", "a.csv", "b.csv", "--config", str(cfg), cwd=tmp_path)
    assert r.returncode == 2 and "unknown criterion key(s) ['alfa']" in r.stderr
    r = run_bench("compare", "a.csv", "b.csv", "--alpha", "1.5", cwd=tmp_path)
    assert r.returncode == 2 and "argument --alpha" in r.stderr and "'1.5'" in r.stderr
