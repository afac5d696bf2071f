"""Validation of the budget inputs (v, delta, patches, rates): one :class:`BudgetError` each."""

from __future__ import annotations

import math
import numbers
import operator

from bench.core.errors import BudgetError

__all__ = ["real", "whole", "check_uncertainty", "check_delta", "check_patches"]


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


def whole(value: object, name: str, minimum: int) -> int:
    """``value`` as an int >= ``minimum`` (any integer type, never a bool or a float)."""
    bad = BudgetError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if isinstance(value, bool):
        raise bad
    try:
        n = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise bad from None
    if n < minimum:
        raise bad
    return n


def check_patches(patches: object) -> int:
    return whole(patches, "patches", 1)

