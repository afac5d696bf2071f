"""The virtual spectrophotometer: a Lambertian within eq. 3.5's bound, and the instrument contract."""

import math

import numpy as np
import pytest
from scipy import stats

from bench.core.errors import GeometryError, InputError, SpecimenError
from bench.core.conformance import check_conformance
from virtual.bounds import hoeffding_rays
from virtual.spectrophotometer import VirtualSpectrophotometer
from bench.core.parsing import parse_wavelengths


def test_passes_the_conformance_checker():
    sp = VirtualSpectrophotometer("lambert:reflectance=0.4,transmittance=0.3", rays=20_000, seed=1)
    assert check_conformance(sp) == ["Instrument", "Spectrophotometer"]


R, V, DELTA, RUNS = 0.375, 0.005, 0.01, 200


def _errors(n: int) -> np.ndarray:
    """|R_hat - R| of RUNS independently seeded runs of n rays."""
    return np.abs([VirtualSpectrophotometer(f"lambert:reflectance={R}", rays=n, seed=seed)
                   .measure("8/d", [550.0]).reflectance[0] - R for seed in range(RUNS)])


def _failure_rate(n: int) -> float:
    """Exact P(|k/n - R| > V) for k ~ Binomial(n, R)."""
    return stats.binom.cdf(math.ceil(n * (R - V)) - 1, n, R) + stats.binom.sf(math.floor(n * (R + V)), n, R)


def _spread_p(errors: np.ndarray, n: float) -> float:
    """Smaller tail of the chi-square (df = RUNS) of the errors standardized by the binomial
    standard error of n rays: both tails are checked at SPREAD_TAIL."""
    chi2 = np.sum((errors / math.sqrt(R * (1 - R) / n)) ** 2)
    return min(stats.chi2.sf(chi2, RUNS), stats.chi2.cdf(chi2, RUNS))


SPREAD_TAIL = 1e-3
# a rule that fails at exactly DELTA: the normal approximation's ray count, (z_{1-delta/2} / v)^2 R(1 - R)
N_AT_DELTA = math.ceil((stats.norm.isf(DELTA / 2) / V) ** 2 * R * (1 - R))


def test_lambertian_within_v_in_99_percent_of_200_seeded_runs():
    # Eq. 3.5 promises P(|R_hat - R| > v) <= delta = 0.01 per run; at R = 0.375 and its N the
    # exact failure rate is 7.7e-4 (Hoeffding is conservative). Two checks:
    # 1. the seed's acceptance, at most 2 failures in 200 runs: false alarm
    #    P(Binomial(200, 7.7e-4) > 2) = 5.4e-4. It would pass a rule failing at exactly delta
    #    68 % of the time: 200 runs cannot tell such a rule apart, so the power is in 2.
    # 2. the spread: the chi-square of the 200 standardized errors, each tail at 1e-3 (2e-3).
    # Family-wise: 5.4e-4 + 2e-3 = 2.5e-3 (computed below).
    n = hoeffding_rays(V, DELTA)
    assert n == 105967
    f0 = _failure_rate(n)
    assert f0 == pytest.approx(7.7e-4, abs=0.05e-4)
    assert stats.binom.sf(2, RUNS, f0) + 2 * SPREAD_TAIL == pytest.approx(2.5e-3, abs=0.05e-3)
    assert stats.binom.cdf(2, RUNS, _failure_rate(N_AT_DELTA)) == pytest.approx(0.68, abs=0.01)
    errors = _errors(n)
    assert np.sum(errors > V) <= 2
    assert _spread_p(errors, n) > SPREAD_TAIL
    # power: a rule failing at exactly delta (N_AT_DELTA = 62,203 rays, exact rate 1.0e-2) has
    # errors sqrt(n / N_AT_DELTA) = 1.31 times wider -- the same errors judged as if they came
    # from n * 1.70 rays -- and check 2 rejects it (chi-square ~ 340 on 200 df)
    assert _failure_rate(N_AT_DELTA) == pytest.approx(DELTA, rel=0.01)
    assert _spread_p(errors, n * n / N_AT_DELTA) < SPREAD_TAIL


def test_collimated_and_conical_beams_give_the_same_lambertian_reflectance():
    # two-sample z-tests of R and T at two wavelengths, each at alpha = 1e-3 (|z| < 3.29):
    # family-wise at most 4e-3 (Bonferroni)
    kw = dict(rays=400_000, seed=11)
    a = VirtualSpectrophotometer("lambert:reflectance=0.6,transmittance=0.2", beam="collimated", **kw)
    b = VirtualSpectrophotometer("lambert:reflectance=0.6,transmittance=0.2", beam="conical", **kw)
    sa, sb = a.measure("8/d", [450, 650]), b.measure("8/d", [450, 650])
    for x, y, p in ((sa.reflectance, sb.reflectance, 0.6), (sa.transmittance, sb.transmittance, 0.2)):
        z = (x - y) / math.sqrt(2 * p * (1 - p) / 400_000)
        assert np.all(np.abs(z) < 3.29)


