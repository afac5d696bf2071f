"""The statistics the tests share, each with the false-alarm rate it really runs.

One two-sample test (:func:`two_sample_p`) with one pooling rule, the binomial bands of a count,
and the family-wise rate of several comparisons, so that a test can state the rate it runs
(computed, not guessed) and show its power on a perturbed case with the same function.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

MIN_EXPECTED = 5.0
"""Cochran's rule: a bin whose expected count in either sample is below this is pooled."""


def two_sample_p(a, b) -> float:
    """p-value of Pearson's chi-square test that two count vectors over the same bins are draws
    of one multinomial (``scipy.stats.chi2_contingency`` on the 2 x bins table, no continuity
    correction; the totals may differ).

    Pooling rule, the only one in the suite: bins whose expected count in either sample is below
    :data:`MIN_EXPECTED` are summed into one bin, and bins empty in both samples are dropped.
    Under the null the p-value is uniform (to the chi-square approximation), so requiring
    ``p > alpha`` false-alarms with probability ``alpha``.
    """
    table = np.vstack([np.asarray(a, float), np.asarray(b, float)])
    if table.shape[0] != 2 or table.ndim != 2:
        raise ValueError("two_sample_p takes two count vectors of the same length")
    rows = table.sum(axis=1)
    if np.any(rows <= 0):
        raise ValueError("two_sample_p needs a positive total in each sample")
    expected = np.outer(rows, table.sum(axis=0)) / rows.sum()
    small = expected.min(axis=0) < MIN_EXPECTED
    table = np.column_stack([table[:, ~small], table[:, small].sum(axis=1)])
    table = table[:, table.sum(axis=0) > 0]
    if table.shape[1] < 2:
        return 1.0
    return float(stats.chi2_contingency(table, correction=False).pvalue)


def goodness_of_fit(observed, expected) -> tuple[float, float, int]:
    """Pearson's chi-square of counts against expected counts (``scipy.stats.chisquare``):
    (statistic, p-value, degrees of freedom). The same pooling rule as :func:`two_sample_p`:
    bins expected below :data:`MIN_EXPECTED` are summed into one (dropped if it expects
    nothing); the expected counts are rescaled to the observed total."""
    observed, expected = np.asarray(observed, float), np.asarray(expected, float)
    small = expected < MIN_EXPECTED
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    if exp[-1] == 0.0:
        obs, exp = obs[:-1], exp[:-1]
    exp = exp * obs.sum() / exp.sum()
    chi2, p = stats.chisquare(obs, exp)
    return float(chi2), float(p), len(obs) - 1


def family_rate(alpha: float, comparisons: int) -> float:
    """Probability that at least one of ``comparisons`` independent tests, each false-alarming
    with probability ``alpha``, false-alarms: ``1 - (1 - alpha)^m`` (below Bonferroni's
    ``m * alpha``, which bounds it for dependent tests too)."""
    return -math.expm1(comparisons * math.log1p(-alpha))


def binomial_band(n, p, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Equal-tailed band ``[lo, hi]`` of a Binomial(n, p) count: ``P(k < lo) <= alpha/2`` and
    ``P(k > hi) <= alpha/2``, so a count outside it false-alarms with probability at most
    ``alpha`` (:func:`binomial_outside` gives the exact value)."""
    return stats.binom.ppf(alpha / 2, n, p), stats.binom.isf(alpha / 2, n, p)


def binomial_outside(n, p, lo, hi) -> np.ndarray:
    """Exact ``P(k < lo or k > hi)`` for k ~ Binomial(n, p)."""
    return stats.binom.cdf(np.asarray(lo) - 1, n, p) + stats.binom.sf(hi, n, p)


def max_failures(runs: int, rate: float, alpha: float) -> int:
    """Largest number of failures of ``runs`` independent trials, each failing with probability
    at most ``rate``, that a check allows so that it false-alarms with probability at most
    ``alpha`` (the one-sided Binomial quantile)."""
    return int(stats.binom.isf(alpha, runs, rate))


def z_two_sided(alpha: float) -> float:
    """|z| threshold of a two-sided normal test at false-alarm rate ``alpha``."""
    return float(stats.norm.isf(alpha / 2))
