"""Collector-sphere lookup kernels: which patch a direction falls in (see :mod:`virtual.collector`
for the bin numbering and the exact lookup rules these kernels implement).

:func:`patch_of` is exact; :func:`guess_bin` is the branch-free guess of the block kernel, sure
or ``-1`` (its margins come from :func:`virtual.collector.guess_margins`).
"""

from __future__ import annotations

import math

from numba import int64

from virtual.kernels import jit

__all__ = ["SCHEME_EQUAL_ANGLE", "SCHEME_EQUAL_SOLID_ANGLE", "SCHEME_EQUAL_PSA", "ATAN_MAX_ERROR",
           "patch_of", "guess_bin"]

from virtual.kernel_codes import ATAN_MAX_ERROR, SCHEME_EQUAL_ANGLE, SCHEME_EQUAL_PSA, SCHEME_EQUAL_SOLID_ANGLE

_TWO_PI = 2.0 * math.pi
_SCALE_UP = 2.0 ** 600     # brings any tiny component (>= 2^-1074) to >= 2^-474: squares stay normal
_SCALE_DOWN = 2.0 ** -600  # brings any huge finite component (< 2^1024) below 2^424
_INF_AFTER_SCALING = 1e300  # no finite component exceeds 2^424 after scaling: larger means infinite
_HALF_PI = 0.5 * math.pi
_TINY2 = 1e-280  # |v|^2 below: squares may have underflowed -> rescale
_HUGE2 = 1e280   # |v|^2 above: squares may overflow -> rescale

# ATAN_MAX_ERROR (virtual.kernel_codes): the largest error of :func:`_atan_first_quadrant`; the
# margin of :func:`guess_bin` is built on it.


@jit(inline="llvm")
def _atan_first_quadrant(ay, ax):
    """atan2(ay, ax) for ay, ax >= 0 to within :data:`ATAN_MAX_ERROR`, branch-free (0 at 0, 0).

    A least-squares Chebyshev fit of atan(t)/t in t^2 on [0, 1] (degree 8), reflected about
    pi/4 when ay > ax. Only ever a guess: callers correct it exactly or keep a margin.
    """
    swap = ay > ax
    t = min(ax, ay) / max(max(ax, ay), 1e-300)
    t2 = t * t
    a = t * (0.9999999937545597 + t2 * (-0.333331379749331 + t2 * (0.1999369427101566 + t2 * (
        -0.14211105401882718 + t2 * (0.10667483516144449 + t2 * (-0.07556891451298485 + t2 * (
            0.04327812177624217 + t2 * (-0.016413106968129587 + t2 * 0.002932738774815436))))))))
    return _HALF_PI - a if swap else a



@jit(inline="llvm")
def _approx_phi(x, y):
    """atan2(y, x) taken into [0, 2 pi), to within :data:`ATAN_MAX_ERROR` (a guess only)."""
    a = _atan_first_quadrant(abs(y), abs(x))
    a = math.pi - a if x < 0.0 else a
    return _TWO_PI - a if y < 0.0 else a



@jit(inline="llvm")
def _ring_guess(s2, az, rho2, r2, scheme_code, n_theta):
    """The ring coordinate (ring index + fraction) of a direction by the scheme's closed form."""
    if scheme_code == SCHEME_EQUAL_PSA:
        return s2 * n_theta
    if scheme_code == SCHEME_EQUAL_SOLID_ANGLE:
        return (1.0 - az / math.sqrt(r2)) * n_theta
    return _atan_first_quadrant(math.sqrt(rho2), az) * (n_theta / _HALF_PI)



@jit(inline="llvm")
def _patch_core(x, y, z, rho2, r2, scheme_code, n_theta, n_phi, sin2_edges, phi_cs):
    az = abs(z)
    s2 = rho2 / r2
    if s2 > 1.0:
        s2 = 1.0
    # --- ring: closed-form guess, then exact correction against the stored edges
    g = _ring_guess(s2, az, rho2, r2, scheme_code, n_theta)
    if not (g >= 0.0):
        g = 0.0
    k = int(g)
    if k > n_theta - 1:
        k = n_theta - 1
    while k > 0 and s2 < sin2_edges[k]:
        k -= 1
    while k < n_theta - 1 and s2 >= sin2_edges[k + 1]:
        k += 1
    # --- sector: guess from a polynomial atan2 (error < 1.4e-8 rad), then exact correction by
    # the sign of the cross product with the stored edge vectors (cos phi_j, sin phi_j)
    j = 0
    if rho2 > 0.0 and n_phi > 1:
        if n_phi == 2:
            if y < 0.0 or (y == 0.0 and x < 0.0):
                j = 1
        else:
            f = _approx_phi(x, y) * (n_phi / _TWO_PI)
            if not (f >= 0.0):
                f = 0.0
            j = int(f)
            if j > n_phi - 1:
                j = n_phi - 1
            for _ in range(n_phi):
                if phi_cs[j, 0] * y - phi_cs[j, 1] * x < 0.0:  # v before edge j
                    j = j - 1 if j > 0 else n_phi - 1
                elif phi_cs[j + 1, 0] * y - phi_cs[j + 1, 1] * x >= 0.0:  # v at/after edge j+1
                    j = j + 1 if j < n_phi - 1 else 0
                else:
                    break
    return k * n_phi + j + (n_theta * n_phi) * (z < 0.0)



