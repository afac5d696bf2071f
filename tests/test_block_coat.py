"""Mitsuba's ``roughplastic`` and the leaf on the compiled kernels: the float64 block kernel
(:mod:`virtual.kernels.block_coat`) counts the distribution of the ray-by-ray kernel, the ray
kernel the distribution of the specimen's own density (the certified fast path), and
roughplastic's specular-albedo table is within 1e-6 of 1 - E_spec where the beam sends rays.

Agreement cases are two-sample chi-squares (tests/helpers/stats.py) over the patches plus
absorbed and missed, or goodness of fit against the fast path's probabilities; the module runs
``len(AGREE) + len(DENSITY)`` of them at ``EACH`` (Sidak), family-wise false-alarm rate
``FAMILY`` = 1e-3, fixed seeds. Power: a perturbed parameter, or a perturbed albedo table, fails
the same comparison with p < 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.kernels import agreement_with_rays, kernel_counts, on_one_and_all_threads
from tests.helpers.stats import family_rate, goodness_of_fit, two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual import engine
from virtual.engine import gonio_counts, gonio_kernel_for, measurement_params, measurement_seed
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.kernel_codes import B_AXIS_Z, RP_E, RP_N_E, RP_S_HI, RP_S_LO
from virtual.kernels import jit
from virtual.kernels.coat import rp_e
from virtual.model_ids import MODEL_LEAF, MODEL_ROUGHPLASTIC
from virtual.python_engine import incidence
from virtual.specimens import parse_specimen
from virtual.specimens.roughplastic import _specular_albedo, albedo_table, beam_cosines, lagrange4

N = 400_000
PSA = Collector("equal-psa", 9, 24)
CONICAL, COLLIMATED = Beam("conical"), Beam("collimated")
RP = "roughplastic:alpha=0.3,eta=1.5,kd=0.5"
LEAF = "leaf:healthy"

_SLOW = pytest.mark.slow  # roughplastic conical at 60 and 80 deg: 2.2 and 3.3 s (tables of 17 and 33 nodes)
AGREE = [(spec, beam, theta) for spec in (RP, LEAF) for beam in (COLLIMATED, CONICAL) for theta in (0.0, 30.0, 60.0, 80.0)]
AGREE_MARKED = [pytest.param(*case, marks=_SLOW) if case[0] == RP and case[1] is CONICAL and case[2] >= 60.0
                else case for case in AGREE]
# the ray kernel against the certified fast path (collimated: the fast path's beam)
DENSITY = [(RP, 30.0), (RP, 70.0), pytest.param(LEAF, 30.0, marks=_SLOW)]  # the leaf's quadrature: 4.5 CPU-s
FAMILY = 1e-3
EACH = -np.expm1(np.log1p(-FAMILY) / (len(AGREE) + len(DENSITY)))


def test_the_stated_family_wise_rate_is_the_one_run():
    assert family_rate(EACH, len(AGREE) + len(DENSITY)) == pytest.approx(FAMILY, rel=1e-9)


def test_auto_routes_both_families_to_a_block_kernel():
    """block32 where float32 resolves them (tests/test_block32_coat.py), this float64 kernel
    otherwise (here: no parameters to judge by)."""
    for spec in (RP, LEAF):
        sp = parse_specimen(spec)
        assert sp.model in (MODEL_ROUGHPLASTIC, MODEL_LEAF)
        assert gonio_kernel_for(sp.model, CONICAL.disk_code, params=sp.params(550.0)) == "block32"
        assert gonio_kernel_for(sp.model, CONICAL.disk_code) == "block"


@pytest.mark.parametrize("spec, beam, theta", AGREE_MARKED)
def test_block_and_ray_kernels_count_the_same_distribution(spec, beam, theta):
    assert agreement_with_rays(spec, beam, PSA, N, 41, "block", theta) > EACH


@pytest.mark.parametrize("spec, theta", DENSITY)
def test_the_ray_kernel_counts_the_specimens_own_density(spec, theta):
    g = VirtualGoniophotometer(spec, collector=PSA, rays=N, method="fast", seed=5)
    p = g.bin_probabilities(theta, 0.0, 550.0)
    n_bins = 2 * PSA.n_patches
    counts = kernel_counts(spec, COLLIMATED, PSA, N, 43, "ray", theta=theta, phi=0.0)
    observed = counts[:n_bins + 1]  # patches, absorbed (nothing missed)
    expected = p[:n_bins + 1] * N
    assert expected.sum() == pytest.approx(N, rel=1e-6)
    assert counts[n_bins + 1] == 0
    _, pval, _ = goodness_of_fit(observed, expected)
    assert pval > EACH


def _counts(model, params, beam, theta, seed, kernel, n=N):
    return gonio_counts(model, params, beam.code, beam.disk_code, beam.kernel_args(theta, 20.0), PSA.kernel_args(),
                        n, measurement_seed(seed), kernel=kernel)


def test_power_against_a_perturbed_roughness():
    a = kernel_counts(RP, CONICAL, PSA, N, 41, "block", theta=30.0)
    b = kernel_counts("roughplastic:alpha=0.33,eta=1.5,kd=0.5", CONICAL, PSA, N, 42, "ray", theta=30.0)
    assert two_sample_p(a, b) < 1e-6


def test_power_against_a_perturbed_albedo_table(monkeypatch):
    """The table's E_spec moved by 5 % of 1 - E_spec (the base's share by 5 %) is detected (2 %
    is not, at these rays); the table is certified 5e4 times closer than that."""
    sp = parse_specimen(RP)
    a = _counts(sp.model, sp.params(550.0), CONICAL, 30.0, 41, "block")
    exact = engine.incidence_params

    def perturbed(params, beam_kind, beam_args, hemisphere=False):
        q = exact(params, beam_kind, beam_args, hemisphere)
        q[RP_E:] -= 0.05 * (1.0 - q[RP_E:])
        return q

    monkeypatch.setattr(engine, "incidence_params", perturbed)
    b = _counts(sp.model, sp.params(550.0), CONICAL, 30.0, 42, "ray")
    assert two_sample_p(a, b) < 1e-6


def test_power_against_a_perturbed_leaf_body():
    sp = parse_specimen(LEAF)
    p = sp.params(550.0)
    q = p.copy()
    q[3] *= 1.1  # r_b, the body's reflectance (0.12 at 550 nm; the cuticle's roughness moves too few rays)
    a = _counts(sp.model, p, CONICAL, 30.0, 41, "block")
    b = _counts(sp.model, q, CONICAL, 30.0, 42, "ray")
    assert two_sample_p(a, b) < 1e-6


@pytest.mark.parametrize("kernel", ["block", "block32"])
@pytest.mark.parametrize("spec, beam", [(LEAF, CONICAL), (RP, COLLIMATED)])
def test_counts_do_not_depend_on_the_thread_count(spec, beam, kernel):
    """Several chunks, float64 and float32 kernels; the rejected (and, in float32, doubted) rays
    finish on a scalar stream of each chunk's own."""
    n = 3 * (1 << 20) + 5
    one, many = on_one_and_all_threads(lambda: kernel_counts(spec, beam, PSA, n, 3, kernel))
    np.testing.assert_array_equal(one, many)


