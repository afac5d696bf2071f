"""GGX's visible normals, Smith masking ratios, its reflection, the Fresnel factors, and the rough
dielectric's and rough plastic's steps from the visible normal on, written once for float64 and
float32.

This module is the float64 source: it computes with the constants of its ``precision64`` import
line, never a float literal, and :mod:`virtual.kernels.lawcode` writes its float32 twin
``virtual/kernels/ggx32.py`` (the same text importing ``precision32``: a build product, not
checked in) the way it writes the laws' (:mod:`virtual.kernels.laws`). The float32 block kernels
import the twin's functions (:mod:`virtual.kernels.block32`, :mod:`virtual.kernels.branchfree32`,
:mod:`virtual.kernels.block32_coat`, ...), the float64 kernels these
(:func:`~virtual.kernels.scatter.ggx_given_parts` is :func:`ggx_normal` then :func:`ggx_reflect`;
the rough dielectric's and plastic's given forms in :mod:`virtual.kernels.branchfree` are
:func:`ggx_normal` then :func:`dielectric_about`, :func:`plastic_about`; Mitsuba's roughplastic's
in :mod:`virtual.kernels.block_coat`, :func:`ggx_normal` then :func:`roughplastic_about`). A step deciding with a
uniform also returns ``doubt``, whether a decision lies within the float32 grid's reach of its
threshold (``in_doubt``: always False in float64, where that code folds away).
:func:`ggx_vndf` and :func:`ggx_fresnel_draw` draw from a stream: float64 only (their twins are
never compiled).

``plain`` and ``k_zero`` (a literal at each call: the branches fold away) pick a shorter form
for the float32 block kernel's commonest case (isotropic, height-correlated, k = 0); it rounds
differently, so the float64 kernels, whose counts are pinned with the general form, pass False.

Conventions (shared with the numpy densities of :mod:`virtual.specimens.physics`): GGX uses
Smith's height-correlated masking-shadowing G2 = 1 / (1 + L(wi) + L(wo)), G1(w) = 1 / (1 + L(w)),
L(w) = (sqrt(1 + (ax^2 wx^2 + ay^2 wy^2) / wz^2) - 1) / 2; with n(w) = sqrt(ax^2 wx^2 + ay^2 wy^2 +
wz^2), G2 / G1(wi) = (zi + n_i) zo / (n_i zo + n_o zi): no division by a grazing cosine anywhere.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.microfacet import disk_direction
from virtual.kernels.xoshiro import next_double
from virtual.kernels.precision64 import FOUR, HALF, ONE, TINY, TWO, ZERO, in_doubt, warp_cosine_hemisphere  # precision

__all__ = ["ggx_n", "ggx_vndf_given", "ggx_vndf", "g2_over_g1_ratio", "g2_over_g1_masked_ratio", "g2_over_g1",
           "g2_over_g1_masked", "ggx_normal", "ggx_mirror", "ggx_reflect", "fresnel_conductor_ratio", "fresnel_dielectric",
           "dielectric_about", "plastic_diffuse", "plastic_about", "roughplastic_about", "ggx_fresnel_draw"]


@jit(inline="llvm")
def ggx_n(wx, wy, wz, ax, ay):
    """|(ax wx, ay wy, wz)|: n(w) of the module docstring."""
    return math.sqrt(ax * ax * wx * wx + ay * ay * wy * wy + wz * wz)


@jit(inline="llvm")
def ggx_vndf_given(wx, wy, wz, ax, ay, inv_ni, ca, sa, r2):
    """A microfacet normal from GGX's distribution of visible normals for w (wz > 0), given
    ``inv_ni`` = 1 / |(ax wx, ay wy, wz)| (:func:`ggx_n`, which G1 needs too) and a uniform
    point of the unit disk as its direction (ca, sa) (unit) and squared radius r2. Branch-free.

    Dupuy & Benyoub (2023) "spherical caps" form of Heitz (2018): in the stretched frame the
    visible normal is h = c + v with c uniform on the cap z > -v_z of the unit sphere. The cap
    point from the disk point: z = 1 - q r2 with q = 1 + v_z and sin(theta) (cos, sin)(phi) =
    (ca, sa) sqrt(r2 q (2 - q r2)) -- no trigonometric call.
    """
    vx = ax * wx * inv_ni
    vy = ay * wy * inv_ni
    vz = wz * inv_ni
    q = ONE + vz
    z = ONE - q * r2
    sc = math.sqrt(max(r2 * q * (TWO - q * r2), ZERO))
    hx = ca * sc + vx
    hy = sa * sc + vy
    hz = max(z + vz, ZERO)
    mx = ax * hx
    my = ay * hy
    n2 = mx * mx + my * my + hz * hz
    good = n2 > ZERO
    inv = ONE / math.sqrt(n2 if good else ONE)
    return (mx * inv if good else ZERO), (my * inv if good else ZERO), (hz * inv if good else ONE)


@jit(inline="llvm")
def ggx_vndf(wx, wy, wz, ax, ay, s):
    """:func:`ggx_vndf_given` with the disk point drawn by rejection from the stream ``s`` (float64
    only: the float32 kernels take their uniforms in blocks)."""
    ca, sa, r2 = disk_direction(s)
    return ggx_vndf_given(wx, wy, wz, ax, ay, ONE / ggx_n(wx, wy, wz, ax, ay), ca, sa, r2)


@jit(inline="llvm")
def g2_over_g1_ratio(wz, ni, oz, no):
    """G2(wi, wo) / G1(wi) as ``(num, den)`` from the cosines and :func:`ggx_n` of both
    directions; den > 0 for wz, oz > 0."""
    return (wz + ni) * oz, ni * oz + no * wz


@jit(inline="llvm")
def g2_over_g1_masked_ratio(wz, ni, oz, no, separable):
    """G2(wi, wo) / G1(wi) as ``(num, den)`` under either masking convention, branch-free:
    ``separable`` = 0.0 (height-correlated, :func:`g2_over_g1_ratio`) or 1.0 (separable Smith,
    G2 = G1(wi) G1(wo), so the ratio is G1(wo) = 2 oz / (oz + n_o))."""
    c = ONE - separable
    return c * (wz + ni) * oz + separable * TWO * oz, c * (ni * oz + no * wz) + separable * (oz + no)


@jit(inline="llvm")
def g2_over_g1(wx, wy, wz, ox, oy, oz, ax, ay):
    """G2(wi, wo) / G1(wi) for wz, oz > 0 (<= 1)."""
    num, den = g2_over_g1_ratio(wz, ggx_n(wx, wy, wz, ax, ay), oz, ggx_n(ox, oy, oz, ax, ay))
    return num / den


@jit(inline="llvm")
def g2_over_g1_masked(wx, wy, wz, ox, oy, oz, ax, ay, separable):
    """:func:`g2_over_g1` under the masking convention ``separable`` (0.0 or 1.0)."""
    num, den = g2_over_g1_masked_ratio(wz, ggx_n(wx, wy, wz, ax, ay), oz, ggx_n(ox, oy, oz, ax, ay), separable)
    return num / den


@jit(inline="llvm")
def ggx_normal(ax, ay, wx, wy, wz, ca, sa, r2, plain):
    """GGX (isotropic or anisotropic), two-sided, first half: the visible normal ``(mx, my, mz)``
    of |w| for the disk point (direction ``ca, sa``, squared radius ``r2``) and ni = |(ax wx,
    ay wy, |wz|)| (:func:`ggx_n`). ``plain`` says ax == ay: ni without the anisotropic term's
    product (the module docstring)."""
    wz = abs(wz)
    if plain:
        ni = math.sqrt(ax * ax * (wx * wx + wy * wy) + wz * wz)
    else:
        ni = ggx_n(wx, wy, wz, ax, ay)
    mx, my, mz = ggx_vndf_given(wx, wy, wz, ax, ay, ONE / ni, ca, sa, r2)
    return mx, my, mz, ni


@jit(inline="llvm")
def ggx_mirror(wx, wy, wz, mx, my, mz):
    """``(flip, |wz|, c, ox, oy, oz)``: whether w comes from below, its cosine on the upper side,
    c = w.m (>= 0) and the mirror direction 2 c m - w of (wx, wy, |wz|) about the normal m."""
    flip = wz < ZERO
    wz = abs(wz)
    c = max(wx * mx + wy * my + wz * mz, ZERO)
    return flip, wz, c, TWO * c * mx - wx, TWO * c * my - wy, TWO * c * mz - wz


@jit(inline="llvm")
def ggx_reflect(ax, ay, separable, wx, wy, wz, mx, my, mz, ni, plain):
    """The second half: the reflection of w about the normal of :func:`ggx_normal` (side
    restored) and its terms, ``(ox, oy, oz, c, g_num, g_den, valid)`` -- the cosine w.m the Fresnel
    factor takes, G2/G1 as a ratio under the masking convention ``separable`` (0.0
    height-correlated, 1.0 separable) and whether both cosines are > 0. ``plain`` says ax == ay
    and height-correlated masking."""
    flip, wz, c, ox, oy, oz = ggx_mirror(wx, wy, wz, mx, my, mz)
    if plain:
        no = math.sqrt(ax * ax * (ox * ox + oy * oy) + oz * oz)
        g_num, g_den = (wz + ni) * oz, ni * oz + no * wz
    else:
        g_num, g_den = g2_over_g1_masked_ratio(wz, ni, oz, ggx_n(ox, oy, oz, ax, ay), separable)
    return ox, oy, (-oz if flip else oz), c, g_num, g_den, (wz > ZERO) & (oz > ZERO)


@jit(inline="llvm")
def fresnel_conductor_ratio(c, eta, k, k_zero):
    """The conductor's Fresnel factor at the cosine c in [0, 1] as ``(num, den)``, F = num / den,
    den >= 0 (scalar twin of :func:`virtual.fresnel.np_fresnel_conductor`): F = (Rs + Rp)
    / 2 with Rp = Rs (t3 - t4) / (t3 + t4) is Rs t3 / (t3 + t4), and Rs = (t1 - t2) / (t1 + t2);
    callers compare against F without dividing. With k = 0 it is the dielectric's F, total
    internal reflection (eta < 1) included. ``k_zero`` says k = 0, where a^2 + b^2 = |t0| and
    a = sqrt(max(t0, 0)): one square root fewer."""
    c2 = c * c
    s2 = ONE - c2
    e2 = eta * eta
    k2 = k * k
    t0 = (eta - ONE) * (eta + ONE) - k2 + c2  # = e2 - k2 - s2, without rounding c2 away near eta = 1
    if k_zero:
        a2b2 = abs(t0)
        a = math.sqrt(max(t0, ZERO))
    else:
        a2b2 = math.sqrt(t0 * t0 + FOUR * e2 * k2)
        a = math.sqrt(max(HALF * (a2b2 + t0), ZERO))
    t1 = a2b2 + c2
    t2 = TWO * c * a
    t3 = c2 * a2b2 + s2 * s2
    t4 = t2 * s2
    return (t1 - t2) * t3, (t1 + t2) * (t3 + t4)


@jit(inline="llvm")
def fresnel_dielectric(c, eta):
    """``(F, cos_t)`` for the incident cosine c in [0, 1] and eta = n_t / n_i, branch-free; F = 1
    and cos_t = 0 on total internal reflection. cos_t^2 = ((eta - 1)(eta + 1) + c^2) / eta^2, not
    1 - (1 - c^2) / eta^2: at eta = 1 and grazing c the latter rounds c^2 away (c < 2.4e-4 in
    float32) and reports total reflection where nothing reflects."""
    ct2 = ((eta - ONE) * (eta + ONE) + c * c) / (eta * eta)
    tir = ct2 <= ZERO
    ct = math.sqrt(max(ct2, ZERO))
    rs = (c - eta * ct) / max(c + eta * ct, TINY)
    rp = (eta * c - ct) / max(eta * c + ct, TINY)
    f = HALF * (rs * rs + rp * rp)
    return (ONE if tir else f), (ZERO if tir else ct)


@jit(inline="llvm")
def dielectric_about(p, wx, wy, wz, mx, my, mz, ni, er, inv, u0, u3):
    """The rough dielectric (``p`` = alpha, eta, separable) from the visible normal m of |w|
    (:func:`ggx_normal`, ni its n(w)) on: reflection when u0 < F (else refraction; F = 1 on total
    internal reflection), surviving with probability G2/G1 by u3: ``(ox, oy, oz, alive, doubt)``.
    ``er`` is the relative index on w's side (eta from above, 1/eta from below) and ``inv`` its
    inverse, which each precision's caller computes its own way (1/er in float64, eta or 1/eta
    in float32: the two round differently, and each precision's counts are pinned)."""
    a = p[0]
    flip, wz, c, rx, ry, rz = ggx_mirror(wx, wy, wz, mx, my, mz)
    f, ct = fresnel_dielectric(c, er)
    refl = u0 < f
    k = c * inv - ct
    ox = rx if refl else k * mx - wx * inv
    oy = ry if refl else k * my - wy * inv
    oz = rz if refl else k * mz - wz * inv
    az = oz if refl else -oz  # the cosine on the side the ray leaves to
    g_num, g_den = g2_over_g1_masked_ratio(wz, ni, az, ggx_n(ox, oy, az, a, a), p[2])
    alive = (wz > ZERO) & (az > ZERO) & (u3 * g_den < g_num)
    doubt = in_doubt(u0, f, ONE) | in_doubt(u3, g_num, g_den)
    return ox, oy, (-oz if flip else oz), alive, doubt


