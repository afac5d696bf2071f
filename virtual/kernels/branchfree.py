"""Block-kernel ("given uniforms") forms of the specimens that need four or more uniforms per ray.

Each function takes the uniforms a ray needs and returns ``(ox, oy, oz, alive)`` without
branching on data, so the block kernel's loops vectorize: the rough dielectric in four uniforms
(:func:`scatter_given4`; Phong and Oren-Nayar are laws of :mod:`virtual.kernels.laws`), the rough
plastic in seven (:func:`plastic_given`) with the rare rejected diffuse rays finished by
:func:`plastic_diffuse_redo` on a per-chunk scalar stream. Each is the ray-by-ray branch of
:mod:`virtual.kernels.scatter` with its random draws made explicit (tested against it by
two-sample chi-square, tests/test_block_families.py), made of the steps written once for both
precisions in :mod:`virtual.kernels.ggx`, whose float32 twins the float32 block kernel runs.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.ggx import dielectric_about, fresnel_dielectric, ggx_normal, plastic_about, plastic_diffuse
from virtual.kernels.microfacet import unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernels.warps import sincos_2pi

__all__ = ["GIVEN4_MODELS", "GIVEN4_UNIFORMS", "scatter_given4", "PLASTIC_UNIFORMS", "plastic_given",
           "plastic_diffuse_redo"]


from virtual.kernel_codes import GIVEN4_MODELS, GIVEN4_UNIFORMS


@jit(inline="llvm")
def _dielectric_given(p, wx, wy, wz, u0, u1, u2, u3):
    """:func:`_dielectric` given its uniforms: the visible normal from (u1, u2), reflection when
    u0 < F (else refraction), surviving with probability G2/G1 by u3:
    :func:`~virtual.kernels.ggx.ggx_normal` then :func:`~virtual.kernels.ggx.dielectric_about`,
    the relative index inverted as 1/er."""
    a = p[0]
    er = 1.0 / p[1] if wz < 0.0 else p[1]
    ca, sa = sincos_2pi(u1)
    mx, my, mz, ni = ggx_normal(a, a, wx, wy, wz, ca, sa, u2, False)
    ox, oy, oz, alive, _ = dielectric_about(p, wx, wy, wz, mx, my, mz, ni, er, 1.0 / er, u0, u3)
    return ox, oy, oz, alive


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
    accepted when u6 >= F(cos theta_o): :func:`~virtual.kernels.ggx.ggx_normal`,
    :func:`~virtual.kernels.ggx.plastic_diffuse`, then :func:`~virtual.kernels.ggx.plastic_about`.
    """
    a = p[0]
    ca, sa = sincos_2pi(u1)
    mx, my, mz, ni = ggx_normal(a, a, wx, wy, wz, ca, sa, u2, False)
    dx, dy, dz, fo = plastic_diffuse(p, u4, u5)
    ox, oy, oz, alive, redo, _ = plastic_about(p, wx, wy, wz, mx, my, mz, ni, dx, dy, dz, fo, u0, u3, u6)
    return ox, oy, oz, alive, redo


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


