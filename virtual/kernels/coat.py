"""Mitsuba 3's ``roughplastic`` in the kernels (model ``MODEL_ROUGHPLASTIC``): its two tables and
its ray-by-ray branch (:func:`roughplastic`, dispatched by :func:`virtual.kernels.scatter.scatter`).

The parameter vector (:mod:`virtual.kernel_codes`, ``RP_*``) is ``[alpha, eta, kd_eff, c,
t(mu_0) .. t(mu_63), s_lo, s_hi, n, E(nu_0) .. E(nu_{n-1})]``: the specimen's
(:meth:`virtual.specimens.roughplastic.MitsubaRoughPlastic.kernel_params`, the coat transmittance
t on Mitsuba's 64 nodes mu_i = i / 63, read by Mitsuba's linear ``lerp_gather``, :func:`rp_t`),
then what the engine appends for one measurement
(:func:`virtual.specimens.roughplastic.incidence_params`): the coat's specular albedo E_spec at
n nodes nu_j uniform in s = sqrt(1 - mu) over [s_lo, s_hi], the cosines of incidence the beam can
deliver, read by four-point Lagrange interpolation in s (:func:`rp_e`; E_spec is smooth in s,
~ the angle of incidence, while in mu it is not at normal incidence). A collimated beam has one
cosine: its four nodes all hold the exact E_spec there and every ray reads it exactly (x = 0
puts all the weight on the first node).

Sampling (the specimen's own, :meth:`~virtual.specimens.roughplastic.MitsubaRoughPlastic.sample`):
a visible normal m, the mirror direction kept with probability F(wi.m) G1(wo) -- the specular
lobe, probability E_spec(wi) in all; otherwise the base with probability
c t(cos_i) / (1 - E_spec(cos_i)), tested as ``u (1 - E) < c t`` (no division), so that the base
gets c t(cos_i) of all rays; its direction a cosine one kept with probability t(cos_o) (redrawn
otherwise). The coupling needs E_spec at the ray's own incidence: no exact formulation without
it was found (the split between the two lobes has to be known), hence the table.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.ggx import g2_over_g1_masked, ggx_fresnel_draw
from virtual.kernels.microfacet import unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernel_codes import RP_E, RP_N_E, RP_S_HI, RP_S_LO, RP_TABLE, RP_TABLE_RES

__all__ = ["rp_t", "rp_e", "roughplastic", "roughplastic_base_redo"]


@jit(inline="llvm")
def rp_t(p, mu):
    """t(mu) as Mitsuba's ``lerp_gather`` reads its 64-node table (``p[RP_TABLE:]``), mu in [0, 1]."""
    x = mu * (RP_TABLE_RES - 1)
    i = min(int(max(x, 0.0)), RP_TABLE_RES - 2)
    w = x - i
    return (1.0 - w) * p[RP_TABLE + i] + w * p[RP_TABLE + i + 1]


@jit(inline="llvm")
def rp_e(p, mu):
    """E_spec(mu) from the measurement's table: four-point Lagrange interpolation in
    s = sqrt(1 - mu) on its n >= 4 uniform nodes over [s_lo, s_hi], s clamped to that range.
    Branch-free."""
    n = int(p[RP_N_E])
    lo = p[RP_S_LO]
    span = p[RP_S_HI] - lo
    x = (min(max(math.sqrt(max(1.0 - mu, 0.0)), lo), lo + span) - lo) / span * (n - 1)
    i = min(max(int(x) - 1, 0), n - 4)
    t = x - i
    t1 = t - 1.0
    t2 = t - 2.0
    t3 = t - 3.0
    j = RP_E + i
    return (-t1 * t2 * t3 * p[j] + 3.0 * t * t2 * t3 * p[j + 1] - 3.0 * t * t1 * t3 * p[j + 2]
            + t * t1 * t2 * p[j + 3]) / 6.0


@jit(inline="llvm")
def roughplastic_base_redo(p, s):
    """A direction of the base's lobe (cosine, kept with probability t(cos_o), redrawn
    otherwise) from the stream ``s``, upper hemisphere. Ends with probability 1 (t > 0)."""
    while True:
        ox, oy, r2 = unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        if next_double(s) < rp_t(p, oz):
            return ox, oy, oz


@jit(inline="llvm")
def roughplastic(p, wx, wy, wz, s):
    """Mitsuba's roughplastic, ray by ray (see the module docstring); two-sided like every
    opaque model. ``(ox, oy, oz, alive)``."""
    flip = wz < 0.0
    if flip:
        wz = -wz
    if not (wz > 0.0) or p.shape[0] < RP_E + 4:  # no albedo table: the engine did not append one
        return 0.0, 0.0, 0.0, False
    a = p[0]
    refl, ox, oy, oz, _, _, _, _, _ = ggx_fresnel_draw(wx, wy, wz, a, p[1], s)
    if refl:
        if oz > 0.0 and next_double(s) < g2_over_g1_masked(wx, wy, wz, ox, oy, oz, a, a, 1.0):
            return ox, oy, (-oz if flip else oz), True
    if not (next_double(s) * (1.0 - rp_e(p, wz)) < p[3] * rp_t(p, wz)):
        return 0.0, 0.0, 0.0, False
    ox, oy, oz = roughplastic_base_redo(p, s)
    return ox, oy, (-oz if flip else oz), True
