"""GUM budgets (bench/core/budget.py): a budget checked by hand from its components, the covariance
the shared white standard makes, chi-square with the full covariance against the diagonal (false
alarms and power), GUM-S1 Monte Carlo against linear propagation, and the budget of a scan on the
virtual body (stored, shown, exported, read back from an old store).

Statistical checks use fixed seeds; their stated false-alarm rates are exact binomial tails (see
each test). Family-wise for this module: 2e-3 (two checks at 1e-3).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats as sps

from bench.core.budget import (COMPONENT_KEYS, budget_covariance, calibration_budgets, linear_budget, mc_budget,
                               readings_and_covariance)
from bench.core.calibration import Calibration, WhiteStandard
from bench.core.geometry import Geometry
from bench.core.records import BSDFRecord
from bench.core.roles import Reading
from compare.stats import chi_square

WL = np.array([450.0, 550.0, 650.0])
GEOMETRY = Geometry(30.0, 0.0, 40.0, 180.0)


def reading(signal, std, dark=False, t=0.1, averages=4, timestamp=1.0):
    return Reading(WL, np.asarray(signal, float), np.zeros(3, bool), t, averages, timestamp=timestamp, dark=dark,
                   std=np.asarray(std, float))


@pytest.fixture
def calibration():
    white = reading([5000.0, 6000.0, 7000.0], [20.0, 25.0, 30.0], t=0.2)
    white_dark = reading([100.0, 100.0, 100.0], [3.0, 3.0, 3.0], dark=True, t=0.2)
    return Calibration(WhiteStandard(0.99, 0.005), white, white_dark)


def test_budget_combines_its_components_as_computed_by_hand(calibration):
    r = reading([1500.0, 1600.0, 1700.0], [10.0, 11.0, 12.0])
    d = reading([100.0, 101.0, 102.0], [3.0, 3.5, 4.0], dark=True, timestamp=2.0)
    desc = {"instrument": {"read_noise": 4.0, "lamp_drift": 0.001},
            "uncertainty": {"nonlinearity": 0.002, "aperture": 0.003}}
    budgets = calibration_budgets(calibration, r, GEOMETRY, d, desc, lit_index=5)
    cos_ratio = math.cos(math.radians(45.0)) / math.cos(math.radians(40.0))
    for i, b in enumerate(budgets):
        # the model by hand: f = (S - D) / t / W * R_w / pi * cos_w / cos_r, W = (S_w - D_w) / t_w
        S, D, t = r.signal[i], d.signal[i], r.integration_s
        W = (calibration.white.signal[i] - calibration.white_dark.signal[i]) / 0.2
        u_W = math.hypot(calibration.white.std[i], calibration.white_dark.std[i]) / 0.2
        f = (S - D) / t / W * 0.99 / math.pi * cos_ratio
        u_read = 4.0 / math.sqrt(4)
        hand = {  # name: (u, c)
            "counting noise": (math.sqrt(r.std[i] ** 2 - u_read**2), f / (S - D)),
            "read noise": (u_read, f / (S - D)),
            "dark reading": (d.std[i], -f / (S - D)),
            "white reference reading": (u_W, -f / W),
            "white standard certificate": (0.005, f / 0.99),
            "lamp drift": (0.001 * 5, f),
            "nonlinearity": (0.002, f),
            "detector solid angle": (0.003, f),
        }
        assert [c.name for c in b.components] == list(hand)
        for c in b.components:
            u, sens = hand[c.name]
            assert c.standard_uncertainty == pytest.approx(u, rel=1e-12)
            assert c.sensitivity == pytest.approx(sens, rel=1e-9)
            assert c.contribution == pytest.approx(abs(sens) * u, rel=1e-9)
        assert b.value == pytest.approx(f, rel=1e-12)
        assert b.combined == pytest.approx(math.sqrt(sum((s * u) ** 2 for u, s in hand.values())), rel=1e-9)
        assert b.expanded == pytest.approx(2.0 * b.combined) and b.k == 2.0
        assert set(b.as_dict()["components"][0]) >= set(COMPONENT_KEYS)
    # with none of the optional components declared, the budget is the calibration's own std
    plain = calibration_budgets(calibration, r, GEOMETRY, d, {}, lit_index=5)
    np.testing.assert_allclose([b.combined for b in plain], calibration.apply(r, GEOMETRY, d).std, rtol=1e-12)


def test_two_readings_sharing_the_white_standard_covary_by_its_term_alone(calibration):
    r = reading([1500.0, 1600.0, 1700.0], [10.0, 11.0, 12.0])
    b = calibration_budgets(calibration, r, GEOMETRY, None, {}, lit_index=1)
    c = [next(x.sensitivity for x in bb.components if x.name == "white standard certificate") for bb in b]
    table = BSDFRecord(_table(b), {})
    values, cov = readings_and_covariance(table)
    np.testing.assert_allclose(values, [bb.value for bb in b])
    # two wavelengths of one point share only the certificate: cov = u_white^2 c1 c2
    assert cov[0, 1] == pytest.approx(0.005**2 * c[0] * c[1], rel=1e-12)
    assert cov[1, 2] == pytest.approx(0.005**2 * c[1] * c[2], rel=1e-12)
    np.testing.assert_allclose(np.diag(cov), [bb.combined**2 for bb in b], rtol=1e-12)
    # the same wavelength at two points also shares the white reading: its term adds
    r2 = reading([900.0, 950.0, 1000.0], [8.0, 8.5, 9.0])
    b2 = calibration_budgets(calibration, r2, Geometry(30.0, 0.0, 60.0, 180.0), None, {}, lit_index=2)
    _, cov2 = readings_and_covariance(BSDFRecord(_table(b + b2), {}))
    term = {name: [next(x for x in bb.components if x.name == name) for bb in (b[0], b2[0])]
            for name in ("white standard certificate", "white reference reading")}
    expect = sum(x.sensitivity * y.sensitivity * x.standard_uncertainty**2 for x, y in term.values())
    assert cov2[0, 3] == pytest.approx(expect, rel=1e-12)
    # a record without budgets: diag(std^2)
    plain = BSDFRecord(_table(b).drop(columns=["uncertainty_budget"]), {})
    np.testing.assert_allclose(readings_and_covariance(plain)[1], np.diag([bb.combined**2 for bb in b]))
    # every row is kept, in order; a reading with no uncertainty says so (NaN), never a silent 0
    plain.table.loc[1, ["value", "std"]] = np.nan
    values, cov = readings_and_covariance(plain)
    assert np.isnan(values[1]) and np.isnan(cov[1, 1]) and cov[0, 0] == pytest.approx(b[0].combined ** 2)


def _table(budgets):
    import pandas as pd

    return pd.DataFrame({"value": [b.value for b in budgets], "std": [b.combined for b in budgets],
                         "uncertainty_budget": [json.dumps(b.as_dict()) for b in budgets]})


def test_chi_square_with_the_full_covariance_keeps_its_level_and_has_power_the_diagonal_lacks():
    """40 readings whose white-standard term (1 % of each value, shared) dominates their 0.3 %
    own noise. Null: 2000 records drawn from that covariance. The full chi-square rejects at
    alpha = 0.01 in Binomial(2000, 0.01) cases: outside [8, 35] with probability 1e-3 (exact
    tails). The diagonal chi-square, blind to the correlation, rejects far more often. Power: a
    1 % tilt across the record (half the points up, half down), which the shared term cannot
    explain, is rejected by the full chi-square and passed by the diagonal one."""
    n = 40
    value = np.linspace(0.1, 0.3, n)
    budgets = [{"components": [
        {"name": "white standard certificate", "type": "B", "standard_uncertainty": 0.01, "sensitivity": v,
         "contribution": 0.01 * v, "shared": "run"},
        {"name": "counting noise", "type": "A", "standard_uncertainty": 0.003 * v, "sensitivity": 1.0,
         "contribution": 0.003 * v}], "combined": math.hypot(0.01 * v, 0.003 * v), "expanded": 0.0, "k": 2.0}
        for v in value]
    cov = budget_covariance(budgets, np.full(n, np.nan))
    np.testing.assert_allclose(cov, 1e-4 * np.outer(value, value) + np.diag((0.003 * value) ** 2), rtol=1e-12)
    crit = sps.chi2.ppf(0.99, n)
    rng = np.random.default_rng(20261202)
    draws = rng.multivariate_normal(np.zeros(n), cov, size=2000)
    full = np.array([chi_square(d, cov) for d in draws])
    diag = np.sum(draws**2 / np.diag(cov), axis=1)
    lo, hi = sps.binom.ppf(5e-4, 2000, 0.01), sps.binom.ppf(1 - 5e-4, 2000, 0.01)
    assert lo <= int(np.sum(full > crit)) <= hi
    assert int(np.sum(diag > crit)) > 5 * hi
    tilt = 0.01 * value * np.where(np.arange(n) < n // 2, 1.0, -1.0)
    assert sps.chi2.sf(chi_square(tilt, cov), n) < 1e-6
    assert sps.chi2.sf(float(np.sum(tilt**2 / np.diag(cov))), n) > 0.5


def _inputs(u_white_rate):
    from bench.core.budget import Input

    return [Input("counting noise", "A", 1500.0, 0.0), Input("white reference reading", "A", 24500.0, u_white_rate),
            Input("white standard certificate", "B", 0.99, 0.005)]


def _model(x):
    from bench.core.budget import calibrated_value

    return calibrated_value(x, integration_s=0.1, cos_ratio=1.0, slopes={})


def test_monte_carlo_agrees_with_linear_propagation_on_a_linear_model_and_not_on_a_nonlinear_one():
    """20000 draws: the standard deviation's relative standard error is 1/sqrt(2 * 20000) = 0.5 %;
    agreement within 2.5 % (5 sigma), disagreement beyond 8 % (16 sigma)."""
    linear = _inputs(0.0)  # only R_w is uncertain: f is linear in it
    lb, mb = linear_budget(linear, _model), mc_budget(linear, _model, samples=20_000, seed=7)
    assert mb.method == "mc" and lb.method == "linear"
    assert mb.combined == pytest.approx(lb.combined, rel=0.025)
    assert mb.k == pytest.approx(2.0, rel=0.05)
    nonlinear = _inputs(0.3 * 24500.0)  # f ~ 1/W with W 30 % uncertain
    lb, mb = linear_budget(nonlinear, _model), mc_budget(nonlinear, _model, samples=20_000, seed=7)
    assert mb.combined > 1.08 * lb.combined
    assert mb.components == lb.components  # the table is the linear one; u_c, U, k from the draws
    again = mc_budget(nonlinear, _model, samples=20_000, seed=7)
    assert again.combined == mb.combined  # a fixed seed: the same numbers


def test_positioning_sensitivity_is_the_specimen_models_slope():
    """A Lambertian's reading changes with the detector angle only through the cosine the
    calibration divides by: -f tan(theta_r) per radian; with the source angle not at all. A
    glossy lobe also moves with theta_i (its central difference, against a finer one)."""
    from bench.builders.slopes import model_slopes

    g = Geometry(30.0, 0.0, 40.0, 180.0)
    f = 0.8 / math.pi
    (s,) = model_slopes({"specimen": {"spec": "lambert:albedo=0.8"}}, g, np.array([550.0]), np.array([f]))
    assert s["theta_r"] == pytest.approx(-f * math.tan(math.radians(40.0)) * math.pi / 180.0, rel=1e-5)
    assert s["theta_i"] == pytest.approx(0.0, abs=1e-12) and s["phi_r"] == pytest.approx(0.0, abs=1e-12)
    (glossy,) = model_slopes({"specimen": {"spec": "ggx:alpha=0.3"}}, Geometry(30.0, 0.0, 35.0, 180.0),
                             np.array([550.0]), np.array([1.0]))
    assert abs(glossy["theta_i"]) > 1e-3
    # no declared specimen: the calibration's own cosine (Lambertian) slope from the reading
    (fallback,) = model_slopes({}, g, np.array([550.0]), np.array([f]))
    assert fallback["theta_r"] == pytest.approx(s["theta_r"], rel=1e-5)


def test_the_fit_of_a_calibrated_scan_uses_the_budgets_full_covariance_and_skips_masked_readings(calibration):
    """bench fit's Gaussian likelihood divides by the budgets' covariance (the white standard's
    term once for the run, as compare does), not by diag(u^2); a masked reading (value NaN, e.g.
    saturated) is left out rather than refusing the record."""
    import pandas as pd

    from bench.identify.likelihood import record_covariance as fit_covariance

    r = reading([1500.0, 1600.0, 1700.0], [10.0, 11.0, 12.0])
    b = calibration_budgets(calibration, r, GEOMETRY, None, {}, lit_index=1)
    t = _table(b)
    geometry = {"theta_i": 30.0, "phi_i": 0.0, "theta_r": 40.0, "phi_r": 180.0}
    t = t.assign(wavelength_nm=WL, **geometry)
    masked = t.iloc[:1].assign(value=np.nan, std=np.nan, uncertainty_budget=None)
    record = BSDFRecord(pd.concat([masked, t], ignore_index=True), {})
    values, cov = fit_covariance(record)
    expect_values, expect_cov = readings_and_covariance(BSDFRecord(t, {}))
    np.testing.assert_array_equal(values, expect_values)
    np.testing.assert_allclose(cov, expect_cov, rtol=1e-12)
    assert cov[0, 1] > 0  # the shared white standard: not a diagonal matrix
