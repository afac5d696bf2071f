"""The covariance of the differences between an actual record with GUM budgets and a candidate,
and chi-square with it (:mod:`compare.stats`, :mod:`compare.verdict`).

A calibrated scan's readings share inputs -- the white standard's certificate (every reading of
the run), the white reference reading (per wavelength), a dark (the readings that used it) --
so their errors are correlated (:func:`bench.core.budget.budget_covariance`). Chi-square is then
``d^T C^-1 d`` with ``C`` the actual readings' covariance plus, on the diagonal, the candidate's
Monte Carlo variance and any instrument term: the white standard counted once, not per point.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
import pandas as pd

from bench.core.budget import budget_covariance
from bench.core.errors import InputError

if TYPE_CHECKING:
    from compare.stats import UncertaintyModel

__all__ = ["UncertaintyError", "BUDGET_SOURCE", "actual_budgets", "pair_covariance", "chi_square", "sub_covariance"]


class UncertaintyError(InputError):
    """No uncertainty can be formed for a statistic that needs one (chi-square, z)."""


#: where the uncertainty of an actual record with GUM budgets comes from
BUDGET_SOURCE = ("the actual record's GUM budgets (full covariance: shared terms such as the white standard "
                 "once for the run)")


def actual_budgets(actual: Any, pairs: pd.DataFrame) -> list[Any] | None:
    """The GUM budget (``uncertainty_budget``, JSON or dict) of each pair's actual reading, or None
    when the actual record carries none."""
    table = getattr(actual, "table", None)
    if table is None or "uncertainty_budget" not in table or not table["uncertainty_budget"].notna().any():
        return None
    col = table["uncertainty_budget"].reset_index(drop=True)
    return [col.iloc[int(i)] for i in pairs.actual_index.to_numpy()]


def pair_covariance(points: pd.DataFrame, budgets: Sequence[Any], model: "UncertaintyModel") -> np.ndarray:
    """Covariance of the differences ``d``: the actual readings' from their budgets
    (:func:`bench.core.budget.budget_covariance`) plus, on the diagonal, the instrument term of
    ``model`` and the virtual std^2 (independent Monte Carlo)."""
    parsed = [json.loads(b) if isinstance(b, str) else (b if isinstance(b, Mapping) else None) for b in budgets]
    sa = points.actual_std.to_numpy(float)
    cov = budget_covariance(parsed, sa) if model.use_actual_std else np.zeros((len(points), len(points)))
    sv = np.nan_to_num(points.virtual_std.to_numpy(float), nan=0.0) if model.use_virtual_std else 0.0
    return cov + np.diag(points.u_instrument.to_numpy(float) ** 2 + sv**2)


def chi_square(d: np.ndarray, cov: np.ndarray) -> float:
    """``d^T C^-1 d`` by a Cholesky solve (scipy.linalg); C must be positive definite."""
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    try:
        factor = cho_factor(cov, lower=True)
    except LinAlgError as exc:
        raise UncertaintyError(f"the covariance of the differences is not positive definite ({exc})") from None
    return float(d @ cho_solve(factor, d))


def sub_covariance(points: pd.DataFrame, group: pd.DataFrame, covariance: np.ndarray | None) -> np.ndarray | None:
    """The block of ``covariance`` (rows as ``points``) for the rows of ``group``."""
    if covariance is None:
        return None
    pos = points.index.get_indexer(group.index)
    return covariance[np.ix_(pos, pos)]


