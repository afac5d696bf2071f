"""Ray budgets (virtual/bounds.py): eq. 3.5/3.12, binomial intervals, the adaptive rule.

Statistical assertions use tolerances derived from the binomial distribution and stated next to
them; every random test has a fixed seed. Where possible the test is exact instead of random:
the failure probability of a small adaptive plan is computed by dynamic programming over the
counts and compared with delta directly.
"""

from __future__ import annotations

import dataclasses
import math
import time
from decimal import Decimal, localcontext

import numpy as np
import pytest
from scipy import signal, stats

from bench.core.errors import BudgetError, InputError
from tests.helpers.stats import max_failures
from virtual.bounds import (
    AdaptivePlan,
    _certify,
    adaptive_plan,
    binomial_ci,
    budget_report,
    estimate_time,
    hoeffding_rays,
    run_adaptive,
)

# One-sided tolerance for Monte Carlo failure counts: with R independent runs of a rule whose
# failure probability is at most delta, the number of failures is stochastically smaller than
# Binomial(R, delta); we allow up to the count whose upper tail is at most TAIL_ALPHA
# (tests/helpers/stats.max_failures), so a correct rule fails one such check with probability
# at most 1e-3 -- a test of three incidences at most 3e-3 -- while a rule whose real failure
# rate were several times delta would exceed it.
TAIL_ALPHA = 1e-3


def _max_failures(runs: int, delta: float) -> int:
    return max_failures(runs, delta, TAIL_ALPHA)


def _exact_bracket_ok(n1: int, v: float, delta: float) -> bool:
    """``ceil(ln(2/delta)/(2v^2)) == n1``, checked through exp instead of ln, at 100 digits:
    exp(2 v^2 (n1 - 1)) < 2/delta <= exp(2 v^2 n1). Both sides are exact rationals or
    transcendental, so equality never happens and 100 digits decide."""
    with localcontext() as ctx:
        ctx.prec = 100
        two_v2 = 2 * Decimal(v) * Decimal(v)
        target = Decimal(2) / Decimal(delta)
        return (two_v2 * (n1 - 1)).exp() < target <= (two_v2 * n1).exp()


# --- eq. 3.5 / 3.12 ----------------------------------------------------------------------------


def test_acceptance_numbers_of_the_seed():
    assert hoeffding_rays(0.005, 0.01) == 105967  # eq. 3.5: "10^5.02 rays"
    assert hoeffding_rays(0.005, 0.01, patches=900) == 95370300  # eq. 3.12: "at most 10^8"
    assert isinstance(hoeffding_rays(0.005, 0.01), int)


@pytest.mark.parametrize(
    "kwargs, bad",
    [
        ({"uncertainty": 0.0, "delta": 0.01}, "0.0"),
        ({"uncertainty": -0.1, "delta": 0.01}, "-0.1"),
        ({"uncertainty": 1.5, "delta": 0.01}, "1.5"),
        ({"uncertainty": float("nan"), "delta": 0.01}, "nan"),
        ({"uncertainty": float("inf"), "delta": 0.01}, "inf"),
        ({"uncertainty": "0.1", "delta": 0.01}, "'0.1'"),
        ({"uncertainty": True, "delta": 0.01}, "True"),
        ({"uncertainty": 0.01, "delta": 0.0}, "0.0"),
        ({"uncertainty": 0.01, "delta": 1.0}, "1.0"),
        ({"uncertainty": 0.01, "delta": -0.5}, "-0.5"),
        ({"uncertainty": 0.01, "delta": float("nan")}, "nan"),
        ({"uncertainty": 0.01, "delta": 0.01, "patches": 0}, "0"),
        ({"uncertainty": 0.01, "delta": 0.01, "patches": -3}, "-3"),
        ({"uncertainty": 0.01, "delta": 0.01, "patches": 2.5}, "2.5"),
        ({"uncertainty": 0.01, "delta": 0.01, "patches": True}, "True"),
        ({"uncertainty": 0.01, "delta": 0.01, "patches": "9"}, "'9'"),
    ],
)
def test_bad_inputs_raise_budget_error_naming_the_value(kwargs, bad):
    for fn in (hoeffding_rays, adaptive_plan):
        with pytest.raises(BudgetError) as info:
            fn(**kwargs)
        msg = str(info.value)
        assert bad in msg and "\n" not in msg
        assert isinstance(info.value, InputError)  # the CLI maps it to exit status 2


