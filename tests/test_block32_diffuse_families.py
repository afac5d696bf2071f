"""The float32 block kernel's Phong and Oren-Nayar count the same distribution as the
float64 ray-by-ray kernel, and the test can tell a slightly different specimen apart.

Each comparison is a two-sample chi-square over the collector bins plus absorbed and missed
(two independent multinomial samples of equal size): under equal distributions its p-value is
uniform, so the threshold p > 1e-3 fails a correct kernel once in 1000 (seeds are fixed, so the
outcome is too). Power: the same test with one parameter perturbed must give p < 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_engine import _gonio, _two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_kernel_for
from virtual.kernels.f32 import MAX_PHONG_EXPONENT
from virtual.kernels.branchfree32 import phong_lobe_omc32
from virtual.specimens import parse_specimen

N = 400_000
COL = Collector("equal-psa", 9, 24)

CASES = [
    ("phong:exponent=20", Beam("conical"), 35.0),
    ("phong:exponent=3,kd=0.2,ks=0.6", Beam("collimated"), 160.0),  # from below (two-sided), a wide lobe
    ("phong:exponent=500,kd=0.1,ks=0.8", Beam("collimated"), 80.0),  # grazing: much of the lobe below the horizon
    ("oren-nayar:sigma=30,albedo=0.7", Beam("conical"), 35.0),
    ("oren-nayar:sigma=10", Beam("collimated"), 0.0),  # normal incidence: no azimuth of incidence
    ("oren-nayar:sigma=40,albedo=0.6", Beam("collimated"), 100.0),  # from below, grazing
]

PERTURBED = [
    ("phong:exponent=20", "phong:exponent=23"),
    ("oren-nayar:sigma=30,albedo=0.7", "oren-nayar:sigma=40,albedo=0.7"),
]


@pytest.mark.parametrize("spec, beam, theta", CASES)
def test_block32_and_ray_kernels_agree_for_phong_and_oren_nayar(spec, beam, theta):
    sp = parse_specimen(spec)
    assert gonio_kernel_for(sp.model, beam.disk_code, "auto", sp.params(550.0)) == "block32"
    a = _gonio(spec, beam, COL, N, 31, "block32", theta=theta)
    b = _gonio(spec, beam, COL, N, 32, "ray", theta=theta)
    assert a.sum() == b.sum() == N
    assert _two_sample_p(a, b) > 1e-3


@pytest.mark.parametrize("spec, other", PERTURBED)
def test_the_block32_comparison_has_power_against_a_perturbed_parameter(spec, other):
    a = _gonio(spec, Beam("conical"), COL, N, 31, "block32")
    b = _gonio(other, Beam("conical"), COL, N, 32, "ray")
    assert _two_sample_p(a, b) < 1e-6


@pytest.mark.parametrize("n", [0.0, 1.0, 20.0, 1000.0, MAX_PHONG_EXPONENT, 1e7])
def test_phong_lobe_one_minus_cos_is_accurate_where_cos_rounds_to_one(n):
    """1 - cos(alpha) = -expm1(ln(u)/(n+1)) to a relative 1e-6 on every float32 uniform's kind
    (0, the smallest, near 1, a random 65536), where 1 - powf(u, 1/(n+1)) errs by up to 100 %."""
    rng = np.random.default_rng(7)
    u = np.concatenate([[0.0, 2.0 ** -24, 0.5, 1.0 - 2.0 ** -24, 1.0 - 2.0 ** -23],
                        rng.integers(0, 1 << 24, 65536) * 2.0 ** -24]).astype(np.float32)
    p = tuple(np.float32(x) for x in (0.3, 0.5, n, 0.5, 0.0, 0.0))
    out = np.empty(u.size, np.float32)
    phong_lobe_omc32(p, u, np.empty(u.size, np.int32), out)
    e = float(np.float32(1.0) / (p[2] + np.float32(1.0)))  # the kernel's float32 exponent
    with np.errstate(divide="ignore"):
        ref = np.where(u == 0.0, 1.0, -np.expm1(np.log(u.astype(np.float64)) * e))
    np.testing.assert_allclose(out, ref, rtol=1e-6, atol=0.0)
