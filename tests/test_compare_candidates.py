"""compare.report's computing half, called directly: compare_candidates ranks, judges and checks
the candidates and writes nothing; the summary it gives write_report is tested as values (the
files themselves in test_report.py)."""

from __future__ import annotations

import pytest

from compare.report import RecordComparison, compare_candidates, write_report
from compare.verdict import Criterion


@pytest.fixture(scope="module")
def spectra():
    from virtual.spectrophotometer import VirtualSpectrophotometer

    def meas(albedo, seed):
        return VirtualSpectrophotometer(f"lambert:albedo={albedo}", rays=20_000, seed=seed).measure("8/d", "400:700:50")

    return meas(0.5, 1), meas(0.5, 2), meas(0.6, 3)


def test_a_brighter_candidate_ranks_last_and_is_rejected(spectra, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    actual, same, brighter = spectra
    r = compare_candidates(actual, {"brighter": brighter, "same": same})
    assert isinstance(r, RecordComparison) and r.kind == "spectrum" and r.k == 2.0
    assert [x["name"] for x in r.ranking] == ["same", "brighter"]
    assert r.verdicts["brighter"]["verdict"] == "reject" and r.verdicts["same"]["verdict"] == "accept"
    assert r.warnings[0].startswith("brighter (rank 2) is rejected: ")
    assert r.checks == {} and r.errors == {} and set(r.group_tables) == {"brighter", "same"}
    assert list(tmp_path.iterdir()) == []  # nothing written
    s = r.summary()
    assert s["figures"] == [] and s["fits"] == {} and s["unmatched"] == {"brighter": 0, "same": 0}
    assert s["candidates"]["brighter"]["chi2_per_dof"] > s["candidates"]["same"]["chi2_per_dof"]
    assert s["verdicts"] is r.verdicts and s["nominal_fraction"] == pytest.approx(0.9545, abs=1e-4)


def test_the_criterion_wins_over_k_and_a_bad_candidate_is_listed(spectra):
    from virtual.goniophotometer import VirtualGoniophotometer

    actual, same, _ = spectra
    bsdf = VirtualGoniophotometer("lambert:albedo=0.5", collector="equal-psa:3x8", rays=20_000, seed=1,
                                  method="rays").measure_bsdf(30.0)
    r = compare_candidates(actual, {"same": same, "gonio": bsdf}, k=2.0, criterion=Criterion(k=3.0),
                           on_error="skip")
    assert r.k == 3.0 and r.summary()["k"] == 3.0 and r.summary()["criterion"]["k"] == 3.0
    assert list(r.comparisons) == ["same"] and list(r.errors) == ["gonio"]
    with pytest.raises(Exception, match="cannot compare a spectrum record with a bsdf record"):
        compare_candidates(actual, {"gonio": bsdf})


def test_bsdf_records_are_checked_and_the_report_says_what_was_computed(tmp_path):
    from virtual.goniophotometer import VirtualGoniophotometer

    def rec(seed):
        return VirtualGoniophotometer("lambert:albedo=0.5", collector="equal-psa:3x8", rays=50_000, seed=seed,
                                      method="rays").measure_bsdf(30.0)

    r = compare_candidates(rec(1), {"again": rec(2)})
    assert r.kind == "bsdf" and set(r.checks) == {"actual", "again"}
    assert set(r.checks["actual"]) == {"reciprocity", "energy_conservation", "isotropy"}
    assert r.verdicts["again"]["verdict"] == "accept"
    written = write_report(r, tmp_path, draw_figures=False)
    assert written["ranking"] == r.ranking and written["figures"] == []
    assert written["candidates"]["again"]["n_points"] == r.comparisons["again"].summary["n_points"] > 0
    assert (tmp_path / "summary.json").is_file()
    assert compare_candidates(rec(1), {"again": rec(2)}, checks=False).checks == {}