def test_v_equal_one_and_numpy_scalars_are_accepted():
    assert hoeffding_rays(1.0, 0.5) == 1  # ln(4)/2 = 0.69 -> 1
    assert hoeffding_rays(np.float64(0.005), np.float32(0.01).item(), np.int64(900)) == 95370300


def test_huge_budgets_are_instant_and_exact():
    t0 = time.thread_time()  # CPU seconds of this thread: a loaded machine does not inflate them
    n = hoeffding_rays(1e-6, 0.01)
    n900 = hoeffding_rays(1e-6, 0.01, patches=900)
    report = budget_report(1e-6, 0.01, 900, rays_per_second=1e8)
    cpu = time.thread_time() - t0
    assert cpu < 0.5  # no simulation, no loop over 2.6e12 rays: microseconds in practice
    assert n == 2649158683275 and _exact_bracket_ok(n, 1e-6, 0.01)
    assert n900 == 900 * n  # Python int, no overflow (2.4e15)
    assert report["N"] == n900 and report["seconds"] == pytest.approx(n900 / 1e8, rel=1e-15)
    absurd = budget_report(1e-300, 0.01)  # a 600-digit ray count: exact int, time inf
    assert absurd["N"] > 10**600 and absurd["seconds"] == math.inf


def test_hoeffding_ceiling_is_exact_for_many_inputs_and_near_integers():
    rng = np.random.default_rng(20261122)
    cases = [(float(v), float(d)) for v, d in zip(10 ** rng.uniform(-6, 0, 300), 10 ** rng.uniform(-12, -1e-3, 300))]
    # near-integer quotients: v = 1/2 gives q = 2 ln(2/delta) = j for delta = 2 exp(-j/2); the
    # float delta is off by an ulp, so the true q is within ~1e-15 of j on either side, where
    # float arithmetic cannot decide the ceiling
    cases += [(0.5, 2.0 * math.exp(-j / 2.0)) for j in range(2, 60)]
    for v, d in cases:
        n1 = hoeffding_rays(v, d)
        assert _exact_bracket_ok(n1, v, d), (v, d, n1)


def test_estimate_time_and_budget_report():
    assert estimate_time(105967, 1e5) == pytest.approx(1.05967)
    assert estimate_time(0, 1.0) == 0.0
    rep = budget_report(0.005, 0.01, 900, rays_per_second=2e6)
    assert rep["N"] == 95370300 and rep["seconds"] == pytest.approx(95370300 / 2e6)
    for bad_n, bad_rate in ((-1, 1.0), (1.5, 1.0), (10, 0.0), (10, float("inf")), (10, -2.0)):
        with pytest.raises(BudgetError):
            estimate_time(bad_n, bad_rate)


# --- binomial intervals ------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["clopper-pearson", "wilson"])
def test_binomial_ci_edges(method):
    n = np.array([1, 10, 1000, 10**12], dtype=np.int64)
    lo0, hi0 = binomial_ci(np.zeros(4, dtype=np.int64), n, 0.01, method)
    assert np.all(lo0 == 0.0) and np.all(np.isfinite(hi0)) and np.all((hi0 > 0) & (hi0 < 1))
    lo1, hi1 = binomial_ci(n, n, 0.01, method)
    assert np.all(hi1 == 1.0) and np.all((lo1 > 0) & (lo1 < 1))
    # symmetry k <-> n - k
    k = np.array([0, 3, 400, 7 * 10**11], dtype=np.int64)
    lo, hi = binomial_ci(k, n, 0.01, method)
    lo_m, hi_m = binomial_ci(n - k, n, 0.01, method)
    np.testing.assert_allclose(lo, 1.0 - hi_m, atol=1e-12)
    np.testing.assert_allclose(hi, 1.0 - lo_m, atol=1e-12)
    assert np.all((lo <= k / n) & (k / n <= hi))


