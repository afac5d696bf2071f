"""The virtual goniophotometer: a Lambertian in its binomial intervals, roles, records, fast path."""

import math

import numpy as np
import pytest
from scipy import stats

from bench.core.errors import GeometryError, InputError
from bench.core.geometry import Geometry
from bench.core.conformance import check_conformance
from virtual.beam import Beam
from virtual.goniophotometer import VirtualGoniophotometer


def _lambert_record(n, seed, collector="equal-psa:9x36", method="rays", albedo=1.0):
    g = VirtualGoniophotometer(f"lambert:albedo={albedo}", collector=collector, rays=n, seed=seed, method=method)
    return g, g.measure_bsdf(30.0)


def test_lambertian_albedo_one_every_patch_in_its_binomial_interval():
    # p = PSA / pi for every patch (1/(9*36) with equal PSA). Per patch the 99.9 % two-sided
    # binomial interval of the count around N p. With 324 patches, the number outside is
    # Binomial(324, 1e-3): P(X > 3) = 2.7e-4, so at most 3 may fall outside; and with the
    # Bonferroni level 1e-3 / 324 none may (each seed).
    n = 2_000_000
    for seed in (1, 2):
        g, rec = _lambert_record(n, seed)
        up = rec.reflection().table
        p = up.psa.to_numpy() / math.pi
        k = up["count"].to_numpy()
        lo, hi = stats.binom.ppf(0.0005, n, p), stats.binom.isf(0.0005, n, p)
        assert np.sum((k < lo) | (k > hi)) <= 3
        blo, bhi = stats.binom.ppf(0.0005 / 324, n, p), stats.binom.isf(0.0005 / 324, n, p)
        assert np.all((k >= blo) & (k <= bhi))
        assert rec.transmission().table["count"].sum() == 0
        # every estimate is 1/pi to within its own interval, almost always
        inside = (up.ci_lo <= 1 / math.pi) & (1 / math.pi <= up.ci_hi)
        assert inside.mean() > 0.97


def test_rms_error_falls_like_one_over_sqrt_n():
    # RMS of (f_hat - 1/pi) over patches, for N = 1e5, 1e6, 1e7; theory: sqrt(p(1-p)/N)/PSA.
    # Log-log slope -1/2: the fitted slope of three points lies within +-0.1 of it (the RMS of
    # 324 patches has a relative spread of about 1/sqrt(2*324) = 4 %, i.e. +-0.04 in slope).
    ns, rms = [10**5, 10**6, 10**7], []
    for n in ns:
        _, rec = _lambert_record(n, 3)
        up = rec.reflection().table
        err = up.value.to_numpy() - 1 / math.pi
        rms.append(math.sqrt(np.mean(err**2)))
        p = up.psa.to_numpy()[0] / math.pi
        expected = math.sqrt(p * (1 - p) / n) / up.psa.to_numpy()[0]
        assert 0.85 < rms[-1] / expected < 1.15  # chi-square(324) / 324 within +-15 %: 5 sigma
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


def test_fast_path_matches_counting_rays_in_distribution():
    # Two-sample chi-square (homogeneity) between ray counting and the multinomial fast path
    # over the 324 patches + absorbed; at alpha = 1e-3 a correct fast path fails 1 time in 1000.
    n = 1_000_000
    _, rays = _lambert_record(n, 5, method="rays", albedo=0.7)
    _, fast = _lambert_record(n, 6, method="fast", albedo=0.7)
    a = np.append(rays.reflection().table["count"].to_numpy(), rays.meta["totals"][0]["absorbed"])
    b = np.append(fast.reflection().table["count"].to_numpy(), fast.meta["totals"][0]["absorbed"])
    chi2, pvalue, _, _ = stats.chi2_contingency(np.vstack([a, b]))
    assert pvalue > 1e-3
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
