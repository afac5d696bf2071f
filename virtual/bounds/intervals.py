"""The one binomial confidence interval every device uses (Clopper-Pearson or Wilson)."""

from __future__ import annotations

import numpy as np

from bench.core.errors import BudgetError
from virtual.bounds._checks import check_delta, check_uncertainty

__all__ = ["binomial_ci", "CI_METHODS", "relative_patch_rays"]

CI_METHODS: tuple[str, ...] = ("clopper-pearson", "wilson")


def binomial_ci(k, n, delta: float, method: str = "clopper-pearson") -> tuple[np.ndarray, np.ndarray]:
    """Two-sided ``1 - delta`` confidence interval for a binomial proportion, vectorized.

    Parameters
    ----------
    k, n
        Success counts and trial counts: integers (Python, numpy int64 or arrays, broadcast
        against each other), ``0 <= k <= n``.
    delta
        Total miss probability in (0, 1): ``delta/2`` in each tail.
    method
        ``"clopper-pearson"`` (exact: coverage >= 1 - delta for every p; the default) or
        ``"wilson"`` (score interval: shorter, coverage ~1 - delta, not guaranteed).

    Returns
    -------
    (lo, hi)
        float64 arrays of the broadcast shape (0-d arrays for scalar input). Always finite with
        ``0 <= lo <= k/n <= hi <= 1``; ``lo == 0`` exactly at ``k == 0`` and ``hi == 1``
        exactly at ``k == n``. For ``n == 0`` (no rays: no information) the interval is
        ``(0, 1)``, the limit of both methods, so arrays with empty entries still work.

    Raises
    ------
    BudgetError
        For ``delta`` outside (0, 1), an unknown method, non-integer, negative or ``k > n``
        counts.
    """
    d = check_delta(delta)
    if method not in CI_METHODS:
        raise BudgetError(f"unknown binomial interval method {method!r}; known: {', '.join(CI_METHODS)}")
    k_arr, n_arr = np.asarray(k), np.asarray(n)
    for name, arr in (("k", k_arr), ("n", n_arr)):
        if arr.dtype.kind not in "iu":
            if arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
                continue  # integral floats (e.g. from a float expected count) are accepted
            raise BudgetError(f"binomial counts {name} must be integers, got dtype {arr.dtype}")
    kf, nf = np.broadcast_arrays(k_arr.astype(np.float64), n_arr.astype(np.float64))
    if np.any(nf < 0) or np.any(kf < 0) or np.any(kf > nf):
        bad = np.argwhere((nf < 0) | (kf < 0) | (kf > nf))[0]
        raise BudgetError(
            f"binomial counts need 0 <= k <= n, got k={kf[tuple(bad)]:.0f}, n={nf[tuple(bad)]:.0f}"
        )
    from scipy import special  # ~0.4 s to import: loaded by the callers of an interval, not by `bench rays`

    empty = nf == 0
    nn = np.where(empty, 1.0, nf)
    kk = np.where(empty, 0.0, kf)
    if method == "clopper-pearson":
        # lo = Beta^-1(delta/2; k, n-k+1), hi = Beta^-1(1-delta/2; k+1, n-k); edges set exactly.
        with np.errstate(all="ignore"):
            lo = special.betaincinv(np.maximum(kk, 1.0), nn - kk + 1.0, d / 2.0)
            hi = special.betaincinv(kk + 1.0, np.maximum(nn - kk, 1.0), 1.0 - d / 2.0)
        lo = np.where(kk == 0, 0.0, lo)
        hi = np.where(kk == nn, 1.0, hi)
    else:
        z = float(-special.ndtri(d / 2.0))  # scipy.stats.norm.isf(q) is -ndtri(q), without importing scipy.stats
        z2 = z * z
        centre = (kk + z2 / 2.0) / (nn + z2)
        half = z / (nn + z2) * np.sqrt(kk * (nn - kk) / nn + z2 / 4.0)
        lo = np.where(kk == 0, 0.0, np.clip(centre - half, 0.0, 1.0))
        hi = np.where(kk == nn, 1.0, np.clip(centre + half, 0.0, 1.0))
    p_hat = kk / nn
    lo = np.minimum(lo, p_hat)  # guard the last ulp so that lo <= p_hat <= hi always holds
    hi = np.maximum(hi, p_hat)
    lo = np.where(empty, 0.0, lo)
    hi = np.where(empty, 1.0, hi)
    return lo, hi


def relative_patch_rays(p: np.ndarray, uncertainty: float, delta: float, max_rays: int | None = None
                        ) -> dict[str, object]:
    """Rays for a *relative* uncertainty of every patch's BSDF (``bench gonio --relative-uncertainty``).

    A patch's BSDF is ``k / (N psa)`` with ``k ~ Binomial(N, p)``, so its relative standard error
    is ``sqrt((1 - p) / (N p))``: the least-populated patch decides. With ``p`` the estimated
    probabilities of the patches of interest (e.g. from a pilot run) and
    ``z = Phi^-1(1 - delta / 2)`` (the two-sided ``1 - delta`` interval every patch of a record
    carries), ``N = ceil(z^2 (1 - p_min) / (v^2 p_min))`` makes each patch's interval
    half-width at most about ``v`` times its value (normal approximation). With ``max_rays``, patches that would need more are
    listed as ``unreachable`` (their indices into ``p``) and N is capped.

    Returns
    -------
    dict
        ``N``, ``z``, ``p_min``, ``needed`` (rays the dimmest patch needs), ``unreachable``
        (indices), ``capped`` (bool).
    """
    v = check_uncertainty(uncertainty)
    d = check_delta(delta)
    p = np.asarray(p, dtype=float)
    if p.size == 0 or not np.all(p > 0):
        raise BudgetError("relative_patch_rays needs patch probabilities > 0 (patches that received rays)")
    from scipy import special  # see binomial_ci

    z = float(-special.ndtri(d / 2.0))  # scipy.stats.norm.isf(d / 2)
    need = np.ceil(z * z * (1.0 - p) / (v * v * p))
    n = int(need.max())
    unreachable = np.flatnonzero(need > max_rays) if max_rays is not None else np.array([], dtype=int)
    capped = max_rays is not None and n > max_rays
    return {"N": int(min(n, max_rays)) if capped else n, "z": z, "p_min": float(p.min()), "needed": n,
            "unreachable": unreachable.tolist(), "capped": bool(capped)}
