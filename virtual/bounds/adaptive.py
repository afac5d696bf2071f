"""The variance-adaptive sequential stopping rule: plans (checkpoints, thresholds, their
certification) and :func:`run_adaptive`; its guarantee is stated in :mod:`virtual.bounds`."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from bench.core.errors import BudgetError
from virtual.bounds._checks import check_delta, check_patches, check_uncertainty
from virtual.bounds.hoeffding import hoeffding_per_patch
from virtual.bounds.intervals import binomial_ci

__all__ = ["AdaptivePlan", "AdaptiveResult", "adaptive_plan", "run_adaptive", "CHECKPOINT_RATIO"]


#: geometric ratio between consecutive checkpoints of the adaptive rule
CHECKPOINT_RATIO = 1.2
#: cell width of the partition of [0, 1/2] used to certify a plan, as a fraction of v
_CELL_FRACTION = 1.0 / 16.0
#: certify only when cells x checkpoints stays below this (about v >= 5e-4); else union mode
_CERTIFY_MAX_WORK = 700_000
#: a certified plan must keep its bound below this fraction of delta/m (margin for the
#: rounding of scipy's binomial tails, which are accurate to ~1e-14 relative)
_CERTIFY_MARGIN = 0.999
#: binomial tails whose Chernoff bound is below this are not evaluated exactly
_NEGLIGIBLE = 1e-20


@dataclass(frozen=True)
class AdaptivePlan:
    """Checkpoint schedule of the adaptive rule (see :func:`adaptive_plan`).

    Attributes
    ----------
    uncertainty, delta, patches
        The request: ``v``, overall failure probability, number of patches ``m``.
    mode
        ``"certified"`` or ``"union"`` (how the guarantee is proved; see :func:`adaptive_plan`).
    checkpoints
        Cumulative ray counts at which the rule looks; strictly increasing, the last is ``cap``.
    alphas
        Per-checkpoint, per-patch two-sided Clopper-Pearson level used to decide stopping; the
        cap's entry is the Hoeffding level eq. 3.5 is evaluated at there.
    lower_stop
        Certified mode: stop thresholds ``L_k`` (a patch count ``c`` at checkpoint ``k`` is
        settled iff ``c <= L_k`` or ``c >= n_k - L_k``; ``-1`` = nothing settles; the cap's entry
        is ``n_K``). ``None`` in union mode, where the interval is computed at run time.
    cap
        Ray count at which the rule stops whatever it saw.
    hoeffding_N
        Eq. 3.5 (``patches=1``) / eq. 3.12 for the request, for comparison.
    failure_bound
        Proven upper bound on ``P(exists j: |p_hat_j - p_j| > v)``; ``<= delta``.
    """

    uncertainty: float
    delta: float
    patches: int
    mode: str
    checkpoints: tuple[int, ...]
    alphas: tuple[float, ...]
    lower_stop: tuple[int, ...] | None
    cap: int
    hoeffding_N: int
    failure_bound: float

    @property
    def patch_delta(self) -> float:
        """Failure probability allowed per patch, ``delta / patches`` (union bound)."""
        return self.delta / self.patches

    def settled(self, index: int, counts: np.ndarray) -> np.ndarray:
        """Which patch ``counts`` (cumulative, at checkpoint ``index``) may stop the rule there."""
        n = self.checkpoints[index]
        c = np.asarray(counts)
        if index == len(self.checkpoints) - 1:
            return np.ones(c.shape, dtype=bool)
        if self.lower_stop is not None:
            L = self.lower_stop[index]
            return (c <= L) | (c >= n - L)
        lo, hi = binomial_ci(c, n, self.alphas[index])
        p_hat = c / n
        return (hi - p_hat <= self.uncertainty) & (p_hat - lo <= self.uncertainty)


def _cp_fits(c: np.ndarray, n: np.ndarray, alpha: float, v: float) -> np.ndarray:
    lo, hi = binomial_ci(c, n, alpha)
    p_hat = c / n
    return (hi - p_hat <= v) & (p_hat - lo <= v)


def _lower_thresholds(ns: np.ndarray, alpha: float, v: float) -> np.ndarray:
    """Largest count ``c <= n/2`` whose Clopper-Pearson interval lies within ``c/n +- v``.

    Bisection on ``c`` (the interval's half-widths grow with ``c`` up to ``n/2``). Should that
    monotonicity fail somewhere the guarantee is unaffected: certification analyses the
    threshold sets themselves, not the intervals.
    """
    ns = np.asarray(ns, dtype=np.float64)
    lo = np.full(ns.shape, -1.0)
    hi = np.floor(ns / 2.0) + 1.0
    while np.any(hi - lo > 1):
        mid = np.floor((lo + hi) / 2.0)
        fit = _cp_fits(np.maximum(mid, 0.0), ns, alpha, v) & (mid >= 0)
        active = hi - lo > 1
        lo = np.where(active & fit, mid, lo)
        hi = np.where(active & ~fit, mid, hi)
    return lo


def _chernoff_tail(t: np.ndarray, n: np.ndarray, p: np.ndarray, lower: bool) -> np.ndarray:
    """Upper bound on ``P_p(X <= t)`` (``lower``) or ``P_p(X >= t)``, X ~ Binomial(n, p).

    Chernoff: ``exp(-n kl(t/n || p))`` on the tail side of the mean, 1 on the other, and the
    exact 0 / 1 outside ``[0, n]``. Arrays broadcast.
    """
    t, n, p = np.broadcast_arrays(np.asarray(t, dtype=np.float64), np.asarray(n, dtype=np.float64),
                                  np.asarray(p, dtype=np.float64))
    from scipy import special  # ~0.4 s to import: only where a plan is certified or run, not for `bench rays`

    q = t / n
    with np.errstate(all="ignore"):
        kl = special.rel_entr(q, p) + special.rel_entr(1.0 - q, 1.0 - p)  # inf outside [0, 1]
        chernoff = np.exp(-n * kl)
    if lower:
        return np.where(t < 0, 0.0, np.where(t >= n, 1.0, np.where(q < p, chernoff, 1.0)))
    return np.where(t <= 0, 1.0, np.where(t > n, 0.0, np.where(q > p, chernoff, 1.0)))


def _exact_tail(t: np.ndarray, n: np.ndarray, p: np.ndarray, lower: bool, mask: np.ndarray) -> np.ndarray:
    """The exact tail (scipy) at the entries of ``mask``; NaN elsewhere."""
    t, n, p = np.broadcast_arrays(np.asarray(t, dtype=np.float64), np.asarray(n, dtype=np.float64),
                                  np.asarray(p, dtype=np.float64))
    from scipy import stats  # ~1.5 s to import: only when an exact tail is needed

    out = np.full(t.shape, np.nan)
    if lower:
        out[mask] = stats.binom.cdf(t[mask], n[mask], p[mask])
    else:
        out[mask] = stats.binom.sf(t[mask] - 1.0, n[mask], p[mask])
    return out


def _tail(t, n, p, lower: bool, cond=None) -> np.ndarray:
    """``_chernoff_tail``, replaced by the exact tail wherever the bound is not negligible
    (and ``cond`` holds; entries outside ``cond`` are 0)."""
    bound = _chernoff_tail(t, n, p, lower)
    if cond is not None:
        bound = np.where(cond, bound, 0.0)
    need = (bound > _NEGLIGIBLE) & (bound < 1.0)
    if need.any():
        bound = np.where(need, _exact_tail(t, n, p, lower, need), bound)
    return bound


def _min_tails(first: tuple, second: tuple, cond: np.ndarray) -> np.ndarray:
    """``min`` of two tail bounds (each ``(t, n, p, lower)``) where ``cond``, else 0; exact
    tails are evaluated only where the smaller Chernoff bound is not negligible."""
    bound = np.where(cond, np.minimum(_chernoff_tail(*first), _chernoff_tail(*second)), 0.0)
    need = bound > _NEGLIGIBLE
    if need.any():
        exact = np.minimum(_exact_tail(*first, need), _exact_tail(*second, need))
        bound = np.where(need, exact, bound)
    return bound


def _certify(ns: np.ndarray, L: np.ndarray, cap: int, v: float, limit: float | None = None) -> float:
    """Upper bound, uniform in ``p``, on one patch's failure probability under a threshold plan.

    For one patch with probability ``p`` and counts ``X_k ~ Binomial(n_k, p)`` (any dependence
    between checkpoints), failure ``|X/n - p| > v`` at the stopping point implies, for some
    checkpoint ``k``, ``X_k`` in the stop set ``{<= L_k} u {>= n_k - L_k}`` with
    ``|X_k/n_k - p| > v``, or failure at the cap. The probability is at most
    ``F(p) = sum_k P_p(X_k in S_k, |X_k/n_k - p| > v) + P_p(|X_K/n_K - p| > v)``.
    ``[0, 1/2]`` is cut into cells ``[a, b]`` of width ``v/16``; on a cell, ``{X < n(p - v)}``
    is contained in ``{X <= t_b}`` and ``{X > n(p + v)}`` in ``{X >= s_a}`` with fixed integers,
    ``P_p(X <= t)`` decreases and ``P_p(X >= s)`` increases in ``p``, so each term is bounded
    by binomial tails at the cell's ends (exact, or a Chernoff bound where that is below 1e-20;
    see ``_tail``). The design is symmetric (``X -> n - X``, ``p -> 1 - p``), which covers
    ``[1/2, 1]``. Returns ``max`` over cells of the bound.

    With ``limit``, every 8th cell is tried first and, if one of them already exceeds
    ``limit``, that (partial) maximum is returned: the full maximum exceeds it too.
    """
    w = v * _CELL_FRACTION
    m = max(1, math.ceil(0.5 / w))
    a_all = np.minimum(np.arange(m) * w, 0.5)
    passes = [np.arange(0, m, 8), np.arange(m)] if limit is not None and m > 64 else [np.arange(m)]
    worst = 0.0
    for cells in passes:
        a = a_all[cells]
        b = np.minimum(a + w, 0.5)
        n_all = np.append(np.asarray(ns, dtype=np.float64), float(cap))[:, None]
        # largest integer < n(b - v), rounded up; smallest integer > n(a + v), rounded down
        t_b = np.maximum(np.floor(n_all * (b - v) * (1 + 1e-12) + 1e-9), -1.0)
        s_a = np.ceil(n_all * (a + v) * (1 - 1e-12) - 1e-9)

        total = np.zeros(len(cells))
        if len(ns):
            n = n_all[:-1]
            Lk = np.asarray(L, dtype=np.float64)[:, None]
            Uk = n - Lk
            tb, sa = t_b[:-1], s_a[:-1]
            # settled low (X <= L): too low (X <= t_b), or too high (s_a <= X <= L)
            low_set = _tail(np.minimum(Lk, tb), n, a, True) + _min_tails(
                (Lk, n, a, True), (sa, n, b, False), sa <= Lk)
            # settled high (X >= U): too high (X >= s_a), or too low (U <= X <= t_b)
            high_set = _tail(np.maximum(Uk, sa), n, b, False) + _min_tails(
                (Uk, n, b, False), (tb, n, a, True), tb >= Uk)
            total += np.minimum(low_set + high_set, 1.0).sum(axis=0)
        ncap = n_all[-1]
        total += np.minimum(_tail(t_b[-1], ncap, a, True) + _tail(s_a[-1], ncap, b, False), 1.0)
        worst = max(worst, float(total.max()))
        if limit is not None and worst > limit:
            break
    return worst


def _geometric_grid(first: int, cap: int, ratio: float) -> list[int]:
    ns: list[int] = []
    n = max(1, first)
    while n < cap:
        ns.append(n)
        n = max(n + 1, math.ceil(n * ratio))
    return ns


def _first_checkpoint(alpha: float, v: float) -> int:
    """Smallest ``n`` at which a count of 0 can settle: ``1 - (alpha/2)^(1/n) <= v``."""
    if v >= 1.0:
        return 1
    return max(1, math.ceil(math.log(alpha / 2.0) / math.log1p(-v)))


@functools.lru_cache(maxsize=64)
def _plan(v: float, delta: float, m: int) -> AdaptivePlan:
    dp = delta / m
    hoeffding_n = m * hoeffding_per_patch(v, delta)
    cap = hoeffding_per_patch(v, dp)
    cells = math.ceil(0.5 / (v * _CELL_FRACTION))
    n_ck = len(_geometric_grid(_first_checkpoint(dp, v), cap, CHECKPOINT_RATIO))
    if cells * (n_ck + 1) <= _CERTIFY_MAX_WORK:
        # Largest per-checkpoint level (0.6 dp, then down by 0.85) whose plan certifies.
        alpha = 0.6 * dp
        for _ in range(40):
            ns = np.array(_geometric_grid(_first_checkpoint(alpha, v), cap, CHECKPOINT_RATIO), dtype=np.int64)
            L = _lower_thresholds(ns, alpha, v) if len(ns) else np.empty(0)
            keep = L >= 0
            ns, L = ns[keep], L[keep]
            bound = _certify(ns, L, cap, v, limit=_CERTIFY_MARGIN * dp)
            if bound <= _CERTIFY_MARGIN * dp:
                return AdaptivePlan(
                    uncertainty=v, delta=delta, patches=m, mode="certified",
                    checkpoints=tuple(int(x) for x in ns) + (cap,),
                    alphas=tuple([alpha] * len(ns)) + (dp,),
                    lower_stop=tuple(int(x) for x in L) + (cap,),
                    cap=cap, hoeffding_N=hoeffding_n, failure_bound=min(delta, bound * m),
                )
            alpha *= 0.85
        # (not reached in practice: with no checkpoints the cap alone certifies, eq. 3.5)
    # Union mode: half of delta/m over the checkpoints (Clopper-Pearson at each fixed n),
    # half to the cap (Hoeffding).
    cap = hoeffding_per_patch(v, dp / 2.0)
    ns_list = _geometric_grid(_first_checkpoint(dp / 2.0, v), cap, CHECKPOINT_RATIO)
    alpha = dp / 2.0 / max(1, len(ns_list))
    return AdaptivePlan(
        uncertainty=v, delta=delta, patches=m, mode="union",
        checkpoints=tuple(ns_list) + (cap,),
        alphas=tuple([alpha] * len(ns_list)) + (dp / 2.0,),
        lower_stop=None, cap=cap, hoeffding_N=hoeffding_n, failure_bound=delta,
    )


def adaptive_plan(uncertainty: float, delta: float, patches: int = 1) -> AdaptivePlan:
    """Plan the variance-adaptive sequential rule for ``(v, delta)`` and ``m = patches``.

    Each patch gets ``delta/m`` (union bound over patches, as eq. 3.12 does). Checkpoints grow
    geometrically (ratio :data:`CHECKPOINT_RATIO`) from the first ray count at which any count
    could settle, up to the cap. At checkpoint ``n_k`` a patch count ``c`` is *settled* when its
    two-sided Clopper-Pearson interval at level ``alpha_k`` lies within ``c/n_k +- v``; the rule
    stops at the first checkpoint where every patch is settled, and at the cap regardless.

    Two modes, both proving ``P(exists j: |p_hat_j - p_j| > v) <= delta`` for every ``p``:

    ``"certified"`` (``v`` >= about 5e-4)
        Cap = ``hoeffding_rays(v, delta/m)``: exactly eq. 3.5 for one patch, and at most
        eq. 3.12 for ``m`` patches (``ln(2m/delta) <= m ln(2/delta)``). The settled counts
        form threshold sets ``c <= L_k`` or ``c >= n_k - L_k``. The plan's per-patch failure
        probability ``sum_k P_p(settled at k and |p_hat_k - p| > v) + P_p(|p_hat_cap - p| > v)``
        is bounded for *every* ``p`` by binomial tails on a partition of ``[0, 1]`` into cells
        of width ``v/16`` (monotonicity of binomial tails in ``p``; exact tails, or Chernoff
        bounds where those are below 1e-20; see ``_certify``), and the largest level
        ``alpha`` whose bound is ``<= 0.999 delta/m`` is used. The union over checkpoints is
        thus sharp: only the one or two checkpoints whose thresholds sit near ``p`` contribute,
        instead of every checkpoint being charged its full ``alpha``.
    ``"union"`` (smaller ``v``, where certifying would take seconds)
        Plain union bound: ``sum_k alpha_k = delta/(2m)`` (Clopper-Pearson covers with
        probability ``>= 1 - alpha_k`` at each fixed ``n_k``; a settled patch outside its
        interval is the only way to fail at a checkpoint) and the cap
        ``hoeffding_rays(v, delta/(2m))`` fails with probability ``<= delta/(2m)`` (Hoeffding).
        This cap exceeds eq. 3.5 for one patch by the factor ``ln(4/delta)/ln(2/delta)``
        (1.13 at ``delta = 0.01``).

    Pure and cached; certification takes well under a second at ``v = 0.005``.

    Raises
    ------
    BudgetError
        For a bad ``uncertainty``, ``delta`` or ``patches`` (naming the value).
    """
    return _plan(check_uncertainty(uncertainty), check_delta(delta), check_patches(patches))


@dataclass
class AdaptiveResult:
    """Outcome of :func:`run_adaptive`.

    Attributes
    ----------
    N
        Rays used.
    counts
        Cumulative success counts per patch, int64 array of shape ``(patches,)``.
    estimate
        ``counts / N`` per patch.
    ci
        ``(lo, hi)`` per patch: ``estimate -+ v`` clipped to [0, 1], the interval the guarantee
        is about: all patches' intervals hold together with probability ``>= 1 - delta``.
    hoeffding_N
        Eq. 3.5 / 3.12 for the same request.
    saved_fraction
        ``1 - N / hoeffding_N`` (negative only in union mode at the cap, single patch).
    stopped_early
        True when the rule stopped before the cap.
    checkpoints_used
        Checkpoints looked at, including the one it stopped at.
    plan
        The plan that was run.
    """

    N: int
    counts: np.ndarray
    estimate: np.ndarray
    ci: tuple[np.ndarray, np.ndarray]
    hoeffding_N: int
    saved_fraction: float
    stopped_early: bool
    checkpoints_used: int
    plan: AdaptivePlan = field(repr=False)


def _as_counts(raw: object, n_new: int, m: int) -> np.ndarray:
    arr = np.asarray(raw)
    if arr.dtype.kind not in "iu":
        raise BudgetError(f"draw() must return integer counts, got dtype {arr.dtype}")
    arr = arr.astype(np.int64, copy=False).reshape(-1)
    if arr.shape != (m,):
        raise BudgetError(f"draw() must return {m} count(s), got shape {np.shape(raw)}")
    lo, hi = int(arr.min()), int(arr.max())
    if lo < 0 or hi > n_new:
        raise BudgetError(f"draw({n_new}) returned counts outside [0, {n_new}]: {lo}..{hi}")
    return arr


def run_adaptive(draw: Callable[[int], object], uncertainty: float, delta: float,
                 patches: int = 1, plan: AdaptivePlan | None = None) -> AdaptiveResult:
    """Cast rays in batches until the adaptive rule of :func:`adaptive_plan` stops.

    Parameters
    ----------
    draw
        ``draw(n_new)`` casts ``n_new`` fresh rays and returns their success counts: an int64
        array of shape ``(patches,)``, or an integer when ``patches == 1``. Rays of different
        calls must be independent (fresh random streams).
    uncertainty, delta, patches
        As for :func:`adaptive_plan`.
    plan
        A plan from :func:`adaptive_plan` for the same request (optional).

    Returns
    -------
    AdaptiveResult
        Satisfies ``P(exists j: |estimate_j - p_j| > v) <= delta``.

    Raises
    ------
    BudgetError
        For a bad request, a plan for another request, or counts that are not integers in
        ``[0, n_new]`` of the right shape.
    """
    if plan is None:
        plan = adaptive_plan(uncertainty, delta, patches)
    else:
        v, d, m = check_uncertainty(uncertainty), check_delta(delta), check_patches(patches)
        if (plan.uncertainty, plan.delta, plan.patches) != (v, d, m):
            raise BudgetError(
                f"plan is for (v={plan.uncertainty}, delta={plan.delta}, patches={plan.patches}), "
                f"not (v={v}, delta={d}, patches={m})")
    m = plan.patches
    counts = np.zeros(m, dtype=np.int64)
    done = 0
    last = len(plan.checkpoints) - 1
    for i, n_k in enumerate(plan.checkpoints):
        counts += _as_counts(draw(n_k - done), n_k - done, m)
        done = n_k
        if i == last or bool(np.all(plan.settled(i, counts))):
            break
    estimate = counts / done
    ci = (np.clip(estimate - plan.uncertainty, 0.0, 1.0), np.clip(estimate + plan.uncertainty, 0.0, 1.0))
    return AdaptiveResult(
        N=done, counts=counts, estimate=estimate, ci=ci, hoeffding_N=plan.hoeffding_N,
        saved_fraction=1.0 - done / plan.hoeffding_N, stopped_early=i < last,
        checkpoints_used=i + 1, plan=plan,
    )