def test_the_kernels_absorbed_tally_is_one_minus_r_minus_t_and_the_specimens_absorption():
    """Every ray ends in exactly one tally; the kernel's own ``absorbed`` count (not derived from R
    and T) is the record's 1 - R - T, and matches the specimen's absorption 1 - 0.5 - 0.3 = 0.2.
    That last check is a z-test per wavelength at |z| < 3.89 (two-sided 1e-4; 2e-4 family-wise);
    power: an absorption of 0.21 instead lies ~8.8 standard errors away and is rejected."""
    sp = VirtualSpectrophotometer("lambert:reflectance=0.5,transmittance=0.3", rays=123_457, seed=2, beam="conical")
    s = sp.measure("8/d", [500.0, 600.0])
    counts = s.meta["counts"]
    for c in counts:
        assert c["reflected"] + c["transmitted"] + c["absorbed"] + c["missed"] == c["N"] == 123_457
    hits = np.array([c["N"] - c["missed"] for c in counts], dtype=float)
    absorbed = np.array([c["absorbed"] for c in counts], dtype=float) / hits
    np.testing.assert_allclose(s.absorptance, absorbed, rtol=1e-12, atol=0)
    se = math.sqrt(0.2 * 0.8 / hits.min())
    assert np.all(np.abs(absorbed - 0.2) / se < 3.89)
    assert np.all(np.abs(absorbed - 0.21) / se > 3.89)  # power: a 5 % wrong absorption is caught


def test_same_seed_same_result_and_wavelength_keyed_streams():
    a = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=5).measure("8/d", "500:600:50")
    b = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=5).measure("8/d", [550.0])
    assert a.reflectance[1] == b.reflectance[0]
    c = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=6).measure("8/d", [550.0])
    assert c.reflectance[0] != b.reflectance[0]


def test_intervals_cover_the_true_value_at_their_nominal_rate():
    # 300 runs at 99 % confidence: the number of misses is Binomial(300, <= 0.01) (Clopper-Pearson
    # is conservative), so "fewer than 9" false-alarms with probability at most
    # P(X >= 9) = 3.6e-3. Power: 95 % intervals (scipy's Clopper-Pearson) on the same counts,
    # too narrow for the claim, miss 9 times or more (probability 0.97 at their 5 % rate).
    assert stats.binom.sf(8, 300, 0.01) == pytest.approx(3.6e-3, abs=0.05e-3)
    misses = misses_95 = 0
    for seed in range(300):
        s = VirtualSpectrophotometer("lambert:reflectance=0.2", rays=5_000, seed=seed).measure("8/d", [550.0])
        lo, hi = s.reflectance_ci[0]
        misses += not (lo <= 0.2 <= hi)
        c = s.meta["counts"][0]
        ci = stats.binomtest(c["reflected"], c["N"]).proportion_ci(0.95, method="exact")
        misses_95 += not (ci.low <= 0.2 <= ci.high)
    assert misses < 9 <= misses_95


def test_bidirectional_45_0_reflectance_factor_of_a_lambertian_is_its_reflectance():
    # RF = (n_cone/N) / (sin^2(5 deg) cos 0): for a Lambertian RF = R. The count in the cone is
    # binomial with p = R sin^2(5 deg); 4 standard errors bound the deviation (false alarm 6.3e-5).
    n = 4_000_000
    s = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=n, seed=3).measure("45/0", [550.0])
    p = 0.5 * math.sin(math.radians(5)) ** 2
    se = math.sqrt(p * (1 - p) / n) / math.sin(math.radians(5)) ** 2
    assert abs(s.reflectance[0] - 0.5) < 4 * se
    assert s.meta["quantity"] == "reflectance factor"
    assert s.reflectance_ci[0, 0] < 0.5 < s.reflectance_ci[0, 1]


def test_diffuse_illumination_is_measured_by_reciprocity_and_says_so():
    s = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=10_000, seed=3).measure("d/0", [550.0])
    assert s.meta["measured_as"] == "0/d" and s.meta["reciprocity"]


def test_gloss_trap_excludes_the_specular_cone():
    full = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=400_000, seed=4).measure("8/d", [550.0])
    trap = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=400_000, seed=4).measure("8/de", [550.0])
    # same rays: the trap removes exactly the rays in the 5 deg specular cone, about R sin^2(5) cos(8)
    # (binomial; 4 standard errors: false alarm 6.3e-5)
    removed = full.reflectance[0] - trap.reflectance[0]
    expected = 0.5 * math.sin(math.radians(5)) ** 2 * math.cos(math.radians(8))
    assert abs(removed - expected) < 4 * math.sqrt(expected / 400_000)


def test_colorchecker_spectrum_and_its_range():
    sp = VirtualSpectrophotometer("colorchecker:dark skin", rays=20_000, seed=1)
    s = sp.measure("8/d", "400:700:100")
    assert np.all(s.reflectance < 0.5) and np.all(s.transmittance == 0)
    with pytest.raises(SpecimenError, match="outside the data"):
        sp.measure("8/d", [300.0])


@pytest.mark.parametrize("text,expected", [("400:700:100", [400, 500, 600, 700]), ("550", [550]),
                                           ("450,550", [450, 550]), ("400:700:400", [400])])
def test_parse_wavelengths(text, expected):
    assert np.allclose(parse_wavelengths(text), expected)


@pytest.mark.parametrize("bad", ["700:400:10", "400:700:0", "abc", "", "-5"])
def test_bad_wavelengths_are_refused(bad):
    with pytest.raises(InputError):
        parse_wavelengths(bad)


def test_bad_inputs_are_refused():
    with pytest.raises(SpecimenError, match="unknown specimen"):
        VirtualSpectrophotometer("marble")
    with pytest.raises(SpecimenError, match="reflectance"):
        VirtualSpectrophotometer("lambert:reflectance=1.5")
    with pytest.raises(GeometryError):
        VirtualSpectrophotometer("lambert:reflectance=0.5", rays=10).measure("12/7", [550])
    with pytest.raises(InputError, match="rays"):
        VirtualSpectrophotometer("lambert:reflectance=0.5", rays=0)
