"""Block-kernel ("given uniforms") forms of the specimens that need four or more uniforms per ray.

Each function takes the uniforms a ray needs and returns ``(ox, oy, oz, alive)`` without
branching on data, so the block kernel's loops vectorize: the rough dielectric in four uniforms
(:func:`scatter_given4`; Phong and Oren-Nayar are laws of :mod:`virtual.kernels.laws`), the rough
plastic in seven (:func:`plastic_given`) with the rare rejected diffuse rays finished by
:func:`plastic_diffuse_redo` on a per-chunk scalar stream. Each is the ray-by-ray branch of
:mod:`virtual.kernels.scatter` with its random draws made explicit (tested against it by
two-sample chi-square, tests/test_block_families.py).
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.ggx import g2_over_g1_masked_ratio, g2_over_g1_ratio, ggx_n, ggx_vndf_given
from virtual.kernels.microfacet import fresnel_dielectric, unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernels.warps import sincos_2pi, warp_cosine_hemisphere

__all__ = ["GIVEN4_MODELS", "GIVEN4_UNIFORMS", "scatter_given4", "PLASTIC_UNIFORMS", "plastic_given",
           "plastic_diffuse_redo"]


from virtual.kernel_codes import GIVEN4_MODELS, GIVEN4_UNIFORMS


@jit(inline="llvm")
def _dielectric_given(p, wx, wy, wz, u0, u1, u2, u3):
    """:func:`_dielectric` given its uniforms: the visible normal from (u1, u2), reflection when
    u0 < F (else refraction), surviving with probability G2/G1 by u3."""
    a = p[0]
    flip = wz < 0.0
    wz = abs(wz)
    er = 1.0 / p[1] if flip else p[1]
    ni = ggx_n(wx, wy, wz, a, a)
    ca, sa = sincos_2pi(u1)
    mx, my, mz = ggx_vndf_given(wx, wy, wz, a, a, 1.0 / ni, ca, sa, u2)
    c = max(wx * mx + wy * my + wz * mz, 0.0)
    f, ct = fresnel_dielectric(c, er)
    refl = u0 < f
    inv = 1.0 / er
    k = c * inv - ct
    ox = 2.0 * c * mx - wx if refl else -wx * inv + k * mx
    oy = 2.0 * c * my - wy if refl else -wy * inv + k * my
    oz = 2.0 * c * mz - wz if refl else -wz * inv + k * mz
    az = oz if refl else -oz
    g_num, g_den = g2_over_g1_masked_ratio(wz, ni, az, ggx_n(ox, oy, az, a, a), p[2])
    alive = (wz > 0.0) & (az > 0.0) & (u3 * g_den < g_num)
    return ox, oy, (-oz if flip else oz), alive


@jit(inline="llvm")
def scatter_given4(model, p, wx, wy, wz, u0, u1, u2, u3):
    """:func:`scatter` for the :data:`GIVEN4_MODELS`, with four uniforms given: the same
    distribution of ``(ox, oy, oz, alive)``, no branch (callers pass a constant ``model``)."""
    return _dielectric_given(p, wx, wy, wz, u0, u1, u2, u3)


# --- rough plastic for the block kernel (float32 and float64) --------------------------------------
#: Uniforms :func:`plastic_given` consumes per ray.
PLASTIC_UNIFORMS = 7


@jit(inline="llvm")
def plastic_given(p, wx, wy, wz, u0, u1, u2, u3, u4, u5, u6):
    """:func:`_plastic` with its uniforms given and one attempt of the diffuse lobe's rejection
    loop: ``(ox, oy, oz, alive, redo)``. ``redo`` marks a diffuse ray whose one attempt was
    rejected: its direction must come from :func:`plastic_diffuse_redo` (the loop continued,
    which -- attempts being independent -- gives exactly the loop's law); ``oz`` then carries
    only the side (+-1).

    u0 < F picks the specular reflection (visible normal from (u1, u2), survival G2/G1 by u3);
    otherwise u0 is uniform on [F, 1), so u0 - F < kd (1 - F) is the diffuse survival with
    probability kd, no new uniform; the diffuse attempt is Malley's direction from (u4, u5),
    accepted when u6 >= F(cos theta_o).
    """
    flip = wz < 0.0
    wz = abs(wz)
    a = p[0]
    eta = p[1]
    ni = ggx_n(wx, wy, wz, a, a)
    ca, sa = sincos_2pi(u1)
    mx, my, mz = ggx_vndf_given(wx, wy, wz, a, a, 1.0 / ni, ca, sa, u2)
    c = max(wx * mx + wy * my + wz * mz, 0.0)
    f, _ = fresnel_dielectric(c, eta)
    spec = u0 < f
    sx = 2.0 * c * mx - wx
    sy = 2.0 * c * my - wy
    sz = 2.0 * c * mz - wz
    g_num, g_den = g2_over_g1_ratio(wz, ni, sz, ggx_n(sx, sy, sz, a, a))
    spec_ok = (sz > 0.0) & (u3 * g_den < g_num)
    dx, dy, dz = warp_cosine_hemisphere(u5, u4)
    fo, _ = fresnel_dielectric(dz, eta)
    diffuse = (u0 >= f) & ((u0 - f) < p[2] * (1.0 - f))
    accepted = u6 >= fo
    ox = sx if spec else dx
    oy = sy if spec else dy
    oz = sz if spec else (dz if accepted else 1.0)
    ok = wz > 0.0
    alive = ok & ((spec & spec_ok) | (diffuse & accepted))
    redo = ok & diffuse & (u6 < fo)
    return ox, oy, (-oz if flip else oz), alive, redo


@jit(inline="llvm")
def plastic_diffuse_redo(eta, s):
    """The plastic's diffuse direction (cosine lobe thinned by 1 - F(cos theta_o)) drawn by
    rejection from the stream ``s``, upper hemisphere: the fallback of :func:`plastic_given`."""
    while True:
        ox, oy, r2 = unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        fo, _ = fresnel_dielectric(oz, eta)
        if next_double(s) >= fo:
            return ox, oy, oz


