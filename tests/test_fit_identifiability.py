"""What a fit or a design cannot identify is said, not hidden behind ``converged``; outliers are
named; a parameter's alias is accepted and reported as written."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench.identify import fit_record
from bench.identify.identifiability import flat_profiles, identifiability, refuse_unidentifiable
from bench.core.errors import InputError
from tests.helpers.cli import run_main
from tests.test_fit_normalization import _textbook_record

ROOT = Path(__file__).resolve().parents[1]


def test_rank_condition_and_reasons_from_the_fisher_information():
    good = identifiability(np.array([[4.0, 0.0], [0.0, 1.0]]), ["a", "b"], [1.0, 1.0])
    assert good.rank == 2 and good.condition == pytest.approx(4.0) and not good.unidentified
    blind = identifiability(np.array([[4.0, 0.0], [0.0, 0.0]]), ["reflectance", "transmittance"], [1.0, 1.0])
    assert blind.rank == 1 and math.isinf(blind.condition)
    assert blind.unidentified == {"transmittance": "no reading sees transmission"}
    j = np.array([[1.0, 2.0], [2.0, 4.0]])  # two parameters the readings see only as a + 2 b
    both = identifiability(j.T @ j, ["a", "b"], [1.0, 1.0])
    assert set(both.unidentified) == {"a", "b"} and "confounded with b" in both.unidentified["a"]
    flat = flat_profiles(good, {"a": (0.0, 1.0), "b": (0.2, 0.3)}, {"a": (0.0, 1.0), "b": (0.0, 1.0)})
    assert list(flat.unidentified) == ["a"] and "whole search range" in flat.unidentified["a"]
    with pytest.raises(InputError, match="cannot identify transmittance at any bench time"):
        refuse_unidentifiable(np.diag([4.0, 0.0]), ["reflectance", "transmittance"], [1.0, 1.0], "b")


def test_a_fit_says_transmittance_is_not_identified_by_reflection_readings():
    record = _textbook_record([0.6 / math.pi, 0.4 / math.pi, 0.5 / math.pi], 0.1, 0.2)
    fit = fit_record(record, "lambert:albedo=?,transmittance=?")
    doc = fit.to_json()
    assert doc["converged"] is True
    assert doc["identifiability"]["unidentified"] == {"transmittance": "no reading sees transmission"}
    assert doc["identifiability"]["rank"] == 1
    assert list(doc["parameters"]) == ["albedo", "transmittance"]  # the alias as written
    hessian = fit_record(record, "lambert:albedo=?,transmittance=?", interval="hessian")
    lo, hi = hessian.parameters["reflectance"].ci  # the blind parameter does not blind the other's interval
    assert 0.0 < lo < hi < 1.0 and hessian.identifiability.unidentified == {"transmittance": "no reading sees transmission"}


def test_the_cli_names_what_is_not_identified_and_the_outlier(capsys, tmp_path):
    values = [0.5 / math.pi * (1 + 0.01 * k) for k in (0, 1, -1, 0, 1, -1, 0, 1)] + [-5.0]
    record = _textbook_record(values, 0.01, 0.005)
    path = tmp_path / "r.csv"
    record.table.assign(hemisphere="R").to_csv(path, index=False)
    code, out, err = run_main(capsys, "fit", path, "--model", "lambert:albedo=?,transmittance=?")
    assert "NOT identified: transmittance: no reading sees transmission" in out, out + err
    assert "outlier: reading 8" in out and "value -5" in out, out
    assert "1 reading(s) more than 5 standard uncertainties" in out, out  # its neighbours are not dragged in
    assert "albedo" in out and "reflectance" not in out.split("best-fit")[0]


def test_design_with_a_parameter_no_time_can_identify_exits_2_naming_why(capsys, tmp_path):
    code, out, err = run_main(capsys, "plan", "--design", "lambert:albedo=?,transmittance=?", "--bench",
                              ROOT / "fixtures" / "benches" / "emulated.toml", "--budget-seconds", "4",
                              "--out", tmp_path / "d.toml")
    assert code == 2 and "transmittance: no point of the candidate grid sees transmission" in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "d.toml").exists()


def test_prior_accepts_an_alias():
    from bench.identify.design_io import model_point
    from bench.identify.model_spec import parse_model_spec

    spec = parse_model_spec("lambert:albedo=?")
    assert model_point(spec, {"albedo": 0.7}).values["reflectance"] == 0.7
    assert model_point(spec, {"reflectance": 0.6}).values["reflectance"] == 0.6
    with pytest.raises(InputError, match="not a free parameter"):
        model_point(spec, {"transmittance": 0.1})
