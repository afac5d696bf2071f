"""Phong (:class:`virtual.specimens.diffuse.Phong`), params ``[kd, ks, n, ks (n+2)/(n+1)]``: with
probability kd a cosine-weighted direction; with probability ks (n+2)/(n+1) a direction of the
lobe (n+1)/(2 pi) cos^n(alpha) around the mirror direction, kept with probability cos(theta_o);
else absorbed. Opaque, two-sided.

The lobe's angle comes from u2 (cos(alpha) = u2^(1/(n+1))) in a loop of its own before the
block's main loop (a ``pow`` does not vectorize): ``lobe64`` per ray in float64, and in float32
:func:`~virtual.kernels.branchfree32.phong_lobe_omc32` over a row of the block (``lobe32``:
1 - cos(alpha) by float32 polynomials, which a narrow lobe needs -- cos(alpha) itself rounds to
1 in float32). ``given`` takes that value last and reads it with the precision's
``lobe_cos_sin``: the law itself is one text.
"""

from __future__ import annotations

import math

from virtual.kernels import jit
from virtual.kernels.branchfree32 import phong_lobe_omc32
from virtual.kernel_codes import MAX_PHONG_EXPONENT
from virtual.kernels.microfacet import about_mirror, frame as frame64, two_sided_draw, unit_disk
from virtual.kernels.xoshiro import next_double
from virtual.kernels.precision64 import ONE, ZERO, frame, in_doubt, lobe_cos_sin, sincos_2pi  # precision

MODEL = 2
TITLE = "Phong"
SPECIMEN = "virtual.specimens.diffuse"
UNIFORMS = 4
FLOAT32_LIMITS = ((2, "exponent", 0.0, MAX_PHONG_EXPONENT),)
#: the uniform row the lobe's prepass reads (u2)
LOBE_ROW = 2
#: the float32 prepass over a row of the block: ``lobe32(p, row, int32 scratch, out)``
lobe32 = phong_lobe_omc32


@jit(inline="llvm")
def lobe64(p, u0, u2):
    """cos(alpha) = u2^(1/(n+1)) for a lobe ray (kd <= u0 < kd + lobe share), else 1: a ``pow``,
    which LLVM does not vectorize (the block kernel computes it in a loop of its own)."""
    return u2 ** (1.0 / (p[2] + 1.0)) if (u0 >= p[0]) & (u0 < p[0] + p[3]) else 1.0


@jit(inline="llvm")
def given(p, wx, wy, wz, u0, u1, u2, u3, lobe):
    """Diffuse when u0 < kd (Malley from (u1, u2)), the cos^n lobe when u0 < kd + lobe share
    (its angle from ``lobe``, the prepass's value of u2; azimuth 2 pi u1), surviving with
    probability cos(theta_o) by u3; else absorbed."""
    flip = wz < ZERO
    wz = abs(wz)
    c1, s1 = sincos_2pi(u1)
    rho = math.sqrt(u2)
    dz = math.sqrt(ONE - u2)
    ca, sa = lobe_cos_sin(lobe)
    lx, ly, lz = about_mirror(frame(-wx, -wy, wz), c1 * sa, s1 * sa, ca, wx, wy, wz)
    diffuse = u0 < p[0]
    share = p[0] + p[3]
    lobe_ok = (u0 < share) & (lz > ZERO) & (u3 < lz)
    ox = rho * c1 if diffuse else lx
    oy = rho * s1 if diffuse else ly
    oz = dz if diffuse else lz
    alive = (wz > ZERO) & (diffuse | lobe_ok)
    doubt = in_doubt(u0, p[0], ONE) | in_doubt(u0, share, ONE) | in_doubt(u3, lz, ONE)
    return ox, oy, (-oz if flip else oz), alive, doubt


@jit(inline="llvm")
def ray(p, wx, wy, wz, s):
    """The ray-by-ray sampler: the same proposal, the disk points by rejection from ``s``
    (float64 only)."""
    flip, wz, alive, u = two_sided_draw(wz, s)
    if not alive:
        return 0.0, 0.0, 0.0, False
    if u < p[0]:
        a, b, r2 = unit_disk(s)
        oz = math.sqrt(1.0 - r2)
        return a, b, (-oz if flip else oz), True
    if not (u < p[0] + p[3]):
        return 0.0, 0.0, 0.0, False
    # lobe (n+1)/(2 pi) cos^n around r = (-wx, -wy, wz): cos(alpha) = xi^(1/(n+1)), xi = r2
    a, b, r2 = unit_disk(s)
    ca = r2 ** (1.0 / (p[2] + 1.0))
    sa_over_r = math.sqrt(max((1.0 - ca) * (1.0 + ca), 0.0) / r2)
    ox, oy, oz = about_mirror(frame64(-wx, -wy, wz), a * sa_over_r, b * sa_over_r, ca, wx, wy, wz)
    if not (oz > 0.0 and next_double(s) < oz):
        return 0.0, 0.0, 0.0, False
    return ox, oy, (-oz if flip else oz), True
