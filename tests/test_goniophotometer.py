"""The virtual goniophotometer: a Lambertian in its binomial intervals, roles, records, fast path."""

import math

import numpy as np
import pytest
from scipy import stats

from bench.core.errors import GeometryError, InputError
from bench.core.geometry import Geometry
from bench.core.conformance import check_conformance
from tests.helpers.stats import binomial_band, binomial_outside, two_sample_p
from virtual.beam import Beam
from virtual.goniophotometer import VirtualGoniophotometer


def _lambert_record(n, seed, collector="equal-psa:9x36", method="rays", albedo=1.0):
    g = VirtualGoniophotometer(f"lambert:albedo={albedo}", collector=collector, rays=n, seed=seed, method=method)
    return g, g.measure_bsdf(30.0)


def _patch_checks(rec, n: int) -> dict[str, bool]:
    """The three per-record checks of a Lambertian of albedo 1 (p = PSA / pi for every patch):
    A at most 3 counts outside their equal-tailed binomial band at 1e-3; B none outside the
    Bonferroni band at 1e-3 / patches; C the record's own intervals cover 1/pi for more than
    97 % of the patches."""
    up = rec.reflection().table
    p, k = up.psa.to_numpy() / math.pi, up["count"].to_numpy()
    lo, hi = binomial_band(n, p, 1e-3)
    blo, bhi = binomial_band(n, p, 1e-3 / len(k))
    inside = (up.ci_lo <= 1 / math.pi) & (1 / math.pi <= up.ci_hi)
    return {"A": np.sum((k < lo) | (k > hi)) <= 3, "B": bool(np.all((k >= blo) & (k <= bhi))),
            "C": inside.mean() > 0.97}


def _patch_checks_rate(n: int, patches: int, delta: float) -> float:
    """Family-wise false-alarm rate of :func:`_patch_checks` on one record (Bonferroni over the
    three; the counts of a multinomial are negatively correlated, which only lowers A's and C's
    tails below the independent binomial ones used here)."""
    p = 1 / patches
    q = binomial_outside(n, p, *binomial_band(n, p, 1e-3))  # a patch outside A's band: <= 1e-3
    a = stats.binom.sf(3, patches, q)  # more than 3 of them
    b = patches * binomial_outside(n, p, *binomial_band(n, p, 1e-3 / patches))  # <= 1e-3
    c = stats.binom.sf(math.floor(0.03 * patches), patches, delta)  # intervals at level 1 - delta
    return a + b + c


def test_lambertian_albedo_one_every_patch_in_its_binomial_interval():
    # two seeds x _patch_checks: family-wise false-alarm rate 2 x (3.0e-4 + 9.7e-4 + 1.8e-3)
    # = 6.1e-3, computed here; power: albedo 0.97 fails check A (next test)
    n = 2_000_000
    assert 2 * _patch_checks_rate(n, 324, 0.01) == pytest.approx(6.1e-3, abs=0.1e-3)
    for seed in (1, 2):
        g, rec = _lambert_record(n, seed)
        assert rec.meta["delta"] == 0.01
        assert _patch_checks(rec, n) == {"A": True, "B": True, "C": True}
        assert rec.transmission().table["count"].sum() == 0


def test_the_patch_checks_have_power_against_an_albedo_3_percent_low():
    # every count 2.4 standard errors low: about a fifth of the patches leave A's band
    _, rec = _lambert_record(2_000_000, 1, albedo=0.97)
    checks = _patch_checks(rec, 2_000_000)
    assert not checks["A"] and not checks["C"]


def test_rms_error_falls_like_one_over_sqrt_n():
    # RMS of (f_hat - 1/pi) over patches, for N = 1e5, 1e6, 1e7; theory: sqrt(p(1-p)/N)/PSA.
    # (RMS / theory)^2 is chi-square(324) / 324, so |RMS / theory - 1| < 15 % is 3.8 sigma:
    # false alarm RMS_ALPHA = 1.3e-4 per N, 4.0e-4 for the three (computed below). Log-log slope
    # -1/2: the fitted slope of three points lies within +-0.1 of it (its standard error is
    # 0.04 / sqrt(10.6) = 0.012: 8 sigma, a negligible false-alarm rate). Power: the same RMS
    # compared with the theory of 1.7 N (an engine 30 % noisier than binomial) leaves the band.
    rms_alpha = stats.chi2.cdf(0.85**2 * 324, 324) + stats.chi2.sf(1.15**2 * 324, 324)
    assert 3 * rms_alpha == pytest.approx(4.0e-4, abs=0.1e-4)
    ns, rms = [10**5, 10**6, 10**7], []
    for n in ns:
        _, rec = _lambert_record(n, 3)
        up = rec.reflection().table
        err = up.value.to_numpy() - 1 / math.pi
        rms.append(math.sqrt(np.mean(err**2)))
        p, psa = up.psa.to_numpy()[0] / math.pi, up.psa.to_numpy()[0]
        expected = math.sqrt(p * (1 - p) / n) / psa
        assert 0.85 < rms[-1] / expected < 1.15
        assert not 0.85 < rms[-1] / (math.sqrt(p * (1 - p) / (1.7 * n)) / psa) < 1.15  # power
    slope = np.polyfit(np.log(ns), np.log(rms), 1)[0]
    assert abs(slope + 0.5) < 0.1


