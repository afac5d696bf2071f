"""The Ward family, a law written once (virtual/kernels/laws/ward.py) and run by every kernel path:
its counts follow its own density, it conserves energy, and it is a specimen like the others.

Agreement: each kernel's counts against the probabilities integrated from the family's density
(:meth:`~virtual.specimens.ward.Ward.bsdf` by :mod:`virtual.quadrature`, which never calls a
kernel), Pearson's chi-square (tests/helpers/stats.py) over the patches plus absorbed, for a
collimated beam. ``len(AGREE)`` cases at ``EACH`` each (Sidak): a family-wise false-alarm rate
of ``FAMILY`` = 1e-3; seeds fixed. Power: the same test against a lobe 15 % wider gives p < 1e-6.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special

from bench.cli import main
from tests.helpers.kernels import kernel_counts
from tests.helpers.stats import family_rate, goodness_of_fit
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_kernel_for
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.law_table import MODEL_WARD
from virtual.specimens import SPECIMENS, parse_specimen

N = 400_000
COLLECTOR = "equal-psa:9x24"
PSA = Collector("equal-psa", 9, 24)
COLLIMATED = Beam("collimated")
SPEC = "ward:alpha=0.2,ks=0.6,kd=0.3"

# (kernel, spec, theta_i): oblique (in make test), grazing -- much of the lobe below the horizon --
# and from below (make test-slow)
AGREE = [pytest.param(kernel, spec, theta, marks=() if theta == 35.0 else pytest.mark.slow)
         for kernel in ("ray", "block", "block32")
         for spec, theta in ((SPEC, 35.0), ("ward:alpha=0.5,ks=0.8,kd=0.1", 75.0), ("ward:alpha=0.05,ks=0.9,kd=0", 150.0))]
FAMILY = 1e-3
EACH = -math.expm1(math.log1p(-FAMILY) / len(AGREE))


def _expected(spec: str, theta: float) -> np.ndarray:
    """Bin probabilities (patches, absorbed, missed) from the density alone."""
    g = VirtualGoniophotometer(spec, collector=COLLECTOR, beam="collimated", rays=N, method="fast")
    return g.bin_probabilities(theta, 20.0, 550.0)


def test_the_stated_family_wise_rate_is_the_one_run() -> None:
    assert family_rate(EACH, len(AGREE)) == pytest.approx(FAMILY, rel=1e-9)


@pytest.mark.parametrize("kernel, spec, theta", AGREE)
def test_every_kernel_counts_the_density(kernel: str, spec: str, theta: float) -> None:
    sp = parse_specimen(spec)
    assert gonio_kernel_for(sp.model, COLLIMATED.disk_code, kernel, sp.params(550.0)) == kernel
    counts = kernel_counts(spec, COLLIMATED, PSA, N, 41, kernel, theta=theta, phi=20.0)
    expected = _expected(spec, theta) * N
    _, p, _ = goodness_of_fit(counts[:-1], expected[:-1])  # no ray of a collimated beam misses
    assert counts[-1] == 0 and p > EACH


@pytest.mark.parametrize("kernel", [pytest.param("block", marks=pytest.mark.slow), "block32"])
def test_the_comparison_has_power_against_a_wider_lobe(kernel: str) -> None:
    counts = kernel_counts(SPEC, COLLIMATED, PSA, N, 41, kernel, theta=35.0, phi=20.0)
    expected = _expected("ward:alpha=0.23,ks=0.6,kd=0.3", 35.0) * N
    assert goodness_of_fit(counts[:-1], expected[:-1])[1] < 1e-6


@pytest.mark.parametrize("theta", [0.0, 40.0, 80.0])
def test_energy_is_conserved_and_the_lobe_is_normalized(theta: float) -> None:
    """Albedo <= kd + ks at every incidence, nothing below (opaque). At normal incidence the
    albedo is known in closed form -- kd + ks E[cos(theta_o)], cos(theta_o) = cos(2 theta_h) =
    (1 - t) / (1 + t) with t = tan^2(theta_h) exponential of mean alpha^2, so E = 2 x e^x E1(x) - 1,
    x = 1 / alpha^2 -- which checks the density's normalization apart from the sampler."""
    a, ks, kd = 0.05, 0.7, 0.3
    p = _expected(f"ward:alpha={a},ks={ks},kd={kd}", theta)
    upper, lower = p[:PSA.n_patches], p[PSA.n_patches:PSA.n_bins]
    assert lower.sum() == 0.0
    assert upper.sum() <= kd + ks
    if theta == 0.0:
        x = 1.0 / a ** 2
        assert upper.sum() == pytest.approx(kd + ks * (2.0 * x * special.exp1(x) * math.exp(x) - 1.0), abs=3e-6)


def test_the_density_is_reciprocal_and_opaque() -> None:
    sp = parse_specimen(SPEC)
    v = np.random.default_rng(5).normal(size=(200, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2])  # both directions above
    wi, wo = v[:100], v[100:]
    f_io = np.array([sp.bsdf(a, b[None, :], 550.0)[0] for a, b in zip(wi, wo)])
    f_oi = np.array([sp.bsdf(b, a[None, :], 550.0)[0] for a, b in zip(wi, wo)])
    np.testing.assert_allclose(f_io, f_oi, rtol=1e-12)
    assert (f_io > 0.0).all()
    assert sp.bsdf(wi[0], wo[:5] * [1.0, 1.0, -1.0], 550.0).max() == 0.0  # nothing transmitted


def test_ward_is_a_family_like_the_others(capsys: pytest.CaptureFixture[str]) -> None:
    assert SPECIMENS["ward"].model == MODEL_WARD
    sp = parse_specimen("ward:alpha=0.005")
    assert gonio_kernel_for(sp.model, COLLIMATED.disk_code, params=sp.params(550.0)) == "block"  # below MIN_ALPHA
    assert gonio_kernel_for(MODEL_WARD, COLLIMATED.disk_code, params=parse_specimen(SPEC).params(550.0)) == "block32"
    with pytest.raises(Exception, match="kd \\+ ks"):
        parse_specimen("ward:ks=0.8,kd=0.3")
    assert main(["spectro", "--specimen", "ward:alpha=0.2,ks=0.5,kd=0.4", "--wavelengths", "550", "--rays", "20000",
                 "--seed", "1"]) == 0
    assert "550" in capsys.readouterr().out