def test_clopper_pearson_closed_forms_at_the_edges():
    # k = 0: hi = 1 - (delta/2)^(1/n);  k = n: lo = (delta/2)^(1/n)
    n = np.array([1, 7, 1000], dtype=np.int64)
    _, hi = binomial_ci(0, n, 0.05)
    lo, _ = binomial_ci(n, n, 0.05)
    np.testing.assert_allclose(hi, 1.0 - 0.025 ** (1.0 / n), rtol=1e-12)
    np.testing.assert_allclose(lo, 0.025 ** (1.0 / n), rtol=1e-12)


def test_clopper_pearson_coverage_is_exact():
    """Exact coverage sum_{k: lo_k <= p <= hi_k} Binom(n, p)(k) >= 1 - delta, no randomness."""
    delta = 0.05
    for n in (5, 40, 333):
        k = np.arange(n + 1)
        lo, hi = binomial_ci(k, n, delta)
        for p in np.linspace(0.001, 0.999, 97):
            cover = stats.binom.pmf(k, n, p)[(lo <= p) & (p <= hi)].sum()
            assert cover >= 1.0 - delta - 1e-12, (n, p, cover)


def test_binomial_ci_zero_trials_and_bad_counts():
    lo, hi = binomial_ci(np.array([0, 2]), np.array([0, 4]), 0.05)
    assert lo[0] == 0.0 and hi[0] == 1.0 and 0 < lo[1] < 0.5 < hi[1] < 1
    for k, n in ((3, 2), (-1, 5), (1.5, 4)):
        with pytest.raises(BudgetError):
            binomial_ci(k, n, 0.05)
    with pytest.raises(BudgetError):
        binomial_ci(1, 4, 1.5)
    with pytest.raises(BudgetError):
        binomial_ci(1, 4, 0.05, method="jeffreys")


def test_binomial_ci_is_vectorized_and_fast():
    rng = np.random.default_rng(5)
    n = np.full(100_000, 10**6, dtype=np.int64)
    k = rng.binomial(n, 0.3)
    t0 = time.thread_time()  # CPU seconds of this thread, whatever the load
    lo, hi = binomial_ci(k, n, 0.01)
    assert time.thread_time() - t0 < 10.0  # ~0.6 s on one core; a Python loop takes a minute
    assert lo.shape == hi.shape == (100_000,) and np.all(lo < k / n) and np.all(k / n < hi)


# --- the adaptive rule: structure and exact failure probability ---------------------------------


def _exact_failure_and_stops(plan: AdaptivePlan, p: float) -> tuple[float, np.ndarray]:
    """One patch: the exact P(|p_hat - p| > v at the stop) and P(stop at checkpoint k).

    Dynamic programming over the count among paths that have not stopped yet: convolve with
    the Binomial(n_k - n_{k-1}, p) increment, then remove the settled counts.
    """
    v = plan.uncertainty
    mass = np.array([1.0])
    prev, fail, stops = 0, 0.0, []
    for i, n in enumerate(plan.checkpoints):
        inc = stats.binom.pmf(np.arange(n - prev + 1), n - prev, p)
        mass = np.clip(signal.fftconvolve(mass, inc), 0.0, None)
        c = np.arange(n + 1)
        settled = plan.settled(i, c)
        fail += mass[settled & (np.abs(c / n - p) > v)].sum()
        stops.append(mass[settled].sum())
        mass = np.where(settled, 0.0, mass)
        prev = n
    return fail, np.array(stops)


def test_plan_structure_and_caps():
    plan = adaptive_plan(0.005, 0.01)
    ck = np.array(plan.checkpoints)
    assert plan.mode == "certified" and np.all(np.diff(ck) > 0)
    assert plan.cap == ck[-1] == plan.hoeffding_N == hoeffding_rays(0.005, 0.01)  # cap = eq. 3.5
    assert plan.failure_bound <= 0.01
    # thresholds are where the Clopper-Pearson interval stops fitting in +- v
    for i in range(0, len(ck) - 1, 5):
        n, L = ck[i], plan.lower_stop[i]
        lo, hi = binomial_ci(np.array([L, L + 1]), n, plan.alphas[i])
        fits = (hi - np.array([L, L + 1]) / n <= 0.005) & (np.array([L, L + 1]) / n - lo <= 0.005)
        assert fits.tolist() == [True, False]
    # many patches: cap at eq. 3.5 with delta/m, which is far below eq. 3.12
    multi = adaptive_plan(0.005, 0.01, patches=900)
    assert multi.cap == hoeffding_rays(0.005, 0.01 / 900) <= multi.hoeffding_N == 95370300
    assert adaptive_plan(0.005, 0.01) is plan  # pure and cached