@jit(inline="llvm")
def plastic_diffuse(p, u4, u5):
    """The rough plastic's diffuse attempt, which does not depend on w: Malley's direction from
    (u4, u5) and F at its cosine, ``(dx, dy, dz, fo)``."""
    dx, dy, dz = warp_cosine_hemisphere(u5, u4)
    fo, _ = fresnel_dielectric(dz, p[1])
    return dx, dy, dz, fo


@jit(inline="llvm")
def plastic_about(p, wx, wy, wz, mx, my, mz, ni, dx, dy, dz, fo, u0, u3, u6):
    """The rough plastic (``p`` = alpha, eta, kd), two-sided, one attempt of the diffuse lobe's
    rejection loop, from the visible normal of |w| (:func:`ggx_normal` from (u1, u2)) and the
    diffuse attempt (:func:`plastic_diffuse` from (u4, u5)) on: ``(ox, oy, oz, alive, redo,
    doubt)``, ``redo`` marking a rejected diffuse ray (``oz`` then only its side, +-1) whose
    direction :func:`~virtual.kernels.branchfree.plastic_diffuse_redo` draws. u0 < F: specular
    (G2/G1 by u3); else u0 is uniform on [F, 1), so u0 - F < kd (1 - F) is the diffuse survival
    with probability kd, no new uniform; the attempt is kept when u6 >= F(cos theta_o)."""
    a = p[0]
    flip, wz, c, sx, sy, sz = ggx_mirror(wx, wy, wz, mx, my, mz)
    f, _ = fresnel_dielectric(c, p[1])
    spec = u0 < f
    g_num, g_den = g2_over_g1_ratio(wz, ni, sz, ggx_n(sx, sy, sz, a, a))
    spec_ok = (sz > ZERO) & (u3 * g_den < g_num)
    diffuse = (u0 >= f) & ((u0 - f) < p[2] * (ONE - f))
    accepted = u6 >= fo
    ox = sx if spec else dx
    oy = sy if spec else dy
    oz = sz if spec else (dz if accepted else ONE)
    ok = wz > ZERO
    alive = ok & ((spec & spec_ok) | (diffuse & accepted))
    redo = ok & diffuse & (u6 < fo)
    doubt = (in_doubt(u0, f, ONE) | in_doubt(u0, f + p[2] * (ONE - f), ONE) | in_doubt(u3, g_num, g_den)
             | in_doubt(u6, fo, ONE))
    return ox, oy, (-oz if flip else oz), alive, redo, doubt


