"""The float32 GGX survival step for the 16-lane block kernel (:mod:`virtual.kernels.block32`;
GGX's visible normal, reflection and Fresnel factor are the float32 twin of
:mod:`virtual.kernels.ggx`, written once for both precisions), and Phong's lobe cosine (the
float32 prepass of its law, :mod:`virtual.kernels.laws.phong`).

Each is the float64 given form (:func:`~virtual.kernels.scatter.scatter_given`,
:mod:`virtual.kernels.branchfree`) with the same uniforms in the same roles, written with the
float32 helpers of :mod:`virtual.kernels.f32`: the same law of ``(ox, oy, oz, alive)`` up to
float32 rounding -- each also returns ``doubt``, whether one of its decisions is too near its
threshold for a grid uniform (:func:`~virtual.kernels.f32.in_doubt32`; the block kernel then
decides the ray again in float64) (tested against the float64 ray-by-ray kernel by two-sample chi-square,
tests/test_block_families.py). Parameters ``p`` are a tuple of float32.
"""

from __future__ import annotations

import math

import numpy as np
from numba import int32

from virtual.kernels import jit
from virtual.kernels.f32 import DOUBT, F, HALF, ONE, ZERO
from virtual.kernels.ggx32 import fresnel_conductor_ratio as fresnel_conductor_ratio32, ggx_reflect as ggx_reflect32

__all__ = ["ggx_finish32", "phong_lobe_omc32"]

_LN2 = F(math.log(2.0))
_LOG2E = F(1.0 / math.log(2.0))
_L3, _L5, _L7, _L9 = F(1.0 / 3.0), F(1.0 / 5.0), F(1.0 / 7.0), F(1.0 / 9.0)  # 2 atanh(s) / (2 s) in s^2
_E2, _E3, _E4 = F(1.0 / 2.0), F(1.0 / 6.0), F(1.0 / 24.0)  # expm1(r) / r in r: 1/k!
_E5, _E6, _E7 = F(1.0 / 120.0), F(1.0 / 720.0), F(1.0 / 5040.0)
_MANT, _SQRT2_MANT = np.int32(0x7FFFFF), np.int32(0x3504F3)  # float32 mantissa bits; those of sqrt(2)
_HALF_BITS, _ONE_BITS = np.int32(0x3F000000), np.int32(0x3F800000)  # exponent bits of 0.5 and 1
_BIAS, _MIN_EXP, _SHIFT = np.int32(127), np.int32(-126), np.int32(23)


@jit(inline="llvm")
def ggx_finish32(p, wx, wy, wz, mx, my, mz, ni, u0, plain):
    """GGX reflection from its visible normal (:func:`~virtual.kernels.ggx.ggx_normal`'s float32
    twin) on, surviving with probability F G2/G1 by u0 (``p`` = alpha_x, alpha_y, eta, k,
    separable): ``(ox, oy, oz, alive, doubt)``. ``plain`` (a literal) says isotropic,
    height-correlated and k = 0 (a dielectric's Fresnel factor: one square root fewer).

    The float64 survival test (:func:`~virtual.kernels.scatter._ggx_given`) is the same
    decision in another association: ``(u f_den) g_den`` there, ``u (f_den g_den)`` here, the
    product the doubt test reuses. One text for both would move one path's pinned counts, so
    this step stays per precision."""
    ox, oy, oz, c, g_num, g_den, valid = ggx_reflect32(p[0], p[1], p[4], wx, wy, wz, mx, my, mz, ni, plain)
    f_num, f_den = fresnel_conductor_ratio32(c, p[2], p[3], plain)
    den = f_den * g_den
    excess = u0 * den - f_num * g_num  # < 0: survives; within DOUBT den of 0: in doubt (in_doubt32)
    return ox, oy, oz, valid & (excess < ZERO), abs(excess) <= DOUBT * den


@jit(error_model="numpy")
def phong_lobe_omc32(p, u, ibuf, out):
    """``out[i]`` = 1 - cos(alpha) = -expm1(ln(u[i]) / (n+1)) of Phong's cos^n lobe (n = p[2]),
    to a relative 3e-7 at any n (1 - powf(u, 1/(n+1)) loses it all where cos(alpha) rounds to 1:
    a relative 2e-4 on average at n = 1000). Three branch-free loops with float32 polynomials
    (``powf`` does not vectorize; ``ibuf`` is int32 scratch of out's size): ln u from the bits
    of u (u = 2^k m, m in [sqrt(1/2), sqrt(2)), ln m = 2 atanh((m-1)/(m+1)), series to s^9),
    exp(y) = 2^j (1 + expm1(r)), |r| <= ln(2)/2, series to r^7 (both truncations < 1e-8)."""
    n = out.shape[0]
    e = ONE / (p[2] + ONE)
    bits = u.view(np.int32)
    fbuf = ibuf.view(np.float32)
    for i in range(n):  # the bits of u: m into ibuf (read as float32), k into out
        b = bits[i]
        mant = b & _MANT
        big = mant > _SQRT2_MANT
        ibuf[i] = mant | (_HALF_BITS if big else _ONE_BITS)
        out[i] = F((b >> _SHIFT) - _BIAS + int32(big))
    for i in range(n):  # y = e ln u = j ln 2 + r: 2^j into ibuf (as bits), expm1(r) into out
        m = fbuf[i]
        s = (m - ONE) / (m + ONE)
        s2 = s * s
        y = e * (out[i] * _LN2 + (s + s) * (ONE + s2 * (_L3 + s2 * (_L5 + s2 * (_L7 + s2 * _L9)))))
        j = np.floor(y * _LOG2E + HALF)
        r = y - j * _LN2
        out[i] = r * (ONE + r * (_E2 + r * (_E3 + r * (_E4 + r * (_E5 + r * (_E6 + r * _E7))))))
        ibuf[i] = (max(int32(j), _MIN_EXP) + _BIAS) << _SHIFT
    for i in range(n):  # 1 - 2^j (1 + q): -q itself when j = 0 (no cancellation); u = 0 gives cos(alpha) = 0
        q = out[i]
        two_j = fbuf[i]
        omc = -q if two_j == ONE else ONE - two_j * (ONE + q)
        out[i] = ONE if u[i] == ZERO else omc
