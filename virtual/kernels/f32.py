"""Float32 twins of the scalar helpers, for the block kernel's 16-lane path.

An AVX-512 register holds 16 float32 lanes against 8 float64 ones, so the block kernel's
branch-free loops run about twice as fast in float32 (:mod:`virtual.kernels.block32`). numba
types a float literal as float64 and promotes float32 with it, so every constant here is a
module-level ``np.float32`` (frozen by numba as a float32 constant) and every helper takes and
returns float32: one float64 literal in a loop would silently turn it back into float64.

What float32 costs, and where it stops (:func:`virtual.engine.gonio_kernel_for` decides): each
direction carries a relative error of a few 1e-7 and each survival test a few 1e-7 of its
probability -- far below what any count of rays can detect, but not nothing. The uniforms'
2^-24 grid alone would put a floor under every decision (``u < p`` happening with probability
ceil(p 2^24) 2^-24); :func:`in_doubt32` hands the rays near a threshold to float64
(:mod:`virtual.kernels.refine`), so no probability is floored. So only
well-conditioned specimens take this path (GGX-like roughness >= :data:`MIN_ALPHA`, Phong
exponents <= :data:`MAX_PHONG_EXPONENT`, the same lobe width, dielectric indices within
:data:`MAX_ETA`); the bin of each computed direction is exact (a guess with margins, the float64
:func:`~virtual.kernels.patch_lookup.patch_of` near an edge).
"""

from __future__ import annotations

import math

import numpy as np
from numba import int32

from virtual.kernels import jit
from virtual.kernels.emit import B_AXIS_X, B_AXIS_Y, B_AXIS_Z, B_DISTANCE, B_EMITTER_RADIUS, B_SPECIMEN_RADIUS
from virtual.kernels.patch_lookup import SCHEME_EQUAL_PSA, SCHEME_EQUAL_SOLID_ANGLE

__all__ = ["F", "ZERO", "ONE", "TWO", "FOUR", "HALF", "TINY", "MIN_ALPHA", "MAX_PHONG_EXPONENT", "MAX_ETA", "ATAN32_MAX_ERROR",
           "GRID", "DOUBT", "in_doubt32", "sincos_2pi32", "warp_polar32", "warp_cosine_hemisphere32", "emit_given32", "emit_block32", "emit_side32", "guess_bin32",
           "frame32"]

F = np.float32
ZERO = F(0.0)
ONE = F(1.0)
TWO = F(2.0)
FOUR = F(4.0)
HALF = F(0.5)
PI = F(math.pi)
HALF_PI = F(0.5 * math.pi)
TWO_PI = F(2.0 * math.pi)
TINY = F(1e-30)
_TINY2 = F(1e-30)   # |v|^2 below: the float32 squares may have lost their precision -> exact lookup
_HUGE2 = F(1e30)    # |v|^2 above: may overflow -> exact lookup

from virtual.kernel_codes import ATAN32_MAX_ERROR, MAX_ETA, MAX_PHONG_EXPONENT, MIN_ALPHA  # noqa: E402

#: The float32 uniforms' grid (:func:`~virtual.kernels.xoshiro.fill_uniforms32`: k 2^-24, k < 2^24).
GRID = F(2.0 ** -24)
#: Half-width of the band around a decision's threshold within which :func:`in_doubt32` defers
#: to float64: four grid cells, covering the threshold's own float32 rounding (a sum of two
#: rounded parameters, a product of rounded factors: a few units of 2^-24 near 1).
DOUBT = F(4.0 * 2.0 ** -24)


# sin and cos of x in [-pi/4, pi/4]: Taylor to x^7 and x^8, truncation below 4e-9 (float32 ulp 6e-8)
_S3, _S5, _S7 = F(-1.0 / 6.0), F(1.0 / 120.0), F(-1.0 / 5040.0)
_C2, _C4, _C6, _C8 = F(-0.5), F(1.0 / 24.0), F(-1.0 / 720.0), F(1.0 / 40320.0)

