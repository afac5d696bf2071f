"""Honest goodness of fit: the p-value accounts for estimated Type A variances.

Fast: synthetic linear records whose independent variances are estimated with 8 degrees of
freedom; the statistic is computed here by scipy (not the project's fitter) and its p-value by
:func:`bench.identify.gof.calibrated_p_value`. Slow: 60 emulated in-plane records of a
Lambertian 0.8 fitted by ``bench fit``'s code, and the same records with an uncorrected detector
non-linearity (a wrong model) for power.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.stats import binom, chi2

from bench.identify import fit_record
from bench.identify.gof import ReadingNoise, calibrated_p_value, interval_inflation, type_a_dof

N, NU, RECORDS = 40, 8, 300
#: central band of Binomial(RECORDS, level) with a two-sided false-alarm rate of 0.1 %
BAND = {a: (int(binom.ppf(0.0005, RECORDS, a)), int(binom.isf(0.0005, RECORDS, a))) for a in (0.05, 0.01)}


def _synthetic(rng: np.random.Generator, tilt: float) -> tuple[float, float, np.ndarray, np.ndarray, ReadingNoise]:
    """One record ``y = m g (1 + 0.01 z) + e`` (m = 2, one shared 1 % scale z, e independent with
    standard deviation 0.01 estimated with NU dof), plus ``tilt`` x a slope the model lacks.
    Returns (statistic by scipy, chi-square p, jac, scale loadings, noise)."""
    x = np.linspace(0.0, 1.0, N)
    g = 1.0 + 0.5 * np.cos(3.0 * x)
    sigma = np.full(N, 0.01)
    y = 2.0 * g * (1.0 + 0.01 * rng.standard_normal()) + sigma * rng.standard_normal(N) + tilt * (x - 0.5)
    s2 = sigma**2 * rng.chisquare(NU, N) / NU

    def res(p):
        m, z = p
        return np.concatenate([(y - m * g * (1.0 + 0.01 * z)) / np.sqrt(s2), [z]])

    fit = least_squares(res, [2.0, 0.0], xtol=1e-14, ftol=1e-14)
    stat = float(np.sum(fit.fun**2))
    m = fit.x[0]
    noise = ReadingNoise(s2, s2, np.zeros((N, 0)), np.full(N, float(NU)))
    return stat, float(chi2.sf(stat, N - 1)), g[:, None], (0.01 * m * g)[:, None], noise


def test_the_bootstrap_p_value_keeps_its_level_where_the_chi_square_law_does_not():
    """300 correct records with 8-dof variances: the calibrated p < 0.05 and p < 0.01 counts lie
    in Binomial(300, level)'s central band (false alarm 0.1 % each); the chi-square law's do not
    (it reads the estimated variances as known). Power: a slope of 0.05 over the record (2.5 times the
    noise at its ends), which the model lacks, is rejected at 0.05 in at least 30 of 40 records."""
    rng = np.random.default_rng(4301)
    calibrated, naive = [], []
    for _ in range(RECORDS):
        stat, p_naive, jac, scales, noise = _synthetic(rng, 0.0)
        calibrated.append(calibrated_p_value(stat, jac, scales, noise, draws=400))
        naive.append(p_naive)
    calibrated, naive = np.array(calibrated), np.array(naive)
    for a, (lo, hi) in BAND.items():
        assert lo <= np.count_nonzero(calibrated < a) <= hi, (a, np.count_nonzero(calibrated < a), (lo, hi))
        assert np.count_nonzero(naive < a) > hi, (a, np.count_nonzero(naive < a))
    rejected = 0
    for _ in range(40):
        stat, _p, jac, scales, noise = _synthetic(rng, 0.05)
        rejected += calibrated_p_value(stat, jac, scales, noise, draws=400) < 0.05
    assert rejected >= 30, rejected


def _wls(rng: np.random.Generator, nu: float) -> tuple[float, float, np.ndarray, ReadingNoise]:
    """One record ``y = 2 g + e`` (independent e, standard deviation 0.01 + 0.01 x, its variance
    estimated with ``nu`` dof), fitted by scipy weighting with the estimated variances.
    Returns (estimate, its reported standard error, jac, noise)."""
    x = np.linspace(0.0, 1.0, N)
    g = 1.0 + 0.5 * np.cos(3.0 * x)
    sigma = 0.01 * (1.0 + x)
    y = 2.0 * g + sigma * rng.standard_normal(N)
    s2 = sigma**2 * rng.chisquare(nu, N) / nu
    fit = least_squares(lambda p: (y - p[0] * g) / np.sqrt(s2), [1.0])
    se = float(np.sqrt(np.linalg.inv(fit.jac.T @ fit.jac)[0, 0]))
    return float(fit.x[0]), se, g[:, None], ReadingNoise(s2, s2, np.zeros((N, 0)), np.full(N, float(nu)))


def test_intervals_widened_for_estimated_variances_cover_at_their_level():
    """300 records weighted by 8-dof variance estimates: the reported standard error is too small
    (the estimate's spread is sqrt(8 / 4) = 1.41 of it), its 95 % interval covers the truth in
    about 85 %; widened by :func:`interval_inflation` it covers inside Binomial(300, 0.95)'s
    central band (two-sided false alarm 0.1 %). Power: the unwidened intervals fall below it."""
    rng = np.random.default_rng(4302)
    lo, hi = int(binom.ppf(0.0005, RECORDS, 0.95)), int(binom.isf(0.0005, RECORDS, 0.95))
    covered = widened = 0
    for _ in range(RECORDS):
        m, se, jac, noise = _wls(rng, NU)
        f = interval_inflation(jac, np.zeros((N, 0)), noise, draws=400)
        assert f is not None and f.shape == (1,) and f[0] >= 1.0
        covered += abs(m - 2.0) <= 1.959964 * se
        widened += abs(m - 2.0) <= 1.959964 * se * f[0]
    assert lo <= widened <= hi, (widened, (lo, hi))
    assert covered < lo, (covered, (lo, hi))


def test_interval_inflation_is_the_textbook_factor_for_type_a_noise_alone():
    """Type A noise alone with nu dof: the weighted estimate's spread is sqrt(nu / (nu - 4)) of its
    reported error for many readings (1.08 at 27 dof, the shipped emulated bench; 1.035 at 60);
    within 4 % (the bootstrap's 2000 draws scatter by about 1.6 %; measured 1.100 and 1.044 on 40
    readings). The large-readings formula is not asserted at few dof (8: 1.41, measured 1.34)."""
    rng = np.random.default_rng(4303)
    for nu in (27.0, 60.0):
        _m, _se, jac, noise = _wls(rng, nu)
        f = interval_inflation(jac, np.zeros((N, 0)), noise)
        assert f is not None
        assert f[0] == pytest.approx(math.sqrt(nu / (nu - 4.0)), rel=0.04), (nu, f)


def test_known_variances_keep_the_chi_square_law():
    """A virtual body's binomial noise or a single scan: every dof infinite, no bootstrap (None)."""
    noise = ReadingNoise(np.ones(5), np.ones(5), np.zeros((5, 0)), np.full(5, math.inf))
    assert calibrated_p_value(3.0, np.ones((5, 1)), np.zeros((5, 0)), noise) is None
    assert interval_inflation(np.ones((5, 1)), np.zeros((5, 0)), noise) is None  # the reported errors hold
    assert np.all(np.isinf(type_a_dof({"bench_kind": "virtual", "plan": {"averages": 4}}, [450.0])))
    assert np.all(np.isinf(type_a_dof({"bench_kind": "emulated", "plan": {"averages": 1}}, [450.0])))
    meta = {"bench_kind": "emulated", "plan": {"averages": 3},
            "bench_description": {"spectrometer": {"extra": {"bands_nm": [450, 550], "pixels_per_band": [27, 28]}}}}
    assert list(type_a_dof(meta, [450.0, 550.0, 452.0])) == [54.0, 56.0, 54.0]


def _nonlinear(record, beta: float):
    """``record`` with an uncorrected detector non-linearity: each reading times
    ``1 + beta (signal / median signal - 1)`` (a wrong model of the detector for every fit)."""
    from bench.core.records import BSDFRecord

    t = record.table.copy()
    s = t["signal"].to_numpy(float) - t["dark"].to_numpy(float)
    t["value"] = t["value"].to_numpy(float) * (1.0 + beta * (s / np.median(s) - 1.0))
    return BSDFRecord(t, dict(record.meta))


#: emulated records of the slow study (each an in-plane scan through the emulators)
EMULATED_RECORDS = 60


@pytest.mark.slow
def test_p_values_of_emulated_records_keep_their_level_and_power():
    """EMULATED_RECORDS emulated in-plane records of a Lambertian 0.8 (emulator seeds from 500),
    fitted with ``lambert:albedo=?``: p < 0.05 and p < 0.01 counts inside Binomial(n, level)'s
    central band at a 0.1 % false-alarm rate each (the rates are printed). Power: the first 40
    records with a 0.1 % uncorrected detector non-linearity are rejected at 0.05 in at least 30.
    The level on many records is the synthetic test's above (300 records, cheap); this one keeps
    the emulated bench's real noise at a cost CI can pay.

    Measured once over 200 records (AMD EPYC, 2 cores, heavily loaded, 52 min): p < 0.05 in 7/200
    (3.5 %), p < 0.01 in 0/200; the chi-square law's rate on 30 such records was 5/30. Non-linear
    detector: 40/40 rejected."""
    from tests.test_fit_normalization import _emulated_record

    ps, wrong = [], []
    for k, seed in enumerate(range(500, 500 + EMULATED_RECORDS)):
        record = _emulated_record(seed)
        ps.append(fit_record(record, "lambert:albedo=?", interval="hessian").p_value)
        if k < 40:
            wrong.append(fit_record(_nonlinear(record, 0.001), "lambert:albedo=?", interval="hessian").p_value)
    ps = np.array(ps)
    n05, n01, rejected = np.count_nonzero(ps < 0.05), np.count_nonzero(ps < 0.01), np.count_nonzero(np.array(wrong) < 0.05)
    n = EMULATED_RECORDS
    print(f"\np < 0.05: {n05}/{n} ({100 * n05 / n:.1f} %), p < 0.01: {n01}/{n} ({100 * n01 / n:.1f} %); "
          f"non-linear detector rejected at 0.05: {rejected}/40")
    for a, n in ((0.05, n05), (0.01, n01)):
        lo, hi = int(binom.ppf(0.0005, n, a)), int(binom.isf(0.0005, n, a))
        assert lo <= n <= hi, (a, n, (lo, hi))
    assert rejected >= 30, rejected
