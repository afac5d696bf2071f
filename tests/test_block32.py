"""The float32 block kernel's parts: its generator against the published xoshiro128+,
its bin guess against the exact float64 lookup, its float32 functions against float64 ones, and
the rule that sends a specimen to float32 only when float32 resolves it. Its counts against the
ray-by-ray kernel's: tests/test_block_families.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import float32_suits, gonio_kernel_for
from virtual.kernels import jit
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels.f32 import ATAN32_MAX_ERROR, MAX_PHONG_EXPONENT, _atan_first_quadrant32, guess_bin32
from virtual.kernels.branchfree32 import phong_lobe_omc32
from virtual.kernels.xoshiro import fill_uniforms32
from virtual.rng import lane_states32
from virtual.specimens import parse_specimen


# --- the generator ------------------------------------------------------------------------------------

def _xoshiro128plus(state: list[int], n: int) -> list[int]:
    """Blackman & Vigna's xoshiro128+ (prng.di.unimi.it/xoshiro128plus.c), in Python integers."""
    s, out, m = list(state), [], 0xFFFFFFFF
    for _ in range(n):
        out.append((s[0] + s[3]) & m)
        t = (s[1] << 9) & m
        s[2] ^= s[0]
        s[3] ^= s[1]
        s[1] ^= s[2]
        s[0] ^= s[3]
        s[2] ^= t
        s[3] = ((s[3] << 11) | (s[3] >> 21)) & m
    return out


def test_float32_uniforms_are_the_top_24_bits_of_the_published_xoshiro128plus():
    lanes = lane_states32(7, 1)[0]
    start = lanes.copy()
    out = np.empty((40, lanes.shape[1]), dtype=np.float32)
    fill_uniforms32(lanes, out)
    for lane in (0, 1, 17, 63):
        ref = [(r >> 8) * 2.0 ** -24 for r in _xoshiro128plus([int(v) for v in start[:, lane]], 40)]
        np.testing.assert_array_equal(out[:, lane], np.array(ref, dtype=np.float32))
    assert not np.array_equal(lanes, start)  # advanced in place


def test_float32_uniforms_lie_in_the_unit_interval_and_are_uniform():
    from scipy import stats

    lanes = lane_states32(3, 1)[0]
    out = np.empty((4096, lanes.shape[1]), dtype=np.float32)
    fill_uniforms32(lanes, out)
    u = out.ravel()
    assert u.min() >= 0.0 and u.max() < 1.0
    counts = np.bincount((u * 64).astype(np.int64), minlength=64)
    assert stats.chisquare(counts).pvalue > 1e-3  # a uniform fails once in 1000


# --- the bin guess ------------------------------------------------------------------------------------

@jit(error_model="numpy")
def _guesses(v, scheme, n_theta, n_phi, rm, sm, sin2_edges, phi_cs, guess, exact):
    for i in range(v.shape[0]):
        guess[i] = guess_bin32(v[i, 0], v[i, 1], v[i, 2], scheme, n_theta, n_phi, rm, sm)
        exact[i] = patch_of(np.float64(v[i, 0]), np.float64(v[i, 1]), np.float64(v[i, 2]), scheme, n_theta, n_phi,
                            sin2_edges, phi_cs)


def _directions_near_edges(col: Collector, n: int, rng: np.random.Generator) -> np.ndarray:
    """float32 directions on and within a few float32 ulps of every ring and sector edge, at the
    pole and the horizon, plus uniform ones; both hemispheres."""
    theta = np.radians(col.theta_edges_deg)
    phi = np.radians(col.phi_edges_deg)
    t = rng.choice(theta, n) * (1 + rng.integers(-8, 9, n) * 2.0 ** -23)
    p = rng.choice(phi, n) + rng.integers(-8, 9, n) * 2.0 ** -22
    half = n // 2
    t[half:] = np.arccos(rng.random(n - half))
    p[half:] = rng.random(n - half) * 2 * np.pi
    v = np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    v[rng.random(n) < 0.5, 2] *= -1
    v *= rng.uniform(0.5, 2.0, (n, 1))  # the guess takes any length
    return v.astype(np.float32)


@pytest.mark.parametrize("scheme, n_theta, n_phi", [("equal-psa", 30, 30), ("equal-angle", 18, 36),
                                                    ("equal-solid-angle", 9, 24), ("equal-psa", 90, 180)])
