"""The float32 block kernel's rough dielectric and rough plastic count the same
distribution as the float64 ray-by-ray kernel, the test can tell a slightly different specimen
apart, and the plastic's float64 fallback stream keeps the counts independent of the thread count.

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
from virtual.engine import float32_suits, gonio_kernel_for
from virtual.specimens import parse_specimen

N = 400_000
COL = Collector("equal-psa", 9, 24)

CASES = [
    ("dielectric:alpha=0.2,eta=1.5", Beam("conical"), 35.0),
    ("dielectric:alpha=0.3,eta=1.5,masking=separable", Beam("collimated"), 150.0),  # from inside: TIR
    ("plastic", Beam("conical"), 35.0),
    ("plastic:alpha=0.3,eta=1.9", Beam("collimated"), 160.0),  # from below (two-sided), a strong Fresnel
]

PERTURBED = [
    ("dielectric:alpha=0.2,eta=1.5", "dielectric:alpha=0.2,eta=1.6"),
    ("plastic", "plastic:eta=1.6"),
]


@pytest.mark.parametrize("spec, beam, theta", CASES)
def test_block32_and_ray_kernels_agree_for_the_rough_families(spec, beam, theta):
    sp = parse_specimen(spec)
    assert gonio_kernel_for(sp.model, beam.disk_code, params=sp.params(550.0)) == "block32"
    a = _gonio(spec, beam, COL, N, 41, "block32", theta=theta)
    b = _gonio(spec, beam, COL, N, 42, "ray", theta=theta)
    assert a.sum() == b.sum() == N
    assert _two_sample_p(a, b) > 1e-3


@pytest.mark.parametrize("spec, other", PERTURBED)
def test_the_block32_comparison_has_power_against_a_perturbed_parameter(spec, other):
    a = _gonio(spec, Beam("conical"), COL, N, 41, "block32")
    b = _gonio(other, Beam("conical"), COL, N, 42, "ray")
    assert _two_sample_p(a, b) < 1e-6


def test_float32_is_chosen_only_for_resolvable_rough_specimens():
    for spec in ("dielectric:alpha=0.005", "plastic:alpha=0.005"):  # too narrow a lobe for float32
        sp = parse_specimen(spec)
        assert gonio_kernel_for(sp.model, Beam("conical").disk_code, params=sp.params(550.0)) == "block"
    sp = parse_specimen("plastic")
    p = sp.params(550.0).copy()
    assert float32_suits(sp.model, p)
    p[1] = 20.0  # an index beyond MAX_ETA
    assert not float32_suits(sp.model, p)


def test_block32_plastic_counts_do_not_depend_on_the_thread_count():
    n = 3 * (1 << 20) + 7
    one, many = on_one_and_all_threads(lambda: _gonio("plastic:eta=1.9", Beam("conical"), COL, n, 5, "block32"))
    np.testing.assert_array_equal(one, many)
