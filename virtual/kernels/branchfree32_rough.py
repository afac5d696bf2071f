"""Float32 forms of the rough dielectric and the rough plastic for the 16-lane block kernel
(:mod:`virtual.kernels.block32`).

Each is its float64 given form (:func:`~virtual.kernels.branchfree._dielectric_given`,
:func:`~virtual.kernels.branchfree.plastic_given`) with the same uniforms in the same roles, written
with the float32 helpers of :mod:`virtual.kernels.f32` (the branch-free
:func:`~virtual.kernels.f32.fresnel_dielectric32` among them): the same law of the outputs up to
float32 rounding, tested against the float64 ray-by-ray kernel by two-sample chi-square
(tests/test_block_families.py), each with the ``doubt`` flag of :mod:`virtual.kernels.branchfree32`.
Parameters ``p`` are a tuple of float32. The plastic's
rare rejected diffuse rays are finished in float64 by
:func:`~virtual.kernels.branchfree.plastic_diffuse_redo`, as in the float64 block kernel.
"""

from __future__ import annotations

from virtual.kernels import jit
from virtual.kernels.f32 import ONE, TWO, ZERO, fresnel_dielectric32, in_doubt32, warp_cosine_hemisphere32
from virtual.kernels.ggx32 import g2_over_g1_masked_ratio as g2_over_g1_masked_ratio32, ggx_n as ggx_n32

__all__ = ["DIELECTRIC32_UNIFORMS", "PLASTIC32_UNIFORMS", "dielectric_about32", "plastic_diffuse32", "plastic_about32"]

#: Uniforms the rough dielectric consumes per ray (u0-u3, :func:`dielectric_about32`).
DIELECTRIC32_UNIFORMS = 4
#: Uniforms the rough plastic consumes per ray (u0-u6, :func:`plastic_about32`).
PLASTIC32_UNIFORMS = 7


@jit(inline="llvm")
def dielectric_about32(p, wx, wy, wz, mx, my, mz, ni, u0, u3):
    """Rough dielectric (``p`` = alpha, eta, separable) from the visible normal of |w|
    (:func:`~virtual.kernels.ggx.ggx_normal`'s float32 twin from (u1, u2)) on: reflection when u0 < F
    (else refraction; F = 1 on total internal reflection), surviving with probability G2/G1 by u3.
    From below the relative index is 1/eta."""
    a = p[0]
    flip = wz < ZERO
    wz = abs(wz)
    er = ONE / p[1] if flip else p[1]
    inv = p[1] if flip else ONE / p[1]
    c = max(wx * mx + wy * my + wz * mz, ZERO)
    f, ct = fresnel_dielectric32(c, er)
    refl = u0 < f
    k = c * inv - ct
    ox = TWO * c * mx - wx if refl else k * mx - wx * inv
    oy = TWO * c * my - wy if refl else k * my - wy * inv
    oz = TWO * c * mz - wz if refl else k * mz - wz * inv
    az = oz if refl else -oz  # the cosine on the side the ray leaves to
    g_num, g_den = g2_over_g1_masked_ratio32(wz, ni, az, ggx_n32(ox, oy, az, a, a), p[2])
    alive = (wz > ZERO) & (az > ZERO) & (u3 * g_den < g_num)
    doubt = in_doubt32(u0, f, ONE) | in_doubt32(u3, g_num, g_den)
    return ox, oy, (-oz if flip else oz), alive, doubt


@jit(inline="llvm")
def plastic_diffuse32(p, u4, u5):
    """The diffuse attempt of :func:`plastic_about32`, which does not depend on w: Malley's direction
    from (u4, u5) and F at its cosine, ``(dx, dy, dz, fo)``."""
    dx, dy, dz = warp_cosine_hemisphere32(u5, u4)
    fo, _ = fresnel_dielectric32(dz, p[1])
    return dx, dy, dz, fo


@jit(inline="llvm")
def plastic_about32(p, wx, wy, wz, mx, my, mz, ni, dx, dy, dz, fo, u0, u3, u6):
    """Rough plastic (``p`` = alpha, eta, kd), two-sided, one attempt of the diffuse lobe's
    rejection loop: ``(ox, oy, oz, alive, redo, doubt)``, ``redo`` marking a rejected diffuse ray
    (``oz`` then only its side, +-1) whose direction the float64 ``plastic_diffuse_redo`` draws.
    u0 < F: specular (visible normal from (u1, u2), G2/G1 by u3); else u0 - F < kd (1 - F) is
    the diffuse survival; the attempt is Malley's direction from (u4, u5), kept when
    u6 >= F(cos theta_o).
    From the visible normal of |w| (:func:`~virtual.kernels.ggx.ggx_normal`'s float32 twin from (u1,
    u2)) and the diffuse attempt (:func:`plastic_diffuse32` from (u4, u5)) on."""
    flip = wz < ZERO
    wz = abs(wz)
    a = p[0]
    eta = p[1]
    c = max(wx * mx + wy * my + wz * mz, ZERO)
    f, _ = fresnel_dielectric32(c, eta)
    spec = u0 < f
    sx = TWO * c * mx - wx
    sy = TWO * c * my - wy
    sz = TWO * c * mz - wz
    g_num, g_den = g2_over_g1_masked_ratio32(wz, ni, sz, ggx_n32(sx, sy, sz, a, a), ZERO)
    spec_ok = (sz > ZERO) & (u3 * g_den < g_num)
    diffuse = (u0 >= f) & ((u0 - f) < p[2] * (ONE - f))
    accepted = u6 >= fo
    ox = sx if spec else dx
    oy = sy if spec else dy
    oz = sz if spec else (dz if accepted else ONE)
    ok = wz > ZERO
    alive = ok & ((spec & spec_ok) | (diffuse & accepted))
    redo = ok & diffuse & (u6 < fo)
    doubt = (in_doubt32(u0, f, ONE) | in_doubt32(u0, f + p[2] * (ONE - f), ONE) | in_doubt32(u3, g_num, g_den)
             | in_doubt32(u6, fo, ONE))
    return ox, oy, (-oz if flip else oz), alive, redo, doubt
