"""The block kernel's four-uniform families (Phong, Oren-Nayar, rough dielectric) and the rough
plastic (seven uniforms and a rejection fallback) count
the same distribution as the ray-by-ray kernel, and the test can tell a slightly different
specimen apart.

Each comparison is a two-sample chi-square over the collector bins plus absorbed and missed
(two independent multinomial samples of equal size): under equal distributions its p-value is
uniform, so the threshold p > 1e-3 fails a correct kernel once in 1000 (seeds are fixed, so the
outcome is too). Power: the same test with one parameter perturbed must give p < 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_engine import _gonio, _two_sample_p, on_one_and_all_threads
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_kernel_for
from virtual.specimens import parse_specimen

N = 400_000
COL = Collector("equal-psa", 9, 24)

CASES = [
    ("phong:exponent=20", Beam("conical"), 35.0),
    ("phong:exponent=3,kd=0.2,ks=0.6", Beam("collimated"), 70.0),
    ("oren-nayar:sigma=30,albedo=0.7", Beam("conical"), 35.0),
    ("oren-nayar:sigma=10", Beam("collimated"), 0.0),
    ("dielectric:alpha=0.2,eta=1.5", Beam("conical"), 35.0),
    ("dielectric:alpha=0.3,eta=1.5", Beam("collimated"), 150.0),  # from inside: total internal reflection
    ("plastic", Beam("conical"), 35.0),
    ("plastic:alpha=0.3,eta=1.9", Beam("collimated"), 160.0),  # from below (two-sided), a strong Fresnel
]

PERTURBED = [
    ("phong:exponent=20", "phong:exponent=23"),
    ("oren-nayar:sigma=30,albedo=0.7", "oren-nayar:sigma=40,albedo=0.7"),
    ("dielectric:alpha=0.2,eta=1.5", "dielectric:alpha=0.2,eta=1.6"),
    ("plastic", "plastic:eta=1.6"),
]


@pytest.mark.parametrize("spec, beam, theta", CASES)
def test_block_and_ray_kernels_agree_for_the_four_uniform_families(spec, beam, theta):
    assert gonio_kernel_for(parse_specimen(spec).model, beam.disk_code, "block") == "block"  # float64 still available
    a = _gonio(spec, beam, COL, N, 31, "block", theta=theta)
    b = _gonio(spec, beam, COL, N, 32, "ray", theta=theta)
    assert a.sum() == b.sum() == N
    assert _two_sample_p(a, b) > 1e-3


@pytest.mark.parametrize("spec, other", PERTURBED)
def test_the_comparison_has_power_against_a_perturbed_parameter(spec, other):
    a = _gonio(spec, Beam("conical"), COL, N, 31, "block")
    b = _gonio(other, Beam("conical"), COL, N, 32, "ray")
    assert _two_sample_p(a, b) < 1e-6


def test_block_counts_with_a_rejection_fallback_do_not_depend_on_the_thread_count():
    n = 3 * (1 << 20) + 7
    one, many = on_one_and_all_threads(lambda: _gonio("plastic:eta=1.9", Beam("conical"), COL, n, 5, "block"))
    np.testing.assert_array_equal(one, many)
