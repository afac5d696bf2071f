"""Ward (:class:`virtual.specimens.ward.Ward`), params ``[kd, ks, alpha]``: an isotropic Ward
lobe over a Lambertian floor, opaque, two-sided.

f = kd / pi + ks D(h) cos(theta_h) / (4 wi.h), h the half vector of wi and wo and D Ward's
Gaussian-in-tan(theta_h) distribution (Beckmann's), D(h) = exp(-tan^2(theta_h) / alpha^2) /
(pi alpha^2 cos^4(theta_h)). Sampled exactly with four uniforms: u0 < kd picks Malley's
cosine direction from (u1, u2); kd <= u0 < kd + ks picks the lobe -- h from D(h) cos(theta_h)
(azimuth 2 pi u1, tan^2(theta_h) = -alpha^2 ln(1 - u2)), wo the reflection of wi about h, whose
density is exactly D(h) cos(theta_h) / (4 wi.h) -- kept with probability cos(theta_o) by u3
(wo below the horizon is absorbed); u0 >= kd + ks absorbs. The lobe's density being symmetric
in wi and wo, f is reciprocal; its albedo is at most kd + ks (<= 1, required).
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.precision64 import ONE, TWO, ZERO, in_doubt, sincos_2pi  # precision

MODEL = 9
TITLE = "Ward"
SPECIMEN = "virtual.specimens.ward"
UNIFORMS = 4
FLOAT32_LIMITS = ((2, "alpha", 0.01, 100.0),)  # alpha >= MIN_ALPHA: the lobe spans >= 1e5 float32 ulps


@jit(inline="llvm")
def given(p, wx, wy, wz, u0, u1, u2, u3):
    """The floor (Malley from (u1, u2)) when u0 < kd, the lobe (half vector from (u1, u2),
    surviving with probability cos(theta_o) by u3) when u0 < kd + ks, else absorbed."""
    flip = wz < ZERO
    wz = abs(wz)
    c1, s1 = sincos_2pi(u1)
    rho = math.sqrt(u2)
    a = p[2]
    t2 = -(a * a) * math.log(ONE - u2)  # tan^2(theta_h)
    c2 = ONE / (ONE + t2)
    hs = math.sqrt(t2 * c2)  # sin(theta_h), not sqrt(1 - c2): exact for a narrow lobe
    hx = hs * c1
    hy = hs * s1
    hz = math.sqrt(c2)
    d = wx * hx + wy * hy + wz * hz
    lx = TWO * d * hx - wx
    ly = TWO * d * hy - wy
    lz = TWO * d * hz - wz
    diffuse = u0 < p[0]
    lobe = p[0] + p[1]
    lobe_ok = (u0 < lobe) & (lz > ZERO) & (u3 < lz)
    ox = rho * c1 if diffuse else lx
    oy = rho * s1 if diffuse else ly
    oz = math.sqrt(ONE - u2) if diffuse else lz
    alive = (wz > ZERO) & (diffuse | lobe_ok)
    doubt = in_doubt(u0, p[0], ONE) | in_doubt(u0, lobe, ONE) | in_doubt(u3, lz, ONE)
    return ox, oy, (-oz if flip else oz), alive, doubt
