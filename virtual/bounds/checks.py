"""Validation of the budget inputs (v, delta, patches, rates): one :class:`BudgetError` each."""

from __future__ import annotations

import math
import numbers
import operator

from bench.core.errors import BudgetError

__all__ = ["real", "check_uncertainty", "check_delta", "check_patches"]


def real(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise BudgetError(f"{name} must be a real number, got {value!r}")
    return float(value)


def check_uncertainty(uncertainty: object) -> float:
    v = real(uncertainty, "uncertainty v")
    if not (math.isfinite(v) and 0.0 < v <= 1.0):
        raise BudgetError(f"uncertainty v must be finite and in (0, 1], got {uncertainty!r}")
    return v


def check_delta(delta: object, name: str = "delta") -> float:
    d = real(delta, name)
    if not (math.isfinite(d) and 0.0 < d < 1.0):
        raise BudgetError(f"{name} (the confidence of eq. 3.5) must be in (0, 1), got {delta!r}")
    return d


def check_patches(patches: object) -> int:
    if isinstance(patches, bool):
        raise BudgetError(f"patches must be an integer >= 1, got {patches!r}")
    try:
        m = operator.index(patches)  # type: ignore[arg-type]
    except TypeError:
        raise BudgetError(f"patches must be an integer >= 1, got {patches!r}") from None
    if m < 1:
        raise BudgetError(f"patches must be an integer >= 1, got {patches!r}")
    return m

