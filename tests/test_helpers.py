"""The shared test helpers do what the tests rely on: the two-sample test false-alarms at the
rate it is run at and has power, the binomial bands hold their rate exactly, and the hang guard
stops compiled code that a signal alarm could not."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy import stats

from tests.helpers.cli import GuardedWorker, Hang
from tests.helpers.stats import binomial_band, binomial_outside, family_rate, max_failures, two_sample_p

BINS = np.array([0.3, 0.2, 0.2, 0.1, 0.1, 0.05, 0.03, 0.01, 0.005, 0.005])  # two bins to pool at n = 400


def _rejections(p_a, p_b, n, alpha, trials, seed):
    rng = np.random.default_rng(seed)
    return sum(two_sample_p(rng.multinomial(n, p_a), rng.multinomial(n, p_b)) < alpha for _ in range(trials))


def test_two_sample_p_false_alarms_at_its_level():
    # 1000 null pairs at alpha = 0.05: rejections ~ Binomial(1000, 0.05); the check's own
    # false-alarm rate is 1e-3 (equal tails of that binomial)
    trials, alpha = 1000, 0.05
    lo, hi = binomial_band(trials, alpha, 1e-3)
    assert lo <= _rejections(BINS, BINS, 400, alpha, trials, seed=1) <= hi


def test_two_sample_p_has_power_and_pools_small_bins():
    shifted = BINS + np.array([-0.1, 0.1] + [0.0] * 8)
    assert _rejections(BINS, shifted, 400, 0.05, 200, seed=2) > 150  # power ~0.85 at this shift (mean 170 of 200)
    # equal totals: the statistic is sum (a - b)^2 / (a + b) over the bins kept
    a, b = np.array([50, 40, 30, 2, 1, 0]), np.array([45, 48, 26, 1, 3, 0])
    x2 = sum((x - y) ** 2 / (x + y) for x, y in ((50, 45), (40, 48), (30, 26), (3, 4)))
    assert two_sample_p(a, b) == pytest.approx(stats.chi2.sf(x2, 3), rel=1e-12)
    assert two_sample_p([5, 0], [5, 0]) == 1.0


def test_binomial_band_and_family_rates_are_exact():
    lo, hi = binomial_band(1000, 0.3, 1e-3)
    assert binomial_outside(1000, 0.3, lo, hi) <= 1e-3 < binomial_outside(1000, 0.3, lo + 1, hi - 1)
    k = max_failures(200, 0.01, 1e-3)
    assert stats.binom.sf(k, 200, 0.01) <= 1e-3 < stats.binom.sf(k - 1, 200, 0.01)
    assert family_rate(1e-3, 1) == pytest.approx(1e-3) and family_rate(1e-3, 29) == pytest.approx(0.0286, abs=1e-4)


@numba.njit(cache=False)  # compiled afresh in the guarded child (the suite's kernel policy)
def spin(steps):
    """Compiled code that never returns for steps < 0 (and no signal can interrupt)."""
    x, i = 0, 0
    while i != steps:
        x = (x * 31 + i) % 1009
        i += 1
    return x


def test_the_hang_guard_stops_compiled_code():
    worker = GuardedWorker(timeout_s=60)
    try:
        assert worker.call("tests.test_helpers:spin", 10)[:2] == ("ok", spin(10))  # started and compiled
        worker.timeout_s = 1.0
        with pytest.raises(Hang, match="killed"):
            worker.call("tests.test_helpers:spin", -1)
        worker.timeout_s = 60
        assert worker.call("math:factorial", 5)[:2] == ("ok", 120)  # a fresh process serves on
    finally:
        worker.close()