# --- roughplastic's specular-albedo table ---------------------------------------------------------

@pytest.mark.parametrize("theta", [30.0, pytest.param(80.0, marks=_SLOW)])
def test_conical_rays_lie_within_the_tabulated_cosines(theta):
    lo, hi = beam_cosines(CONICAL.code, CONICAL.kernel_args(theta, 20.0))
    w, hit = incidence(CONICAL, theta, 20.0, 200_000, np.random.default_rng(1))
    mu = np.abs(w[hit, 2])
    assert lo <= mu.min() and mu.max() <= hi
    assert mu.max() - mu.min() > 0.6 * (hi - lo)  # nor very loose (a loose bound costs table nodes only)


@pytest.mark.parametrize("theta, alpha", [(0.0, 0.3), (30.0, 0.3), pytest.param(80.0, 0.3, marks=_SLOW),
                                          pytest.param(60.0, 0.05, marks=_SLOW)])
def test_the_albedo_table_is_within_1e_6_of_the_complement(theta, alpha):
    """E_spec from the table at random cosines of the beam against E_spec computed there (the
    Python sampler's own, tolerance 1e-9): the base's probability c t / (1 - E) moves by
    |dE| / (1 - E) < 1e-6."""
    lo, hi = beam_cosines(CONICAL.code, CONICAL.kernel_args(theta, 0.0))
    s_lo, s_hi, values = albedo_table(alpha, 1.5, lo, hi)
    mu = np.random.default_rng(7).uniform(max(lo, 1e-6), hi, 5)
    exact = np.array([_specular_albedo(float(m), alpha, 1.5) for m in mu])
    table = lagrange4(values, s_lo, s_hi, np.sqrt(1.0 - mu))
    assert np.all(np.abs(table - exact) <= 1e-6 * (1.0 - exact))


@jit
def _kernel_e(p, mu):
    out = np.empty(mu.shape[0])
    for i in range(mu.shape[0]):
        out[i] = rp_e(p, mu[i])
    return out


def test_the_kernels_read_the_table_as_tabulated():
    """rp_e (the kernels') against lagrange4 (numpy), conical; collimated, exactly E_spec."""
    sp = parse_specimen(RP)
    p = measurement_params(sp.model, sp.params(550.0), CONICAL.code, CONICAL.kernel_args(30.0, 0.0))
    lo, hi = beam_cosines(CONICAL.code, CONICAL.kernel_args(30.0, 0.0))
    mu = np.linspace(lo, hi, 101)
    values = p[RP_E:RP_E + int(p[RP_N_E])]
    np.testing.assert_allclose(_kernel_e(p, mu), lagrange4(values, p[RP_S_LO], p[RP_S_HI], np.sqrt(1.0 - mu)),
                               rtol=0, atol=1e-14)
    b = COLLIMATED.kernel_args(30.0, 0.0)
    q = measurement_params(sp.model, sp.params(550.0), COLLIMATED.code, b)
    mu0 = abs(float(b[B_AXIS_Z]))
    assert _kernel_e(q, np.array([mu0]))[0] == _specular_albedo(mu0, 0.3, 1.5)