@jit
def _patch_of_rare(x, y, z, scheme_code, n_theta, n_phi, sin2_edges, phi_cs):
    """Slow path of :func:`patch_of`: rescale, or map zero/NaN to bin 0 and infinities to axes.

    Written to stay right under the kernels' fastmath flags (:data:`virtual.kernels.FASTMATH`:
    ``nnan``, ``ninf``): no comparison with infinity (``ninf`` lets LLVM fold it away), NaN
    caught by ``not (m > 0)`` before any arithmetic.
    """
    m = max(abs(x), max(abs(y), abs(z)))
    if not (m > 0.0):  # zero vector or NaN
        return 0
    below = z < 0.0  # the hemisphere is the sign of z, even when scaling flushes a tiny z to -0
    # exact power-of-two rescaling: tiny components become normal, huge finite ones moderate
    f = _SCALE_UP if m < 1.0 else _SCALE_DOWN
    x = x * f
    y = y * f
    z = z * f
    if max(abs(x), max(abs(y), abs(z))) > _INF_AFTER_SCALING:  # only an infinity stays this large
        x = math.copysign(1.0, x) if abs(x) > _INF_AFTER_SCALING else 0.0
        y = math.copysign(1.0, y) if abs(y) > _INF_AFTER_SCALING else 0.0
        z = math.copysign(1.0, z) if abs(z) > _INF_AFTER_SCALING else 0.0
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    if not (r2 > 0.0):
        return 0
    b = _patch_core(x, y, z, rho2, r2, scheme_code, n_theta, n_phi, sin2_edges, phi_cs)
    half = n_theta * n_phi
    return b + half if below and b < half else b



@jit(inline="llvm")
def patch_of(x, y, z, scheme_code, n_theta, n_phi, sin2_edges, phi_cs):
    """Bin index in ``[0, 2 n_theta n_phi)`` of the direction ``(x, y, z)`` (any length).

    Parameters
    ----------
    x, y, z : float
        The outgoing direction; need not be normalized.
    scheme_code : int
        ``SCHEMES[scheme]``; only used for the closed-form first guess of the ring.
    n_theta, n_phi : int
        Rings and sectors per hemisphere.
    sin2_edges : float64[n_theta + 1]
        ``sin^2`` of the zenith edges, ``sin2_edges[0] = 0``, ``sin2_edges[-1] = 1``
        (:attr:`Collector.sin2_edges`).
    phi_cs : float64[n_phi + 1, 2]
        ``(cos, sin)`` of the azimuth edges (:attr:`Collector.phi_cs`), exact at quarter turns.

    Returns
    -------
    int
        See the module docstring for the numbering and for the pole/horizon/degenerate rules.
    """
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    if not (r2 > _TINY2 and r2 < _HUGE2):  # rare: squares under/overflow, zero, inf, NaN
        return _patch_of_rare(x, y, z, scheme_code, n_theta, n_phi, sin2_edges, phi_cs)
    return _patch_core(x, y, z, rho2, r2, scheme_code, n_theta, n_phi, sin2_edges, phi_cs)



@jit(inline="llvm")
def guess_bin(x, y, z, scheme_code, n_theta, n_phi, ring_margin, sector_margin):
    """:func:`patch_of` without table look-ups or branches, for vectorized kernels: the bin,
    or -1 when the answer is not certain (then call :func:`patch_of`).

    The ring and sector coordinates come from the closed forms (:func:`_ring_guess`,
    :func:`_approx_phi`); when both lie farther than ``ring_margin`` / ``sector_margin``
    (:meth:`Collector.guess_margins`, bounds on their errors) from an edge, the bin is the one
    :func:`patch_of` returns. Poles, the horizon, edges and non-finite or badly scaled vectors
    all come back as -1 -- a few rays in a million for fine collectors.
    """
    rho2 = x * x + y * y
    r2 = rho2 + z * z
    g = _ring_guess(min(rho2 / r2, 1.0), abs(z), rho2, r2, scheme_code, n_theta)
    k = min(int64(g), n_theta - 1)
    fk = g - k
    f = _approx_phi(x, y) * (n_phi / _TWO_PI)
    j = min(int64(f), n_phi - 1)
    fj = f - j
    sure = ((fk > ring_margin) & (fk < 1.0 - ring_margin) & (fj > sector_margin) & (fj < 1.0 - sector_margin)
            & (rho2 > _TINY2) & (r2 < _HUGE2))
    b = k * n_phi + j + (n_theta * n_phi) * (z < 0.0)
    return b if sure else -1



@jit
def index_many(dirs, scheme_code, n_theta, n_phi, sin2_edges, phi_cs, out):
    for i in range(dirs.shape[0]):
        out[i] = patch_of(dirs[i, 0], dirs[i, 1], dirs[i, 2], scheme_code, n_theta, n_phi, sin2_edges,
                          phi_cs)
