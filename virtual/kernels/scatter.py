"""The specimen kernels: model ids, one scattering branch per model, and the ``scatter`` dispatch.

``scatter(model, params, wx, wy, wz, s)`` is what the ray kernels call. It dispatches on the
specimen's integer ``model`` id and reads the model's parameter vector ``params`` (what
:meth:`virtual.specimens.Specimen.params` returns for a wavelength). ``(wx, wy, wz)`` is the unit
vector from the specimen toward the source; ``s`` the caller's xoshiro state. It returns
``(ox, oy, oz, alive)``: a unit outgoing direction (oz > 0 reflected, oz < 0 transmitted) or
``alive = False`` when the ray was absorbed. Sampling is analog: the direction density is
``f_s |cos theta_o| / albedo`` and the survival probability is the directional albedo, so
counting rays estimates the BSDF without weights. Every branch samples exactly: a proposal whose
density dominates ``f_s |cos theta_o|`` with total mass <= 1, then survival with the ratio.
Opaque models are two-sided (mirrored when the source is below).

A new kernel model is a law module of :mod:`virtual.kernels.laws` (its id, its sampling, written
once for float64 and float32) and its declaration (a :class:`virtual.specimens.Specimen` subclass
naming its ``model`` id); ``make kernels`` writes its branches (:mod:`virtual.kernels.law_dispatch`,
reached from :func:`_scatter_general`). The physics of each model is documented on its class.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.branchfree import plastic_diffuse_redo
from virtual.kernels.ggx import (fresnel_conductor_ratio, g2_over_g1, g2_over_g1_masked, ggx_fresnel_draw, ggx_normal,
                                ggx_reflect)
from virtual.kernels.microfacet import disk_direction, unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernels.coat import roughplastic
from virtual.kernels.law_dispatch import law_scatter
from virtual.kernels.laws import lambert
from virtual.kernels.warps import sincos_2pi
# Model ids: one branch each in `scatter`; they live in a numba-free module (specimens declare them).
from virtual.model_ids import (MODEL_ANISO_GGX, MODEL_DIELECTRIC, MODEL_GGX, MODEL_LAMBERT, MODEL_LEAF,
                               MODEL_OREN_NAYAR, MODEL_PHONG, MODEL_PLASTIC, MODEL_PYTHON, MODEL_ROUGHPLASTIC)

__all__ = ["MODEL_LAMBERT", "MODEL_OREN_NAYAR", "MODEL_PHONG", "MODEL_GGX", "MODEL_ANISO_GGX",
           "MODEL_PLASTIC", "MODEL_DIELECTRIC", "MODEL_LEAF", "MODEL_ROUGHPLASTIC", "MODEL_PYTHON", "GIVEN_MODELS", "GIVEN_UNIFORMS",
           "scatter", "scatter_given", "ggx_given_parts", "leaf_body_redo"]

from virtual.kernel_codes import GIVEN_MODELS, GIVEN_UNIFORMS

_DEAD = (0.0, 0.0, 0.0, False)


@jit(inline="llvm")
def ggx_given_parts(ax, ay, separable, wx, wy, wz, ca, sa, r2):
    """The wavelength-free part of :func:`_ggx_given`, which calls it (the spectral batch samples
    it once per ray): ``(ox, oy, oz, c, g_num, g_den, valid)`` -- the reflected direction (side
    restored), the cosine w.m the Fresnel factor takes, G2/G1 as a ratio under the masking
    convention ``separable`` (0.0 height-correlated, 1.0 separable), and whether both cosines
    are > 0. A wavelength's ray survives when ``valid`` and u f_den g_den < f_num g_num with
    ``fresnel_conductor_ratio(c, eta, k, False)``. :mod:`virtual.kernels.ggx`'s two halves, which
    the float32 block kernel runs in loops of their own."""
    mx, my, mz, ni = ggx_normal(ax, ay, wx, wy, wz, ca, sa, r2, False)
    return ggx_reflect(ax, ay, separable, wx, wy, wz, mx, my, mz, ni, False)


@jit(inline="llvm")
def _ggx_given(p, wx, wy, wz, ca, sa, r2, u):
    """GGX reflection of the ray from w (either side: two-sided) given the VNDF's disk point
    (direction (ca, sa), squared radius r2) and the survival uniform u. Branch-free (block
    kernels vectorize it): ``(ox, oy, oz, alive)``, the ray surviving with probability
    F(w.m) G2/G1 (masking convention p[4]: 0 height-correlated, 1 separable).

    u < F G2/G1 is tested as u den_F den_G < num_F num_G (both denominators are >= 0, and > 0
    when wz, oz > 0): no division. The conductor Fresnel formula with k = 0 is the dielectric
    one (total internal reflection included), so one formula serves both.
    """
    ox, oy, oz, c, g_num, g_den, valid = ggx_given_parts(p[0], p[1], p[4], wx, wy, wz, ca, sa, r2)
    f_num, f_den = fresnel_conductor_ratio(c, p[2], p[3], False)
    alive = valid & (u * f_den * g_den < f_num * g_num)
    return ox, oy, oz, alive



@jit(inline="llvm")
def _ggx(p, wx, wy, wz, s):
    ca, sa, r2 = disk_direction(s)
    return _ggx_given(p, wx, wy, wz, ca, sa, r2, next_double(s))



@jit(inline="llvm")
def _plastic(p, wx, wy, wz, s):
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0):
        return _DEAD
    a = p[0]
    refl, ox, oy, oz, _, _, _, _, _ = ggx_fresnel_draw(wx, wy, wz, a, p[1], s)
    if refl:
        if not (oz > 0.0 and next_double(s) < g2_over_g1(wx, wy, wz, ox, oy, oz, a, a)):
            return _DEAD
        return ox, oy, (-oz if flip else oz), True
    if not (next_double(s) < p[2]):
        return _DEAD
    ox, oy, oz = plastic_diffuse_redo(p[1], s)  # the cosine lobe thinned by 1 - F(cos_o)
    return ox, oy, (-oz if flip else oz), True



@jit(inline="llvm")
def _dielectric(p, wx, wy, wz, s):
    a = p[0]
    flip = wz < 0.0
    if flip:
        wz = -wz
        er = 1.0 / p[1]
    else:
        er = p[1]
    if not (wz > 0.0):
        return _DEAD
    refl, ox, oy, oz, mx, my, mz, c, ct = ggx_fresnel_draw(wx, wy, wz, a, er, s)
    if refl:
        if not (oz > 0.0 and next_double(s) < g2_over_g1_masked(wx, wy, wz, ox, oy, oz, a, a, p[2])):
            return _DEAD
        return ox, oy, (-oz if flip else oz), True
    inv = 1.0 / er
    k = c * inv - ct
    ox = -wx * inv + k * mx
    oy = -wy * inv + k * my
    oz = -wz * inv + k * mz
    if not (oz < 0.0 and next_double(s) < g2_over_g1_masked(wx, wy, wz, ox, oy, -oz, a, a, p[2])):
        return _DEAD
    return ox, oy, (-oz if flip else oz), True



@jit(inline="llvm")
def _leaf_specular(wx, wy, wz, a, eta, ks, s):
    """The leaf cuticle's specular event for light from w (wz > 0): ``(ox, oy, oz, kept)``, kept
    with probability ks E_s(w) (a visible normal, Fresnel reflection, above the horizon, ks G2/G1)."""
    refl, ox, oy, oz, _, _, _, _, _ = ggx_fresnel_draw(wx, wy, wz, a, eta, s)
    if refl:
        if oz > 0.0 and next_double(s) < ks * g2_over_g1(wx, wy, wz, ox, oy, oz, a, a):
            return ox, oy, oz, True
    return 0.0, 0.0, 0.0, False



@jit(inline="llvm")
def leaf_body_redo(a, eta, ks, s):
    """The leaf body's direction from the stream ``s``, upper hemisphere: the cosine lobe thinned
    by 1 - ks E_s(wo) (a direction is redrawn while light from it would have been kept by the
    cuticle); ends with probability 1 (E_s < 1). The block kernel finishes its rejected attempts
    with it too."""
    while True:
        ox, oy, r2 = unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        _, _, _, back = _leaf_specular(ox, oy, oz, a, eta, ks, s)
        if not back:
            return ox, oy, oz


@jit(inline="llvm")
def _leaf(p, wx, wy, wz, s):
    """Leaf (:class:`virtual.specimens.leaf.Leaf`), params ``[alpha, eta, ks, r_b, t_b]``: the
    cuticle's specular lobe (kept w.p. ks E_s(wi)); else the body reflects (r_b), transmits
    (t_b) or absorbs; the body's ray leaves along a cosine direction wo accepted unless light
    from wo would have been kept by the lobe (probability 1 - ks E_s(wo)): f symmetric."""
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0):
        return _DEAD
    a = p[0]
    eta = p[1]
    ks = p[2]
    ox, oy, oz, kept = _leaf_specular(wx, wy, wz, a, eta, ks, s)
    if kept:
        return ox, oy, (-oz if flip else oz), True
    u = next_double(s)
    if u >= p[3] + p[4]:
        return _DEAD
    up = u < p[3]
    ox, oy, oz = leaf_body_redo(a, eta, ks, s)
    if up == flip:
        oz = -oz
    return ox, oy, oz, True



@jit
def _scatter_general(model, p, wx, wy, wz, s):
    """Every model (called, not inlined: inlining them all into each kernel quadruples the
    compile time)."""
    if model == MODEL_GGX or model == MODEL_ANISO_GGX:
        return _ggx(p, wx, wy, wz, s)
    if model == MODEL_PLASTIC:
        return _plastic(p, wx, wy, wz, s)
    if model == MODEL_DIELECTRIC:
        return _dielectric(p, wx, wy, wz, s)
    if model == MODEL_LEAF:
        return _leaf(p, wx, wy, wz, s)
    if model == MODEL_ROUGHPLASTIC:
        return roughplastic(p, wx, wy, wz, s)
    return law_scatter(model, p, wx, wy, wz, s)  # the laws of virtual.kernels.laws (0, 0, 0, False for none)



@jit(inline="llvm")
def scatter(model, p, wx, wy, wz, s):
    """Scatter one ray (see the module docstring for the contract).

    Inlined into the kernels with the Lambertian's ray (:mod:`virtual.kernels.laws.lambert`), the
    commonest and cheapest specimen (1.2-1.8x the kernel's rays/s); every other model is one call
    away.
    """
    if model == MODEL_LAMBERT:
        return lambert.ray(p, wx, wy, wz, s)
    return _scatter_general(model, p, wx, wy, wz, s)



@jit(inline="llvm")
def scatter_given(model, p, wx, wy, wz, u0, u1, u2):
    """:func:`scatter` for the :data:`GIVEN_MODELS`, with its three uniforms given instead of
    drawn, and no branch: the same distribution of ``(ox, oy, oz, alive)``.

    u0 decides survival (and reflection against transmission); (u1, u2) is a polar disk point
    (:func:`~virtual.kernels.warps.warp_polar`): the Lambertian's cosine-weighted direction
    (Malley), GGX's visible-normal cap point. Callers only read the direction when ``alive``.
    """
    if model == MODEL_LAMBERT:
        ox, oy, oz, alive, _ = lambert.given(p, wx, wy, wz, u0, u1, u2)
        return ox, oy, oz, alive
    ca, sa = sincos_2pi(u2)
    return _ggx_given(p, wx, wy, wz, ca, sa, u1, u0)


# --- four-uniform given forms, for the block kernel: the rough dielectric (virtual.kernels.branchfree) --
# Same contract as `scatter_given`, with four uniforms: u0 picks the lobe (or absorption), (u1, u2)
# is a polar disk point standing for the ray-by-ray branch's rejection-sampled `unit_disk`
# (the same uniform distribution: direction sincos_2pi(u1), squared radius u2), u3 is the
# survival roll. No branch: every lobe is computed and the chosen one selected.
