"""The block kernels -- float64 ("block") and float32 ("block32") -- count the same distribution
as the float64 ray-by-ray kernel for every specimen family they take, the comparison tells a
slightly perturbed specimen apart, and their counts do not depend on the thread count.

Each agreement case is the suite's two-sample chi-square (tests/helpers/stats.py) over the
collector patches plus absorbed and missed: two independent multinomial samples of equal size,
so under equal distributions the p-value is uniform. The module runs ``len(AGREE)`` such cases,
each at ``EACH`` (Sidak), so its family-wise false-alarm rate is ``FAMILY`` = 1e-3 (checked by
``test_the_stated_family_wise_rate_is_the_one_run``); the seeds are fixed, so the outcome is too.
Power: the same test on a specimen with one parameter perturbed must give p < 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.kernels import kernel_counts, on_one_and_all_threads
from tests.helpers.stats import family_rate, two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_kernel_for
from virtual.specimens import parse_specimen

N = 400_000
PSA = Collector("equal-psa", 9, 24)
CONICAL, COLLIMATED = Beam("conical"), Beam("collimated")
LAMBERT = "lambert:reflectance=0.6,transmittance=0.3"

# (spec, beam, collector, theta_i) per kernel: every family the kernel takes, at normal, oblique,
# grazing incidence and from below (two-sided specimens, total internal reflection)
CASES = {
    "block": [
        (LAMBERT, CONICAL, PSA, 35.0),
        (LAMBERT, COLLIMATED, Collector("equal-angle", 6, 12), 35.0),
        ("ggx:alpha=0.2,eta=0.2,k=3", CONICAL, PSA, 35.0),
        ("ggx:alpha=0.05,eta=1.5,k=0", COLLIMATED, Collector("equal-solid-angle", 12, 16), 35.0),
        ("aniso-ggx:alpha_x=0.4,alpha_y=0.1,eta=1.5,k=0", Beam("conical", disk_sampling="polar"), PSA, 35.0),
        ("phong:exponent=20", CONICAL, PSA, 35.0),
        ("phong:exponent=3,kd=0.2,ks=0.6", COLLIMATED, PSA, 70.0),
        ("oren-nayar:sigma=30,albedo=0.7", CONICAL, PSA, 35.0),
        ("oren-nayar:sigma=10", COLLIMATED, PSA, 0.0),
        ("dielectric:alpha=0.2,eta=1.5", CONICAL, PSA, 35.0),
        ("dielectric:alpha=0.3,eta=1.5", COLLIMATED, PSA, 150.0),  # from inside: total internal reflection
        ("plastic", CONICAL, PSA, 35.0),
        ("plastic:alpha=0.3,eta=1.9", COLLIMATED, PSA, 160.0),  # from below (two-sided), a strong Fresnel
    ],
    "block32": [
        (LAMBERT, CONICAL, PSA, 35.0),
        ("lambert:albedo=0.8", COLLIMATED, Collector("equal-angle", 6, 12), 160.0),
        ("ggx:alpha=0.2,eta=0.2,k=3", CONICAL, PSA, 35.0),
        ("ggx:alpha=0.05,eta=1.5,k=0", COLLIMATED, Collector("equal-solid-angle", 12, 16), 75.0),
        ("ggx:alpha=0.3,eta=1.5,k=0", CONICAL, PSA, 150.0),  # from below
        ("aniso-ggx:alpha_x=0.4,alpha_y=0.1,eta=1.5,k=0", CONICAL, PSA, 35.0),
        ("phong:exponent=20", CONICAL, PSA, 35.0),
        ("phong:exponent=3,kd=0.2,ks=0.6", COLLIMATED, PSA, 160.0),  # from below (two-sided), a wide lobe
        ("phong:exponent=500,kd=0.1,ks=0.8", COLLIMATED, PSA, 80.0),  # grazing: much of the lobe below the horizon
        ("oren-nayar:sigma=30,albedo=0.7", CONICAL, PSA, 35.0),
        ("oren-nayar:sigma=10", COLLIMATED, PSA, 0.0),  # normal incidence: no azimuth of incidence
        ("oren-nayar:sigma=40,albedo=0.6", COLLIMATED, PSA, 100.0),  # from below, grazing
        ("dielectric:alpha=0.2,eta=1.5", CONICAL, PSA, 35.0),
        ("dielectric:alpha=0.3,eta=1.5,masking=separable", COLLIMATED, PSA, 150.0),  # from inside: TIR
        ("plastic", CONICAL, PSA, 35.0),
        ("plastic:alpha=0.3,eta=1.9", COLLIMATED, PSA, 160.0),  # from below (two-sided), a strong Fresnel
    ],
}
AGREE = [(kernel, *case) for kernel, cases in CASES.items() for case in cases]
FAMILY = 1e-3
EACH = -np.expm1(np.log1p(-FAMILY) / len(AGREE))  # Sidak: 1 - (1 - FAMILY)^(1/m), about 3.4e-5

# (kernel, spec, perturbed spec, rays): the perturbation each comparison must detect
PERTURBED = [
    ("block", "ggx:alpha=0.2,eta=0.2,k=3", "ggx:alpha=0.22,eta=0.2,k=3", N),
    ("block", "phong:exponent=20", "phong:exponent=23", N),
    ("block", "oren-nayar:sigma=30,albedo=0.7", "oren-nayar:sigma=40,albedo=0.7", N),
    ("block", "dielectric:alpha=0.2,eta=1.5", "dielectric:alpha=0.2,eta=1.6", N),
    ("block", "plastic", "plastic:eta=1.6", N),
    ("block32", "ggx:alpha=0.2,eta=0.2,k=3", "ggx:alpha=0.22,eta=0.2,k=3", 1_000_000),
    ("block32", LAMBERT, "lambert:reflectance=0.6,transmittance=0.31", 1_000_000),
    ("block32", "phong:exponent=20", "phong:exponent=23", N),
    ("block32", "oren-nayar:sigma=30,albedo=0.7", "oren-nayar:sigma=40,albedo=0.7", N),
    ("block32", "dielectric:alpha=0.2,eta=1.5", "dielectric:alpha=0.2,eta=1.6", N),
    ("block32", "plastic", "plastic:eta=1.6", N),
]


def test_the_stated_family_wise_rate_is_the_one_run():
    assert family_rate(EACH, len(AGREE)) == pytest.approx(FAMILY, rel=1e-9)


def _runs_on(kernel, spec, beam):
    """The kernel ``auto`` picks is block32 wherever block32 is tested; float64 block stays
    available on request for every family."""
    sp = parse_specimen(spec)
    if kernel == "block32":
        return gonio_kernel_for(sp.model, beam.disk_code, params=sp.params(550.0)) == "block32"
    return gonio_kernel_for(sp.model, beam.disk_code, "block") == "block"


@pytest.mark.parametrize("kernel, spec, beam, col, theta", AGREE)
def test_block_and_ray_kernels_count_the_same_distribution(kernel, spec, beam, col, theta):
    assert _runs_on(kernel, spec, beam)
    a = kernel_counts(spec, beam, col, N, 31, kernel, theta=theta)
    b = kernel_counts(spec, beam, col, N, 32, "ray", theta=theta)
    assert a.sum() == b.sum() == N
    assert two_sample_p(a, b) > EACH


@pytest.mark.parametrize("kernel, spec, other, n", PERTURBED)
def test_the_comparison_has_power_against_a_perturbed_parameter(kernel, spec, other, n):
    a = kernel_counts(spec, CONICAL, PSA, n, 31, kernel)
    b = kernel_counts(other, CONICAL, PSA, n, 32, "ray")
    assert two_sample_p(a, b) < 1e-6


@pytest.mark.parametrize("kernel", ["block", "block32"])
@pytest.mark.parametrize("spec, n, other_seed_differs", [("ggx:alpha=0.3", 3 * (1 << 20) + 5, True),
                                                         ("plastic:eta=1.9", 3 * (1 << 20) + 7, False)])
def test_counts_do_not_depend_on_the_thread_count(kernel, spec, n, other_seed_differs):
    """Several chunks; the plastic's rejection fallback draws from a float64 stream of its own."""
    one, many = on_one_and_all_threads(lambda: kernel_counts(spec, CONICAL, PSA, n, 3, kernel))
    np.testing.assert_array_equal(one, many)
    if other_seed_differs:
        assert not np.array_equal(kernel_counts(spec, CONICAL, PSA, n, 4, kernel), one)