@jit(inline="llvm")
def roughplastic_about(p, wx, wy, wz, mx, my, mz, u0, u3, u4, u5, u6, base_num, base_den, t_o, plain):
    """Mitsuba's roughplastic (``p`` = alpha, eta, kd_eff, c), two-sided, one attempt of the base's
    rejection loop, from the visible normal m of |w| (:func:`ggx_normal` from (u1, u2)) on:
    ``(ox, oy, oz, alive, redo, doubt)``; ``redo`` marks a base ray whose attempt was rejected
    (``oz`` then carries only the side, +-1).

    Specular when u0 < F G1(wo) (Mitsuba's separable masking: G2/G1 = G1(wo) = 2 oz / (oz + no);
    F and G1 rolled at once: the same probability, and the direction does not depend on the
    roll); else the base when u3 (1 - E_spec) < c t(cos_i); its attempt is Malley's direction from
    (u4, u5), kept when u6 < t(cos_o). The table values come looked up: ``base_num`` = c t(cos_i),
    ``base_den`` = 1 - E_spec(cos_i), ``t_o`` = t(sqrt(1 - u4)), the attempt's cosine. ``plain``
    as :func:`ggx_normal` (the float32 block kernel's normal and no; the float64 one passes False)."""
    a = p[0]
    flip, wz, c, sx, sy, sz = ggx_mirror(wx, wy, wz, mx, my, mz)
    if plain:
        no = math.sqrt(a * a * (sx * sx + sy * sy) + sz * sz)
    else:
        no = ggx_n(sx, sy, sz, a, a)
    f, _ = fresnel_dielectric(c, p[1])
    s_num = f * (TWO * sz)
    s_den = sz + no
    spec = (sz > ZERO) & (u0 * s_den < s_num)
    base = (~spec) & (u3 * base_den < base_num)
    dx, dy, dz = warp_cosine_hemisphere(u5, u4)
    accepted = u6 < t_o
    ox = sx if spec else dx
    oy = sy if spec else dy
    oz = sz if spec else (dz if accepted else ONE)
    ok = wz > ZERO
    doubt = in_doubt(u0, s_num, s_den) | in_doubt(u3, base_num, base_den) | in_doubt(u6, t_o, ONE)
    return ox, oy, (-oz if flip else oz), ok & (spec | (base & accepted)), ok & base & (~accepted), doubt


@jit(inline="llvm")
def ggx_fresnel_draw(wx, wy, wz, a, eta, s):
    """The start of the ray-by-ray samplers of the GGX-coated models (float64 only): a visible
    normal m of w (wz > 0, isotropic roughness ``a``) drawn from the stream ``s``, then the roll of
    Fresnel reflection at the relative index ``eta``: ``(refl, ox, oy, oz, mx, my, mz, c, ct)`` --
    whether the ray reflects, its mirror direction about m (read when it does), m, the cosine w.m
    and the refracted cosine (:func:`fresnel_dielectric`)."""
    mx, my, mz = ggx_vndf(wx, wy, wz, a, a, s)
    _, _, c, ox, oy, oz = ggx_mirror(wx, wy, wz, mx, my, mz)
    f, ct = fresnel_dielectric(c, eta)
    refl = next_double(s) < f
    return refl, ox, oy, oz, mx, my, mz, c, ct
