"""Bounded work: ``bench fit --max-seconds`` and ``bench plan --design --max-seconds`` stop with
the best point (design) reached so far and the reason, exit 1.

Time here is a fake clock that advances one second at every reading (so a limit of S seconds
allows about S evaluations): no test depends on the speed of the host. Power: the same work
without the limit (or with a generous one) finishes, converged, exit 0.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.identify import design as design_module
from bench.identify import fit as fit_module
from bench.identify import fit_record
from bench.io import read_record
from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parents[1]
MODEL = "plastic:alpha=?,kd=?"


class Ticking:
    """``monotonic()`` that advances ``step`` seconds at every call."""

    def __init__(self, step: float = 1.0) -> None:
        self.now, self.step = 1000.0, step

    def __call__(self) -> float:
        self.now += self.step
        return self.now


@pytest.fixture(scope="module")
def record_file(tmp_path_factory):
    """A small virtual gonio record of a Lambertian 0.6 (the fit tests' own)."""
    from bench.cli import main

    path = tmp_path_factory.mktemp("bounds") / "lambert.json"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["gonio", "--specimen", "lambert:reflectance=0.6", "--collector", "equal-psa:3x8", "--rays",
                     "100000", "--seed", "3", "--json"]) == 0
    path.write_text(out.getvalue())
    return path


def test_a_fit_past_its_time_limit_returns_its_best_point_not_converged(record_file, monkeypatch):
    record = read_record(record_file)
    free = fit_record(record, "lambert:reflectance=?", interval="hessian")
    assert free.converged and free.n_evaluations > 4  # unbounded, it takes more than the limit allows
    monkeypatch.setattr(fit_module, "time", SimpleNamespace(monotonic=Ticking()))
    cut = fit_record(record, "lambert:reflectance=?", interval="hessian", max_seconds=3)
    assert not cut.converged and "time limit (3 s)" in cut.message
    assert cut.n_evaluations <= 4 < free.n_evaluations
    p = cut.parameters["reflectance"]
    assert 0 <= p.value <= 1 and all(math.isnan(c) for c in p.ci)
    # the best point of those evaluated: no worse than the declared default the search starts from
    start = fit_record(record, "lambert:reflectance=?", interval="hessian", starts=0, max_seconds=1e-9)
    assert start.n_evaluations == 1 and cut.chi2 <= start.chi2
    assert cut.chi2 >= free.chi2 - 1e-9 * max(1.0, free.chi2)  # and not better than the optimum


def test_bench_fit_max_seconds_exits_1_with_the_best_point_and_the_reason(record_file, capsys, monkeypatch):
    code, out, err = run_main(capsys, "fit", record_file, "--model", "lambert:reflectance=?", "--json")
    assert code == 0 and json.loads(out)["converged"], err
    monkeypatch.setattr(fit_module, "time", SimpleNamespace(monotonic=Ticking()))
    code, out, err = run_main(capsys, "fit", record_file, "--model", "lambert:reflectance=?", "--json",
                              "--max-seconds", "3")
    doc = json.loads(out)  # valid JSON: the missing intervals are null, not NaN
    assert code == 1 and doc["converged"] is False and doc["parameters"]["reflectance"]["ci"] == [None, None]
    assert "time limit (3 s)" in err and "best point" in err
    code, _, err = run_main(capsys, "fit", record_file, "--model", "lambert:reflectance=?", "--max-seconds", "0")
    assert code == 2 and "--max-seconds" in err


@pytest.fixture()
def bench_file(tmp_path):
    text = (ROOT / "fixtures" / "benches" / "emulated.toml").read_text()
    p = tmp_path / "plastic.toml"
    p.write_text(text.replace("lambert:albedo=0.8", "plastic:alpha=0.15,kd=0.5"))
    return p


def _design(capsys, bench_file: Path, out: Path, *extra: str) -> tuple[int, dict, str]:
    code, text, err = run_main(capsys, "plan", "--design", MODEL, "--prior", "alpha=0.15,kd=0.5", "--bench",
                               bench_file, "--body", "virtual", "--budget-seconds", "3", "--out", out, "--step", "10",
                               "--integration-s", "0.01,0.02", "--json", *extra)
    return code, (json.loads(text) if text.strip() else {}), err


@pytest.mark.slow  # two designs on the virtual body (~20 s)
def test_plan_design_past_its_time_limit_writes_the_best_design_so_far_and_exits_1(bench_file, tmp_path, capsys,
                                                                                  monkeypatch):
    code, whole, err = _design(capsys, bench_file, tmp_path / "whole.toml")
    assert code == 0 and whole["stopped"] is None, err
    monkeypatch.setattr(design_module, "monotonic", Ticking())
    out = tmp_path / "cut.toml"
    code, cut, err = _design(capsys, bench_file, out, "--max-seconds", "2")
    assert code == 1 and cut["stopped"] and "time limit of 2 s" in cut["stopped"]
    assert "stopped" in err and str(out) in err and len(err.strip().splitlines()) == 1
    assert out.exists() and cut["points"] >= 2 and cut["seconds"] <= 3  # a design, within the bench budget
    from bench.plans import load_plan

    assert len(load_plan(out).points) == cut["points"]  # the file written is that design, whole


def test_max_seconds_without_design_is_refused(bench_file, capsys):
    code, _, err = run_main(capsys, "plan", ROOT / "fixtures" / "plans" / "in-plane.toml", "--bench", bench_file,
                            "--max-seconds", "5")
    assert code == 2 and "--max-seconds applies to --design MODEL only" in err

