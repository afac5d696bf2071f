"""Float32 forms of the specimens for the 16-lane block kernel (:mod:`virtual.kernels.block32`).

Each is the float64 given form (:func:`~virtual.kernels.scatter.scatter_given`,
:mod:`virtual.kernels.given`) with the same uniforms in the same roles, written with the
float32 helpers of :mod:`virtual.kernels.f32`: the same law of ``(ox, oy, oz, alive)`` up to
float32 rounding (tested against the float64 ray-by-ray kernel by two-sample chi-square,
tests/test_block32.py). Parameters ``p`` are a tuple of float32.
"""

from __future__ import annotations

from virtual.kernels import jit
from virtual.kernels.f32 import (ONE, TWO, ZERO, fresnel_conductor_ratio32, g2_over_g1_masked_ratio32, ggx_n32,
                                 ggx_vndf_given32, sincos_2pi32, warp_cosine_hemisphere32)

__all__ = ["lambert_given32", "ggx_given_parts32", "ggx_given32"]


@jit(inline="always")
def lambert_given32(p, wz, u0, u1, u2):
    """Lambertian: alive when u0 < R + T, reflected (source side) when u0 < R, the direction
    Malley's from (u1, u2)."""
    x, y, z = warp_cosine_hemisphere32(u2, u1)
    up = (wz >= ZERO) != (u0 >= p[0])
    return x, y, (z if up else -z), u0 < p[0] + p[1]


@jit(inline="always")
def ggx_given_parts32(ax, ay, separable, wx, wy, wz, ca, sa, r2):
    """:func:`~virtual.kernels.scatter.ggx_given_parts` in float32: ``(ox, oy, oz, c, g_num,
    g_den, valid)``."""
    flip = wz < ZERO
    wz = abs(wz)
    ni = ggx_n32(wx, wy, wz, ax, ay)
    mx, my, mz = ggx_vndf_given32(wx, wy, wz, ax, ay, ONE / ni, ca, sa, r2)
    c = max(wx * mx + wy * my + wz * mz, ZERO)
    ox = TWO * c * mx - wx
    oy = TWO * c * my - wy
    oz = TWO * c * mz - wz
    g_num, g_den = g2_over_g1_masked_ratio32(wz, ni, oz, ggx_n32(ox, oy, oz, ax, ay), separable)
    return ox, oy, (-oz if flip else oz), c, g_num, g_den, (wz > ZERO) & (oz > ZERO)


@jit(inline="always")
def ggx_given32(p, wx, wy, wz, u0, u1, u2):
    """GGX (isotropic or anisotropic) reflection, two-sided: the visible normal from the disk
    point (direction 2 pi u2, squared radius u1), surviving with probability F G2/G1 by u0
    (``p`` = alpha_x, alpha_y, eta, k, separable)."""
    ca, sa = sincos_2pi32(u2)
    ox, oy, oz, c, g_num, g_den, valid = ggx_given_parts32(p[0], p[1], p[4], wx, wy, wz, ca, sa, u1)
    f_num, f_den = fresnel_conductor_ratio32(c, p[2], p[3])
    return ox, oy, oz, valid & (u0 * f_den * g_den < f_num * g_num)