# atan(t)/t on [0, 1], least squares in t^2 (degree 7): 1.8e-7 rad evaluated in float32 (tested)
_A0, _A1, _A2, _A3 = F(0.9999999403953552), F(-0.33332303166389465), F(0.1997368037700653), F(-0.14040134847164154)
_A4, _A5, _A6, _A7 = F(0.09967909753322601), F(-0.06021890789270401), F(0.02475660853087902), F(-0.004831115715205669)
# ATAN32_MAX_ERROR (virtual.kernel_codes): the largest error of the float32 polynomial atan2 below.


@jit(inline="llvm")
def in_doubt32(u, num, den):
    """Whether the decision ``u den < num`` (u a grid uniform, den >= 0; the probability
    num/den) may turn on bits of u below the 2^-24 grid: num/den within :data:`DOUBT` of u.

    A grid uniform resolves a probability p only to ceil(p 2^24) 2^-24 -- any p below 6e-8
    would happen with probability 6e-8. The kernels decide such rays again in float64 with u
    refined to 53 bits (:mod:`virtual.kernels.refine`): about 8 in 10^7 decisions, and every
    other decision is the same for any refinement of u, so each decision happens with its
    probability to 2^-53 (up to the float32 rounding of num/den itself, a relative few 1e-7)."""
    return abs(u * den - num) <= DOUBT * den


@jit(inline="llvm")
def sincos_2pi32(u):
    """``(cos 2 pi u, sin 2 pi u)`` in float32 for u in [0, 1): the float64
    :func:`~virtual.kernels.warps.sincos_2pi` with float32 polynomials (error < 2e-7)."""
    t = FOUR * u
    q = np.floor(t + HALF)
    x = (t - q) * HALF_PI
    x2 = x * x
    s = x * (ONE + x2 * (_S3 + x2 * (_S5 + x2 * _S7)))
    c = ONE + x2 * (_C2 + x2 * (_C4 + x2 * (_C6 + x2 * _C8)))
    quarter = int32(q) & 3
    odd = (quarter & 1) == 1
    cq = s if odd else c
    sq = c if odd else s
    cq = -cq if (quarter == 1 or quarter == 2) else cq
    sq = -sq if quarter >= 2 else sq
    return cq, sq


@jit(inline="llvm")
def warp_polar32(u1, u2, r):
    """Eq. 3.4: (rho cos phi, rho sin phi) with phi = 2 pi u1, rho = r sqrt(u2)."""
    c, s = sincos_2pi32(u1)
    rho = r * math.sqrt(u2)
    return rho * c, rho * s


@jit(inline="llvm")
def warp_cosine_hemisphere32(u1, u2):
    """Malley's method: z = sqrt(1 - u2) from u2 directly (never from rho)."""
    x, y = warp_polar32(u1, u2, ONE)
    return x, y, math.sqrt(ONE - u2)


@jit(inline="llvm")
def emit_given32(conical, b, u1, u2, u3, u4):
    """:func:`~virtual.kernels.emit.emit_given` in float32 (``b`` a tuple of float32)."""
    x1, y1 = warp_polar32(u1, u2, b[B_EMITTER_RADIUS])
    x2, y2 = warp_polar32(u3, u4, b[B_SPECIMEN_RADIUS])
    d = b[B_DISTANCE]
    ox = b[0] * x1 + b[1] * y1 + b[2] * d - x2
    oy = b[3] * x1 + b[4] * y1 + b[5] * d - y2
    oz = b[6] * x1 + b[7] * y1 + b[8] * d
    inv = ONE / math.sqrt(ox * ox + oy * oy + oz * oz)
    wx = ox * inv
    wy = oy * inv
    wz = oz * inv
    hit = wz * b[B_AXIS_Z] > ZERO
    return (wx if conical else b[B_AXIS_X]), (wy if conical else b[B_AXIS_Y]), (wz if conical else b[B_AXIS_Z]), (hit if conical else True)