def test_the_float32_guess_is_the_exact_bin_or_declines(scheme, n_theta, n_phi):
    col = Collector(scheme, n_theta, n_phi)
    rng = np.random.default_rng(n_theta * n_phi)
    v = _directions_near_edges(col, 400_000, rng)
    code, nt, nph, s2e, pcs = col.kernel_args()
    rm, sm = col.guess_margins32()
    guess = np.empty(v.shape[0], dtype=np.int64)
    exact = np.empty(v.shape[0], dtype=np.int64)
    _guesses(v, code, nt, nph, rm, sm, s2e, pcs, guess, exact)
    sure = guess >= 0
    np.testing.assert_array_equal(guess[sure], exact[sure])
    # power: the same directions without margins are binned wrongly (the test sees edges)
    _guesses(v, code, nt, nph, np.float32(0.0), np.float32(0.0), s2e, pcs, guess, exact)
    assert ((guess >= 0) & (guess != exact)).sum() > 100
    # the uniform half: the exact lookup is rarely needed (the margins are tight)
    assert (~sure[v.shape[0] // 2:]).mean() < 5e-3


def test_the_float32_atan_keeps_its_stated_error():
    @jit(error_model="numpy")
    def atan_many(y, x, out):
        for i in range(y.shape[0]):
            out[i] = _atan_first_quadrant32(y[i], x[i])

    rng = np.random.default_rng(5)
    y = rng.random(1_000_000).astype(np.float32)
    x = rng.random(1_000_000).astype(np.float32)
    y[:1000], x[:1000] = np.float32(1.0), np.linspace(0, 1, 1000, dtype=np.float32)
    out = np.empty_like(y)
    atan_many(y, x, out)
    err = np.abs(out.astype(np.float64) - np.arctan2(y.astype(np.float64), x.astype(np.float64)))
    assert err.max() < ATAN32_MAX_ERROR


# --- which specimens float32 takes -------------------------------------------------------------------

def test_float32_takes_only_specimens_it_resolves():
    conical = Beam("conical").disk_code
    for spec in ("lambert:albedo=0.5", "ggx:alpha=0.2", "aniso-ggx:alpha_x=0.3,alpha_y=0.05"):
        sp = parse_specimen(spec)
        assert float32_suits(sp.model, sp.params(550.0)), spec
    for spec in ("ggx:alpha=0.001", "aniso-ggx:alpha_x=0.3,alpha_y=0.005"):  # lobes float32 would blur
        sp = parse_specimen(spec)
        assert not float32_suits(sp.model, sp.params(550.0)), spec
        assert gonio_kernel_for(sp.model, conical, params=sp.params(550.0)) == "block"
    sp = parse_specimen("ggx:alpha=0.2")
    assert not float32_suits(sp.model, np.array([0.2, 0.2, math.inf, 0.0, 0.0]))
    assert gonio_kernel_for(sp.model, conical) == "block"  # without parameters: never float32
    rejection = Beam("conical", disk_sampling="rejection").disk_code
    assert gonio_kernel_for(sp.model, rejection, params=sp.params(550.0)) == "ray"
    with pytest.raises(ValueError, match="block32 kernel"):
        gonio_kernel_for(sp.model, rejection, "block32")


def test_float32_is_chosen_only_for_resolvable_rough_specimens():
    for spec in ("dielectric:alpha=0.005", "plastic:alpha=0.005"):  # too narrow a lobe for float32
        sp = parse_specimen(spec)
        assert gonio_kernel_for(sp.model, Beam("conical").disk_code, params=sp.params(550.0)) == "block"
    sp = parse_specimen("plastic")
    p = sp.params(550.0).copy()
    assert float32_suits(sp.model, p)
    p[1] = 20.0  # an index beyond MAX_ETA
    assert not float32_suits(sp.model, p)


# --- float32 functions against float64 ------------------------------------------------------------

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


def test_the_k_zero_fresnel_form_is_the_general_one_at_k_zero():
    """The block kernel's isotropic k = 0 GGX loop takes a^2 + b^2 = |t0| and a = sqrt(max(t0, 0)):
    the same factor as the general conductor form at k = 0 (total internal reflection, eta < 1,
    included), to float32 rounding -- and within 2e-5 of the float64 form, except where F ~
    sqrt(t0) at the critical angle of eta < 1 amplifies t0's rounding (2e-4, |c - c_crit| < 1e-3)."""
    from virtual.kernels.ggx import fresnel_conductor_ratio
    from virtual.kernels.ggx32 import fresnel_conductor_ratio as fresnel_conductor_ratio32

    @jit(error_model="numpy")
    def both(c, eta, out):
        for i in range(c.shape[0]):
            a, b = fresnel_conductor_ratio32(c[i], eta, np.float32(0.0), True)
            g, h = fresnel_conductor_ratio32(c[i], eta, np.float32(0.0), False)
            out[i, 0] = a / b
            out[i, 1] = g / h

    c = np.linspace(0.0, 1.0, 20_001).astype(np.float32)
    c[0] = np.float32(1e-4)
    for eta in (0.5, 0.9, 1.0, 1.5, 3.0):
        out = np.empty((c.size, 2), dtype=np.float32)
        both(c, np.float32(eta), out)
        ref = np.array([np.divide(*fresnel_conductor_ratio(float(x), eta, 0.0, False)) for x in c])
        np.testing.assert_allclose(out[:, 0], out[:, 1], rtol=2e-5, atol=2e-6)
        err = np.abs(out[:, 0] - ref)
        assert err.max() < 2e-4
        near = np.abs(c - math.sqrt(max(1.0 - eta * eta, 0.0))) < 1e-3 if eta < 1 else np.zeros(c.size, bool)
        assert (err[~near] < 2e-5 + 2e-5 * ref[~near]).all()