@pytest.mark.parametrize("v, delta", [(0.05, 0.1), (0.02, 0.05)])
def test_exact_failure_probability_is_below_delta_for_every_p(v, delta):
    """Exact (not Monte Carlo) check of the guarantee on a fine grid of p, by DP."""
    plan = adaptive_plan(v, delta)
    ps = np.concatenate([np.linspace(0.0, 1.0, 101), np.linspace(0.3, 0.5, 23)])  # worst p ~ 0.35-0.45
    worst = 0.0
    for p in ps:
        fail, stops = _exact_failure_and_stops(plan, float(p))
        assert stops.sum() == pytest.approx(1.0, abs=1e-9)
        worst = max(worst, fail)
    assert worst <= plan.failure_bound <= delta


def test_certificate_dominates_exact_failure_even_for_a_bad_plan():
    """The certificate must bound any threshold plan, not only good ones: with thresholds
    quadrupled (an anti-conservative rule whose exact failure exceeds delta), the certified
    bound is still >= the exact failure at every p, and it rejects the plan."""
    v, delta = 0.05, 0.1
    good = adaptive_plan(v, delta)
    L = np.minimum(np.array(good.lower_stop[:-1]) * 4 + 2, np.array(good.checkpoints[:-1]) // 2)
    bad = dataclasses.replace(good, lower_stop=tuple(int(x) for x in L) + (good.cap,))
    bound = _certify(np.array(good.checkpoints[:-1]), L, good.cap, v)
    worst = max(_exact_failure_and_stops(bad, float(p))[0] for p in np.linspace(0.0, 0.5, 101))
    assert worst > delta  # the mutation is really wrong ...
    assert bound >= worst  # ... and the certificate sees it


def test_exact_stopping_distribution_at_p_005_uses_under_a_quarter():
    """Exactly: at p = 0.05, v = 0.005, delta = 0.01 the rule is done by a quarter of eq. 3.5
    except with probability < 1e-6."""
    plan = adaptive_plan(0.005, 0.01)
    quarter = hoeffding_rays(0.005, 0.01) / 4
    _, stops = _exact_failure_and_stops(plan, 0.05)
    ck = np.array(plan.checkpoints)
    assert stops[ck > quarter].sum() < 1e-6
    assert (stops * ck).sum() < 0.2 * plan.hoeffding_N  # mean rays: ~19% of eq. 3.5


# --- the adaptive rule: Monte Carlo coverage -----------------------------------------------------


def _coverage(p, v, delta, runs, seed):
    """Runs the rule ``runs`` times on Generator.binomial; returns (failures, rays used)."""
    plan = adaptive_plan(v, delta)
    rng = np.random.default_rng(seed)
    fails, used = 0, np.empty(runs, dtype=np.int64)
    for r in range(runs):
        res = run_adaptive(lambda n: rng.binomial(n, p), v, delta, plan=plan)
        fails += bool(np.any(np.abs(res.estimate - p) > v))
        used[r] = res.N
    return fails, used


@pytest.mark.parametrize("p", [0.05, 0.375, 0.5])
def test_coverage_at_seed_setting(p):
    v, delta, runs = 0.005, 0.01, 1000
    fails, used = _coverage(p, v, delta, runs, seed=int(p * 1000) + 1)
    assert fails <= _max_failures(runs, delta)  # Binomial(1000, 0.01) 99.9% quantile = 21
    cap = adaptive_plan(v, delta).cap
    assert used.max() <= cap == hoeffding_rays(v, delta)  # never more than eq. 3.5
    if p == 0.05:
        assert used.max() <= hoeffding_rays(v, delta) / 4  # every run, not just on average


def test_coverage_where_failures_are_frequent_enough_to_see():
    """delta = 0.2 at v = 0.02: a rule whose real failure rate were 1.25 delta would exceed the
    tolerance here in most seeds (Binomial(1000, 0.2): mean 200, 99.9% quantile 240)."""
    v, delta, runs = 0.02, 0.2, 1000
    for p in (0.1, 0.3, 0.5):
        fails, used = _coverage(p, v, delta, runs, seed=7)
        assert fails <= _max_failures(runs, delta)
        assert used.max() <= hoeffding_rays(v, delta)


def test_coverage_many_patches_multinomial():
    v, delta, runs = 0.005, 0.01, 1000
    probs = np.array([0.05, 0.2, 0.375, 0.3])
    pvals = np.append(probs, 1.0 - probs.sum())  # the remainder leaves through no patch
    plan = adaptive_plan(v, delta, patches=4)
    rng = np.random.default_rng(42)
    fails, used = 0, []
    for _ in range(runs):
        res = run_adaptive(lambda n: rng.multinomial(n, pvals)[:4], v, delta, patches=4, plan=plan)
        fails += bool(np.any(np.abs(res.estimate - probs) > v))
        used.append(res.N)
        assert res.counts.shape == (4,) and res.counts.dtype == np.int64
    assert fails <= _max_failures(runs, delta)
    assert max(used) <= plan.cap <= hoeffding_rays(v, delta, 4)


def test_union_mode_for_small_uncertainty():
    """Below v ~ 5e-4 the plan uses the plain union bound (cap eq. 3.5 at delta/2)."""
    v, delta = 0.0003, 0.01
    plan = adaptive_plan(v, delta)
    assert plan.mode == "union" and plan.lower_stop is None
    assert sum(plan.alphas[:-1]) <= delta / 2 * (1 + 1e-12)
    assert plan.cap == hoeffding_rays(v, delta / 2)
    rng = np.random.default_rng(3)
    runs, fails, used = 300, 0, []
    for _ in range(runs):
        res = run_adaptive(lambda n: rng.binomial(n, 0.02), v, delta, plan=plan)
        fails += abs(res.estimate[0] - 0.02) > v
        used.append(res.N)
    assert fails <= _max_failures(runs, delta)  # 99.9% quantile of Binomial(300, 0.01) = 10
    assert max(used) < 0.25 * plan.hoeffding_N  # p = 0.02 has variance 0.08 of the worst


def test_certified_mode_at_one_per_mille():
    v, delta = 0.001, 0.01
    plan = adaptive_plan(v, delta)
    assert plan.mode == "certified" and plan.cap == hoeffding_rays(v, delta) == 2649159
    rng = np.random.default_rng(8)
    used = [run_adaptive(lambda n: rng.binomial(n, 0.05), v, delta, plan=plan).N for _ in range(100)]
    assert max(used) <= plan.hoeffding_N / 4


def test_result_fields():
    rng = np.random.default_rng(0)
    res = run_adaptive(lambda n: rng.binomial(n, 0.05), 0.005, 0.01)
    assert res.stopped_early and res.N < res.hoeffding_N == 105967
    assert res.saved_fraction == pytest.approx(1 - res.N / 105967)
    assert res.saved_fraction > 0.75
    assert res.checkpoints_used == res.plan.checkpoints.index(res.N) + 1
    assert res.estimate[0] == res.counts[0] / res.N
    assert res.ci[0][0] == pytest.approx(max(0.0, res.estimate[0] - 0.005))
    assert res.ci[1][0] == pytest.approx(res.estimate[0] + 0.005)
    at_half = run_adaptive(lambda n: rng.binomial(n, 0.5), 0.005, 0.01)
    assert at_half.N <= 105967 and at_half.saved_fraction >= 0.0


def test_run_adaptive_rejects_bad_draws_and_mismatched_plans():
    with pytest.raises(BudgetError):
        run_adaptive(lambda n: n * 0.5, 0.005, 0.01)  # float counts
    with pytest.raises(BudgetError):
        run_adaptive(lambda n: n + 1, 0.005, 0.01)  # more successes than rays
    with pytest.raises(BudgetError):
        run_adaptive(lambda n: np.zeros(3, dtype=np.int64), 0.005, 0.01, patches=2)
    with pytest.raises(BudgetError):
        run_adaptive(lambda n: 0, 0.01, 0.01, plan=adaptive_plan(0.005, 0.01))