@jit(inline="always")
def emit_block32(conical, b, u, bo, n, wx, wy, wz, hit):
    """:func:`emit_given32` for the block's first ``n`` rays, from its first four rows of uniforms
    (``bo`` rays apart; 0 for a collimated beam): the directions into ``wx, wy, wz``, ``hit[i]``
    1 or 0. A loop of its own, before the specimen's: the beam's dependency chain (a sine and
    cosine, two disk radii, a square root and a division) added to the specimen's made one loop
    body longer than the core's reorder window holds iterations, so the loop ran at its latency
    rather than its throughput."""
    for i in range(n):
        wx[i], wy[i], wz[i], h = emit_given32(conical, b, u[i], u[bo + i], u[2 * bo + i], u[3 * bo + i])
        hit[i] = h


@jit(inline="llvm")
def emit_side32(conical, b, u1, u2):
    """What a Lambertian needs of :func:`emit_given32`: the z of the direction toward the source
    before normalization (the sign of its ``wz``: the normalization is by a positive factor) and
    whether the ray hits -- the same decisions, without the second disk point (z of the specimen
    point is 0), the square root and the division. u3, u4 are drawn all the same."""
    x1, y1 = warp_polar32(u1, u2, b[B_EMITTER_RADIUS])
    oz = b[6] * x1 + b[7] * y1 + b[8] * b[B_DISTANCE]
    return (oz if conical else b[B_AXIS_Z]), ((oz * b[B_AXIS_Z] > ZERO) if conical else True)


@jit(inline="llvm")
def _atan_first_quadrant32(ay, ax):
    swap = ay > ax
    t = min(ax, ay) / max(max(ax, ay), TINY)
    t2 = t * t
    a = t * (_A0 + t2 * (_A1 + t2 * (_A2 + t2 * (_A3 + t2 * (_A4 + t2 * (_A5 + t2 * (_A6 + t2 * _A7)))))))
    return HALF_PI - a if swap else a


@jit(inline="llvm")
def _phi32(x, y):
    a = _atan_first_quadrant32(abs(y), abs(x))
    a = PI - a if x < ZERO else a
    return TWO_PI - a if y < ZERO else a


@jit(inline="llvm")
def guess_bin32(x, y, z, scheme_code, n_theta, n_phi, ring_margin, sector_margin):
    """:func:`~virtual.kernels.patch_lookup.guess_bin` in float32: the bin of (x, y, z), or -1 when
    it lies within the margins (:func:`virtual.collector.guess_margins32`) of an edge, at the
    pole or with badly scaled squares -- then the float64 ``patch_of`` decides."""
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    s2 = min(rho2 / r2, ONE)
    nt = F(n_theta)
    if scheme_code == SCHEME_EQUAL_PSA:  # sin^2 theta is the ring coordinate
        g = s2 * nt
    elif scheme_code == SCHEME_EQUAL_SOLID_ANGLE:  # 1 - cos theta
        g = (ONE - abs(z) / math.sqrt(r2)) * nt
    else:  # equal angle
        g = _atan_first_quadrant32(math.sqrt(rho2), abs(z)) * (nt / HALF_PI)
    k = min(int32(g), int32(n_theta - 1))
    fk = g - F(k)
    f = _phi32(x, y) * (F(n_phi) / TWO_PI)
    j = min(int32(f), int32(n_phi - 1))
    fj = f - F(j)
    sure = ((fk > ring_margin) & (fk < ONE - ring_margin) & (fj > sector_margin) & (fj < ONE - sector_margin)
            & (rho2 > _TINY2) & (r2 < _HUGE2))
    b = k * n_phi + j + (n_theta * n_phi) * (z < ZERO)
    return b if sure else -1


@jit(inline="llvm")
def frame32(nx, ny, nz):
    """:func:`~virtual.kernels.microfacet.frame` (Duff et al. 2017) in float32."""
    sign = ONE if nz >= ZERO else -ONE
    a = -ONE / (sign + nz)
    b = nx * ny * a
    return (ONE + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)
