"""Sampling points on the emitter and specimen (seed section 3.1.2, eqs. 3.3, 3.4, 3.10, 3.11).

Two layers, one formula each:

* scalar warps (``@njit``) that turn uniforms in [0, 1) into points; the ray kernels call them
  inline, and
* array samplers for analysis, plotting and tests, which draw the uniforms by a *strategy*
  (independent random, jittered/stratified, scrambled Sobol) and apply the same warps.

Strategies on the disk: ``"rejection"`` (eq. 3.3: points in the square of side 2r, those
outside the disk thrown away), ``"polar"`` (eq. 3.4 gives (phi, r') = (2 pi xi1, r sqrt(xi2));
the point is x = r' cos phi, y = r' sin phi), ``"jittered"`` (polar warp of one jittered
uniform per stratum) and ``"sobol"`` (polar warp of scrambled Sobol points, scipy.stats.qmc).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numba import int64, njit

from bench.core.errors import InputError
from virtual.rng import next_double

__all__ = [
    "DISK_STRATEGIES",
    "warp_square",
    "warp_polar",
    "sincos_2pi",
    "warp_triangle",
    "uniforms",
    "sample_disk",
    "sample_triangle",
    "sample_quad",
    "warp_cosine_hemisphere",
    "sample_cosine_hemisphere",
]

DiskStrategy = Literal["rejection", "polar", "jittered", "sobol"]
DISK_STRATEGIES: tuple[str, ...] = ("rejection", "polar", "jittered", "sobol")
UNIFORM_STRATEGIES: tuple[str, ...] = ("random", "jittered", "sobol")

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


@njit(inline="always", cache=True)
def warp_square(u1, u2, r):
    """Eq. 3.3: a point in the square [-r, r]^2 (to be rejected outside the disk)."""
    return r * (2.0 * u1 - 1.0), r * (2.0 * u2 - 1.0)


@njit(inline="always", cache=True)
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


@njit(inline="always", cache=True)
def warp_polar(u1, u2, r):
    """Eq. 3.4 done right: (phi, rho) = (2 pi u1, r sqrt(u2)) -> (rho cos phi, rho sin phi)."""
    c, s = sincos_2pi(u1)
    rho = r * math.sqrt(u2)
    return rho * c, rho * s


@njit(inline="always", cache=True)
def warp_triangle(u3, u4):
    """Eq. 3.11 (Shirley): barycentric (x', y') uniform on the triangle for uniforms u3, u4."""
    xp = 1.0 - math.sqrt(1.0 - u3)
    return xp, (1.0 - xp) * u4


@njit(cache=True)
def _warp_polar_array(u, r, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = warp_polar(u[i, 0], u[i, 1], r)


@njit(cache=True)
def _warp_triangle_array(u, out):
    for i in range(u.shape[0]):
        out[i, 0], out[i, 1] = warp_triangle(u[i, 0], u[i, 1])


def _rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def uniforms(n: int, strategy: str = "random", seed: int | np.random.Generator | None = None) -> np.ndarray:
    """``(n, 2)`` points in [0, 1)^2 by strategy ``random``, ``jittered`` or ``sobol``.

    ``jittered`` splits the square into an ``a x b`` grid with ``a*b >= n`` cells (a = ceil(sqrt n)),
    takes ``n`` distinct cells in random order and one uniform point in each; when ``n`` is a
    product ``a*b`` that is full stratification. ``sobol`` is Owen-scrambled Sobol
    (scipy.stats.qmc); its balance guarantees hold for powers of two.
    """
    if n < 0:
        raise InputError(f"number of samples must be >= 0, got {n}")
    rng = _rng(seed)
    if strategy == "random":
        return rng.random((n, 2))
    if strategy == "jittered":
        if n == 0:
            return np.empty((0, 2))
        a = math.isqrt(n - 1) + 1
        b = -(-n // a)
        cells = rng.permutation(a * b)[:n] if a * b != n else np.arange(n)
        ix, iy = cells % a, cells // a
        jitter = rng.random((n, 2))
        return np.column_stack(((ix + jitter[:, 0]) / a, (iy + jitter[:, 1]) / b))
    if strategy == "sobol":
        from scipy.stats import qmc

        engine = qmc.Sobol(d=2, scramble=True, seed=rng)
        m = max(0, math.ceil(math.log2(max(n, 1))))
        return engine.random_base2(m)[:n]
    raise InputError(f"unknown uniform strategy {strategy!r}; known: {', '.join(UNIFORM_STRATEGIES)}")


def sample_disk(n: int, radius: float = 1.0, strategy: str = "polar",
                seed: int | np.random.Generator | None = None) -> np.ndarray:
    """``(n, 2)`` points uniform on the disk of ``radius`` centred at the origin."""
    if not radius > 0 or not math.isfinite(radius):
        raise InputError(f"disk radius must be finite and > 0, got {radius}")
    rng = _rng(seed)
    if strategy == "rejection":
        out = np.empty((n, 2))
        filled = 0
        while filled < n:
            # acceptance pi/4: draw enough for the rest with margin, keep the points inside
            m = int((n - filled) * 1.35) + 16
            pts = radius * (2.0 * rng.random((m, 2)) - 1.0)  # eq. 3.3, vectorized
            pts = pts[np.einsum("ij,ij->i", pts, pts) < radius * radius]
            take = min(len(pts), n - filled)
            out[filled:filled + take] = pts[:take]
            filled += take
        return out
    if strategy == "polar":
        strategy = "random"
    if strategy not in UNIFORM_STRATEGIES:
        raise InputError(f"unknown disk sampling strategy {strategy!r}; known: {', '.join(DISK_STRATEGIES)}")
    u = uniforms(n, strategy, rng)
    out = np.empty((n, 2))
    _warp_polar_array(u, float(radius), out)
    return out


def sample_triangle(n: int, q0, q1, q2, strategy: str = "random",
                    seed: int | np.random.Generator | None = None) -> np.ndarray:
    """Eq. 3.10: ``q = q0 + x'(q1 - q0) + y'(q2 - q0)`` with (x', y') from eq. 3.11."""
    q0, q1, q2 = (np.asarray(q, dtype=float) for q in (q0, q1, q2))
    bary = np.empty((n, 2))
    _warp_triangle_array(uniforms(n, strategy, seed), bary)
    return q0 + bary[:, :1] * (q1 - q0) + bary[:, 1:] * (q2 - q0)


def sample_quad(n: int, half_width: float, seed: int | np.random.Generator | None = None) -> np.ndarray:
    """A square specimen of side ``2*half_width`` as the seed's pair of triangles (eq. 3.10).

    Each point picks one of the two equal-area triangles by a fair coin.
    """
    rng = _rng(seed)
    h = float(half_width)
    a, b, c, d = (-h, -h), (h, -h), (h, h), (-h, h)
    first = rng.random(n) < 0.5
    n1 = int(first.sum())
    out = np.empty((n, 2))
    out[first] = sample_triangle(n1, a, b, c, seed=rng)
    out[~first] = sample_triangle(n - n1, a, c, d, seed=rng)
    return out


@njit(inline="always", cache=True)
def warp_cosine_hemisphere(u1, u2):
    """Malley's method: the polar warp lifted to the unit hemisphere, pdf cos(theta)/pi.

    z = sqrt(1 - rho^2) = sqrt(1 - u2) is computed from u2 directly, never from rho, so it
    cannot round below 0 or above 1.
    """
    x, y = warp_polar(u1, u2, 1.0)
    return x, y, math.sqrt(1.0 - u2)


@njit(inline="always", cache=True)
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
