"""Ray budgets: the Hoeffding bound of seed eqs. 3.5/3.12, binomial confidence intervals and a
variance-adaptive sequential stopping rule that reaches the same (v, delta) with fewer rays.

A ray count ``n_d`` out of ``N`` rays is Binomial(N, p) (a patch of a collector sphere, or the
upper/lower hemisphere of a spectrophotometer). Three tools live here:

* :func:`hoeffding_rays` -- eq. 3.5 ``N = ceil(ln(2/delta) / (2 v^2))`` and eq. 3.12 (``patches``
  times that), computed with exact decimal arithmetic so the ceiling is never off by one and
  huge budgets (``v = 1e-6`` gives ~2.6e12 rays) are plain Python ints.
* :func:`binomial_ci` -- the one binomial interval every device uses (Clopper-Pearson or Wilson),
  vectorized over numpy arrays.
* :func:`adaptive_plan` / :func:`run_adaptive` -- a group-sequential rule: at geometrically spaced
  checkpoints it stops as soon as every patch's Clopper-Pearson interval lies within
  ``p_hat +- v``; it never goes past a cap of eq. 3.5 rays (eq. 3.5 at ``delta/m`` per patch
  for ``m`` patches, which is at most eq. 3.12). A Bernoulli with ``p`` far from 1/2 has a
  small variance ``p(1 - p)`` and stops early; at ``p = 1/2`` the rule runs to the cap.

Guarantee of the adaptive rule
------------------------------
For every vector of true patch probabilities ``p_j`` (counts per patch marginally
Binomial(n, p_j), e.g. multinomial patch counts), with ``p_hat_j = counts_j / N`` at the ray
count ``N`` where the rule stops::

    P( exists j : |p_hat_j - p_j| > v ) <= delta.

See :func:`adaptive_plan` for how each of the two modes proves it.

Modules: :mod:`~virtual.bounds.hoeffding` (eq. 3.5/3.12, time), :mod:`~virtual.bounds.intervals`
(:func:`binomial_ci`), :mod:`~virtual.bounds.adaptive` (the rule), :mod:`~virtual.bounds._checks`.
"""

from __future__ import annotations

from virtual.bounds.adaptive import (CHECKPOINT_RATIO, AdaptivePlan, AdaptiveResult, _certify, adaptive_plan,  # noqa: F401
                                     run_adaptive)
from virtual.bounds.hoeffding import budget_report, estimate_time, hoeffding_rays
from virtual.bounds.intervals import CI_METHODS, binomial_ci, relative_patch_rays

__all__ = [
    "hoeffding_rays",
    "relative_patch_rays",
    "binomial_ci",
    "AdaptivePlan",
    "AdaptiveResult",
    "adaptive_plan",
    "run_adaptive",
    "estimate_time",
    "budget_report",
    "CI_METHODS",
]
