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


def test_lambertian_within_v_in_99_percent_of_200_seeded_runs():
    # Eq. 3.5 promises P(|R_hat - R| > v) <= delta = 0.01 per run. Over 200 independent runs the
    # number of failures is Binomial(200, <=0.01); acceptance: at least 99 % within v, i.e. at
    # most 2 failures. (Hoeffding is conservative: the exact failure rate at R = 0.375 is
    # P(|Z| > 0.005 / sqrt(0.375 * 0.625 / 105967)) = 8e-4, so the expected count is 0.16.)
    n = hoeffding_rays(0.005, 0.01)
    assert n == 105967
    errors = []
    for seed in range(200):
        sp = VirtualSpectrophotometer("lambert:reflectance=0.375", rays=n, seed=seed)
        errors.append(sp.measure("8/d", [550.0]).reflectance[0] - 0.375)
    errors = np.abs(errors)
    assert np.sum(errors > 0.005) <= 2
    # and the runs really are independent: the spread matches the binomial standard error
    # chi-square of the standardized errors with 200 degrees of freedom, two-sided at 2e-3
    sd = math.sqrt(0.375 * 0.625 / n)
    chi2 = np.sum((np.array(errors) / sd) ** 2)
    assert stats.chi2.sf(chi2, df=200) > 1e-3 and stats.chi2.cdf(chi2, df=200) > 1e-3


def test_collimated_and_conical_beams_give_the_same_lambertian_reflectance():
    # two-sample z-test per wavelength at alpha = 1e-3 (|z| < 3.29)
    kw = dict(rays=400_000, seed=11)
    a = VirtualSpectrophotometer("lambert:reflectance=0.6,transmittance=0.2", beam="collimated", **kw)
    b = VirtualSpectrophotometer("lambert:reflectance=0.6,transmittance=0.2", beam="conical", **kw)
    sa, sb = a.measure("8/d", [450, 650]), b.measure("8/d", [450, 650])
    for x, y, p in ((sa.reflectance, sb.reflectance, 0.6), (sa.transmittance, sb.transmittance, 0.2)):
        z = (x - y) / math.sqrt(2 * p * (1 - p) / 400_000)
        assert np.all(np.abs(z) < 3.29)


def test_r_plus_t_plus_absorption_is_one_ray_by_ray():
    sp = VirtualSpectrophotometer("lambert:reflectance=0.5,transmittance=0.3", rays=123_457, seed=2, beam="conical")
    s = sp.measure("8/d", [500.0, 600.0])
    for c in s.meta["counts"]:
        assert c["reflected"] + c["transmitted"] + c["absorbed"] + c["missed"] == c["N"] == 123_457
    assert np.allclose(s.reflectance + s.transmittance + s.absorptance, 1.0, atol=0)


def test_same_seed_same_result_and_wavelength_keyed_streams():
    a = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=5).measure("8/d", "500:600:50")
    b = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=5).measure("8/d", [550.0])
    assert a.reflectance[1] == b.reflectance[0]
    c = VirtualSpectrophotometer("lambert:reflectance=0.5", rays=50_000, seed=6).measure("8/d", [550.0])
    assert c.reflectance[0] != b.reflectance[0]


def test_intervals_cover_the_true_value_at_their_nominal_rate():
    # 300 runs at 99 % confidence: the number of misses is Binomial(300, <= 0.01) (Clopper-Pearson
    # is conservative); P(X >= 9) < 1e-3 at p = 0.01, so 9 or more misses would fail the claim.
    misses = 0
    for seed in range(300):
        s = VirtualSpectrophotometer("lambert:reflectance=0.2", rays=5_000, seed=seed).measure("8/d", [550.0])
        lo, hi = s.reflectance_ci[0]
        misses += not (lo <= 0.2 <= hi)
    assert misses < 9


def test_bidirectional_45_0_reflectance_factor_of_a_lambertian_is_its_reflectance():
    # RF = (n_cone/N) / (sin^2(5 deg) cos 0): for a Lambertian RF = R. The count in the cone is
    # binomial with p = R sin^2(5 deg); 4 standard errors bound the deviation.
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
