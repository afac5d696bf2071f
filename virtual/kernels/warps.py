"""Scalar warps: uniforms in [0, 1) to points of a square, disk, triangle or the hemisphere.

The ray kernels inline them; :mod:`virtual.sampling` applies the same warps to arrays of
uniforms drawn by a strategy (seed section 3.1.2, eqs. 3.3, 3.4, 3.10, 3.11).
"""

from __future__ import annotations

import math

from numba import int64

from virtual.kernels import jit
from virtual.kernels.xoshiro import next_double

__all__ = ["warp_square", "sincos_2pi", "warp_polar", "warp_triangle", "warp_cosine_hemisphere",
           "sample_cosine_hemisphere"]

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


@jit(inline="llvm")
def warp_square(u1, u2, r):
    """Eq. 3.3: a point in the square [-r, r]^2 (to be rejected outside the disk)."""
    return r * (2.0 * u1 - 1.0), r * (2.0 * u2 - 1.0)



@jit(inline="llvm")
def sincos_2pi(u):
    """``(cos 2 pi u, sin 2 pi u)`` for u in [0, 1), to within 2 ulp, branch-free.

    The angle is reduced exactly to the nearest quarter turn q (4u - q in [-1/2, 1/2] is exact),
    the remainder x = (4u - q) pi / 2 in [-pi/4, pi/4] goes through the Taylor polynomials of
    sin and cos (truncation below 5e-17), and q rotates the result by selects. Unlike libm's
    sin/cos, LLVM vectorizes it, which is what makes the polar warp cheap in the block kernels.
    """
    t = 4.0 * u
    q = math.floor(t + 0.5)
    x = (t - q) * _HALF_PI
    x2 = x * x
    s = x * (1.0 + x2 * (-1.0 / 6.0 + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (
        1.0 / 362880.0 + x2 * (-1.0 / 39916800.0 + x2 * (1.0 / 6227020800.0 + x2 * (-1.0 / 1307674368000.0))))))))
    c = 1.0 + x2 * (-0.5 + x2 * (1.0 / 24.0 + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40320.0 + x2 * (
        -1.0 / 3628800.0 + x2 * (1.0 / 479001600.0 + x2 * (-1.0 / 87178291200.0 + x2 * (1.0 / 20922789888000.0))))))))
    quarter = int64(q) & 3  # angle = quarter * pi/2 + x
    odd = (quarter & 1) == 1
    cq = s if odd else c
    sq = c if odd else s
    cq = -cq if (quarter == 1 or quarter == 2) else cq
    sq = -sq if quarter >= 2 else sq
    return cq, sq



@jit(inline="llvm")
def warp_polar(u1, u2, r):
    """Eq. 3.4 done right: (phi, rho) = (2 pi u1, r sqrt(u2)) -> (rho cos phi, rho sin phi)."""
    c, s = sincos_2pi(u1)
    rho = r * math.sqrt(u2)
    return rho * c, rho * s



@jit(inline="llvm")
def warp_triangle(u3, u4):
    """Eq. 3.11 (Shirley): barycentric (x', y') uniform on the triangle for uniforms u3, u4."""
    xp = 1.0 - math.sqrt(1.0 - u3)
    return xp, (1.0 - xp) * u4



@jit
def _warp_polar_array(u, r, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = warp_polar(u[i, 0], u[i, 1], r)



@jit
def _warp_triangle_array(u, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = warp_triangle(u[i, 0], u[i, 1])



@jit(inline="llvm")
def warp_cosine_hemisphere(u1, u2):
    """Malley's method: the polar warp lifted to the unit hemisphere, pdf cos(theta)/pi.

    z = sqrt(1 - rho^2) = sqrt(1 - u2) is computed from u2 directly, never from rho, so it
    cannot round below 0 or above 1.
    """
    x, y = warp_polar(u1, u2, 1.0)
    return x, y, math.sqrt(1.0 - u2)



@jit(inline="llvm")
def sample_cosine_hemisphere(s):
    """Malley's method on a rejection-sampled unit disk (eq. 3.3): pdf cos(theta)/pi.

    Same distribution as :func:`warp_cosine_hemisphere` without the sine and cosine (about
    twice as fast in the kernels). ``rho^2 < 1`` strictly, so z > 0 and never NaN.
    """
    while True:
        x = 2.0 * next_double(s) - 1.0
        y = 2.0 * next_double(s) - 1.0
        r2 = x * x + y * y
        if r2 < 1.0:
            return x, y, math.sqrt(1.0 - r2)
