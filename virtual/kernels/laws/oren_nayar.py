"""Oren-Nayar (:class:`virtual.specimens.diffuse.OrenNayar`), params ``[albedo, A, B, albedo A,
2 albedo B / pi]``: a mixture proposal -- the cosine lobe (mass albedo A), and "uniform in
cos(theta_o), azimuth density cos(dphi)/2 around the source's azimuth" (mass 2 albedo B / pi) --
thinned to f cos(theta_o) by a survival roll. Opaque, two-sided.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.microfacet import two_sided_draw, unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernels.precision64 import ONE, TWO, ZERO, in_doubt, sincos_2pi  # precision

MODEL = 1
TITLE = "Oren-Nayar"
SPECIMEN = "virtual.specimens.diffuse"
UNIFORMS = 4
FLOAT32_LIMITS = ()


@jit(inline="llvm")
def given(p, wx, wy, wz, u0, u1, u2, u3):
    """The cosine lobe (Malley from (u1, u2)) when u0 < albedo A, else uniform in cos(theta_o)
    (1 - u1) with azimuth density cos(dphi)/2 (sin dphi = 2 u2 - 1) when u0 < albedo (A + 2 B / pi),
    surviving by u3."""
    flip = wz < ZERO
    wz = abs(wz)
    si2 = wx * wx + wy * wy
    has = si2 > ZERO
    inv = ONE / math.sqrt(si2 if has else ONE)
    cp = wx * inv if has else ONE
    sp = wy * inv if has else ZERO
    c1, s1 = sincos_2pi(u1)
    rho = math.sqrt(u2)
    first = u0 < p[3]
    bz = ONE - u1
    so = math.sqrt((ONE - bz) * (ONE + bz))
    sd = TWO * u2 - ONE
    cd = math.sqrt(max(ONE - sd * sd, ZERO))
    ox = rho * c1 if first else so * (cd * cp - sd * sp)
    oy = rho * s1 if first else so * (sd * cp + cd * sp)
    oz = math.sqrt(ONE - u2) if first else bz
    so2 = ox * ox + oy * oy
    pos = so2 > ZERO
    d_ref = max(ox * cp + oy * sp, ZERO)
    c_term = d_ref / math.sqrt(so2 if pos else ONE) if pos else ZERO
    den = p[1] * oz + p[2] * c_term
    num = p[1] * oz + p[2] * max(ox * wx + oy * wy, ZERO) * oz / max(oz, wz)
    total = p[3] + p[4]
    alive = (wz > ZERO) & (u0 < total) & (u3 * den < num)
    doubt = in_doubt(u0, p[3], ONE) | in_doubt(u0, total, ONE) | in_doubt(u3, num, den)
    return ox, oy, (-oz if flip else oz), alive, doubt


@jit(inline="llvm")
def ray(p, wx, wy, wz, s):
    """The ray-by-ray sampler: the same proposal and survival, the cosine lobe's disk point by
    rejection from ``s`` (float64 only)."""
    flip, wz, alive, u = two_sided_draw(wz, s)
    if not alive:
        return 0.0, 0.0, 0.0, False
    si2 = wx * wx + wy * wy
    if si2 > 0.0:
        inv = 1.0 / math.sqrt(si2)
        cp = wx * inv
        sp = wy * inv
    else:
        cp = 1.0
        sp = 0.0
    if u < p[3]:
        a, b, r2 = unit_disk(s)
        ox = a
        oy = b
        oz = math.sqrt(1.0 - r2)
    elif u < p[3] + p[4]:
        oz = 1.0 - next_double(s)  # (0, 1]
        so = math.sqrt((1.0 - oz) * (1.0 + oz))
        sd = 2.0 * next_double(s) - 1.0  # sin(dphi): dphi has density cos(dphi)/2 on (-pi/2, pi/2)
        cd = math.sqrt(max(1.0 - sd * sd, 0.0))
        ox = so * (cd * cp - sd * sp)
        oy = so * (sd * cp + cd * sp)
    else:
        return 0.0, 0.0, 0.0, False
    so2 = ox * ox + oy * oy
    d_ref = max(ox * cp + oy * sp, 0.0)
    c_term = d_ref / math.sqrt(so2) if so2 > 0.0 else 0.0
    den = p[1] * oz + p[2] * c_term
    num = p[1] * oz + p[2] * max(ox * wx + oy * wy, 0.0) * oz / max(oz, wz)
    if not (next_double(s) * den < num):
        return 0.0, 0.0, 0.0, False
    return ox, oy, (-oz if flip else oz), True