def test_equal_psa_gives_equal_relative_error_unlike_equal_angle():
    # With equal PSA every patch of a Lambertian has the same p, so the same relative error;
    # equal angles put tiny PSA at the pole ring (relative error much larger there).
    _, psa = _lambert_record(10**6, 4, "equal-psa:9x36")
    _, ang = _lambert_record(10**6, 4, "equal-angle:9x36")

    def rel(t):
        return (t["std"] / t["value"]).to_numpy()

    up_psa, up_ang = psa.reflection().table, ang.reflection().table
    assert np.ptp(up_psa.psa) < 1e-15
    # equal angles, 10 deg rings: PSA(40-50 deg) / PSA(0-10 deg) = 0.1736 / 0.0302 = 5.75, so the
    # relative errors differ by sqrt(5.75) = 2.4; with equal PSA they differ only by the noise of
    # the counts (~3,000 per patch: a few per cent)
    assert rel(up_ang).max() / rel(up_ang).min() > 2.0
    assert rel(up_psa).max() / rel(up_psa).min() < 1.3


def _counts(rec) -> np.ndarray:
    return np.append(rec.reflection().table["count"].to_numpy(), rec.meta["totals"][0]["absorbed"])


def test_fast_path_matches_counting_rays_in_distribution():
    # The suite's two-sample chi-square between ray counting and the multinomial fast path over
    # the 324 patches + absorbed, one comparison: a correct fast path fails 1 time in 1000.
    # Power: the fast path of albedo 0.69 against rays of 0.7 is rejected (p < 1e-6).
    n = 1_000_000
    _, rays = _lambert_record(n, 5, method="rays", albedo=0.7)
    _, fast = _lambert_record(n, 6, method="fast", albedo=0.7)
    assert two_sample_p(_counts(rays), _counts(fast)) > 1e-3
    assert two_sample_p(_counts(rays), _counts(_lambert_record(n, 6, method="fast", albedo=0.69)[1])) < 1e-6
    assert fast.meta["method"] == "fast" and rays.meta["method"] == "rays"
    assert fast.meta["kernel"] == "fast" and rays.meta["kernel"] == "block32"  # a Lambertian: the float32 block kernel


def test_record_says_which_kernel_counted():
    g = VirtualGoniophotometer("phong:exponent=20", rays=1000, seed=1, method="rays")
    assert g.kernel() == "block32"  # Phong has a float32 form
    g = VirtualGoniophotometer("phong:exponent=1e5,ks=0.4", rays=1000, seed=1, method="rays")
    assert g.kernel() == "block"  # a lobe narrower than float32 resolves: the float64 block kernel
    g = VirtualGoniophotometer("ggx:alpha=0.3", beam=Beam("conical", disk_sampling="rejection"), rays=1000, seed=1)
    assert g.kernel() == "ray"  # rejection-sampled disks are the ray-by-ray kernel's
    g = VirtualGoniophotometer("ggx:alpha=0.3", beam=Beam("conical"), rays=1000, seed=1)
    assert g.kernel() == "block32" and g.measure_bsdf(30.0, 0.0).meta["kernel"] == "block32"
    g = VirtualGoniophotometer("ggx:alpha=0.001", beam=Beam("conical"), rays=1000, seed=1)
    assert g.kernel() == "block"  # a near mirror: float32 would not resolve its lobe, the float64 block kernel


def test_roles_and_conformance():
    g = VirtualGoniophotometer("lambert:albedo=0.8", rays=200_000, seed=1, wavelengths="500,600")
    roles = check_conformance(g, reachable=[Geometry(30, 0, 20, 180), Geometry(0, 0, 45, 90),
                                            Geometry(60, 90, 30, 30)],
                              unreachable=[Geometry(90, 0, 10, 0), Geometry(120, 0, 10, 0)])
    assert roles == ["Instrument", "Goniometer", "Spectrometer", "LightSource"]
    g.off()
    assert not g.acquire(0.1).signal.any()


def test_acquire_follows_the_arms_and_the_cosine():
    g = VirtualGoniophotometer("lambert:albedo=0.8", rays=2_000_000, seed=1, method="rays", gain=1e4)
    g.move_to(Geometry(20, 0, 10, 180))
    near = g.acquire(1.0).signal[0]
    g.move_to(Geometry(20, 0, 70, 180))
    far = g.acquire(1.0).signal[0]
    # signal = gain t f cos(theta_r): a Lambertian gives the ratio of the cosines of the
    # patch-centre directions actually viewed (within 5 binomial sigma)
    assert far / near == pytest.approx(math.cos(math.radians(70)) / math.cos(math.radians(10)), rel=0.12)


def test_simulations_are_cached_per_incidence_and_wavelength():
    g = VirtualGoniophotometer("lambert:albedo=0.8", rays=100_000, seed=1, method="rays")
    a = g.simulate(30.0, 0.0, 550.0)
    assert g.simulate(30.0, 0.0, 550.0) is a
    assert g.simulate(31.0, 0.0, 550.0) is not a


def test_bad_configuration_is_refused():
    with pytest.raises(InputError):
        VirtualGoniophotometer("lambert:albedo=0.5", collector="equal-psa:0x36")
    with pytest.raises(InputError, match="method"):
        VirtualGoniophotometer("lambert:albedo=0.5", method="magic")
    with pytest.raises(GeometryError, match="grazing"):
        VirtualGoniophotometer("lambert:albedo=0.5", rays=10).measure_bsdf(90.0)
