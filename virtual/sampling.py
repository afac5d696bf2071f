"""Sampling points on the emitter and specimen (seed section 3.1.2, eqs. 3.3, 3.4, 3.10, 3.11).

Two layers, one formula each:

* scalar warps (kernels of :mod:`virtual.kernels.warps`, re-exported here) that turn uniforms
  in [0, 1) into points; the ray kernels call them inline, and
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

from bench.core.errors import InputError
from virtual.kernels.warps import _warp_polar_array, _warp_triangle_array

__all__ = ["DISK_STRATEGIES", "uniforms", "sample_disk", "sample_triangle"]

DiskStrategy = Literal["rejection", "polar", "jittered", "sobol"]
DISK_STRATEGIES: tuple[str, ...] = ("rejection", "polar", "jittered", "sobol")
UNIFORM_STRATEGIES: tuple[str, ...] = ("random", "jittered", "sobol")

_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi


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


