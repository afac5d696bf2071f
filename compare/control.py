"""Measurement assurance: E_n numbers of a check standard and a Shewhart chart of them, with the
Western Electric / Nelson run rules.

A lab that trusts its bench measures a *check standard* on a schedule and keeps a control chart
of the results (NIST/SEMATECH e-Handbook of Statistical Methods, section 6.3; ISO 7870-2): the
chart's centre line and limits come from a baseline of in-control points (or are declared), and
a point is flagged when a run rule says the process has left statistical control. Pure functions
of arrays: the store, the CLI and the plots build on them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ["RULES", "Violation", "Chart", "en_numbers", "chart", "violations", "run_length", "false_alarm_rate"]

#: The run rules, by name: what each says (Western Electric Handbook 1956; Nelson 1984).
RULES: dict[str, str] = {
    "beyond-3-sigma": "one point beyond 3 sigma",
    "2-of-3-beyond-2-sigma": "2 of 3 consecutive points beyond 2 sigma on one side",
    "4-of-5-beyond-1-sigma": "4 of 5 consecutive points beyond 1 sigma on one side",
    "8-on-one-side": "8 consecutive points on one side of the centre line",
    "6-trending": "6 consecutive points steadily increasing or decreasing",
}
#: d2 for subgroups of 2: the mean moving range of independent normal points is 1.128 sigma.
_D2 = 1.128


@dataclass(frozen=True)
class Violation:
    """Rule ``rule`` fired at point ``index`` (the last point of the pattern)."""

    index: int
    rule: str

    @property
    def text(self) -> str:
        return RULES[self.rule]


@dataclass(frozen=True)
class Chart:
    """An individuals (Shewhart) chart: centre, sigma, the baseline it came from and the flags."""

    values: tuple[float, ...]
    centre: float
    sigma: float
    baseline: int
    declared: bool
    violations: tuple[Violation, ...] = field(default_factory=tuple)

    @property
    def limits(self) -> dict[str, float]:
        return {f"{s}{k}": self.centre + (1 if s == "+" else -1) * k * self.sigma for k in (1, 2, 3) for s in "+-"}

    @property
    def in_control(self) -> bool:
        return not self.violations

    def as_dict(self) -> dict:
        d = asdict(self)
        d["values"] = list(self.values)
        d["violations"] = [{"index": v.index, "rule": v.rule, "text": v.text} for v in self.violations]
        d["limits"] = self.limits
        d["in_control"] = self.in_control
        return d


def en_numbers(measured: npt.ArrayLike, u_measured: npt.ArrayLike, reference: npt.ArrayLike,
               u_reference: npt.ArrayLike, k: float = 2.0) -> np.ndarray:
    """E_n = (x - X) / sqrt(U_x^2 + U_X^2) with expanded uncertainties U = k u (ISO 13528:2015,
    9.7): |E_n| <= 1 agrees with the reference."""
    x, ux = np.asarray(measured, float), np.asarray(u_measured, float)
    ref, uref = np.asarray(reference, float), np.asarray(u_reference, float)
    return (x - ref) / (k * np.hypot(ux, uref))


def _side(z: np.ndarray, threshold: float) -> np.ndarray:
    """+1 above +threshold, -1 below -threshold, 0 between."""
    return np.where(z > threshold, 1, np.where(z < -threshold, -1, 0))


def violations(values: Sequence[float] | np.ndarray, centre: float, sigma: float,
               rules: Sequence[str] = tuple(RULES)) -> list[Violation]:
    """Every firing of ``rules`` in ``values`` against ``centre`` and ``sigma``, in point order
    (a rule fires at the last point of its pattern; a point fires each rule at most once)."""
    unknown = [r for r in rules if r not in RULES]
    if unknown:
        raise ValueError(f"unknown control rule {unknown[0]!r}; known: {', '.join(RULES)}")
    if not sigma > 0:
        raise ValueError(f"a control chart needs sigma > 0, got {sigma}")
    z = (np.asarray(values, float) - centre) / sigma
    fired = {rule: _fires(rule, z) for rule in rules}
    return [Violation(i, rule) for i in range(z.size) for rule in rules if fired[rule][i]]


def _windows(x: np.ndarray, span: int) -> np.ndarray:
    """Row i: the ``span`` points ending at point i + span - 1."""
    return np.lib.stride_tricks.sliding_window_view(x, span)


def _fires(rule: str, z: np.ndarray) -> np.ndarray:
    """Boolean per point: ``rule``'s pattern ends at that point."""
    out = np.zeros(z.size, dtype=bool)
    if rule == "beyond-3-sigma":
        return np.abs(z) > 3
    if rule in ("2-of-3-beyond-2-sigma", "4-of-5-beyond-1-sigma"):
        need, span, threshold = (2, 3, 2.0) if rule.startswith("2") else (4, 5, 1.0)
        if z.size < span:
            return out
        side = _side(z, threshold)
        w = _windows(side, span)
        last = side[span - 1:]  # the pattern ends at a point beyond the threshold, on its side
        out[span - 1:] = (last != 0) & ((w == last[:, None]).sum(axis=1) >= need)
        return out
    if rule == "8-on-one-side":
        if z.size >= 8:
            out[7:] = np.abs(_windows(np.sign(z), 8).sum(axis=1)) == 8
        return out
    if rule == "6-trending":
        if z.size >= 6:
            d = _windows(np.diff(z), 5)
            out[5:] = (d > 0).all(axis=1) | (d < 0).all(axis=1)
        return out
    raise ValueError(rule)


def run_length(values: Sequence[float], centre: float, sigma: float, rules: Sequence[str] = tuple(RULES),
               start: int = 0) -> int | None:
    """Points from ``start`` (counted from 1) until the first firing at or after it; None if none."""
    violations([], centre, sigma, rules)  # the same refusals
    z = (np.asarray(values, float) - centre) / sigma
    fired = np.zeros(z.size, dtype=bool)
    for rule in rules:
        fired |= _fires(rule, z)
    hits = np.flatnonzero(fired[start:])
    return int(hits[0]) + 1 if hits.size else None


def chart(values: Sequence[float], baseline: int = 20, centre: float | None = None,
          sigma: float | None = None, rules: Sequence[str] = tuple(RULES)) -> Chart:
    """The chart of ``values``: centre and sigma declared, or from the first ``baseline`` points
    (mean, and the mean moving range / 1.128, which a slow drift inflates less than the standard
    deviation does), then every rule's firings over all points."""
    v = np.asarray(values, float)
    if not np.isfinite(v).all():
        raise ValueError("a control chart's values must be finite")
    declared = centre is not None and sigma is not None
    if not declared:
        n = min(int(baseline), v.size)
        if n < 2:
            raise ValueError(f"a control chart needs at least 2 baseline points, got {n}")
        base = v[:n]
        centre = float(base.mean()) if centre is None else centre
        sigma = float(np.abs(np.diff(base)).mean() / _D2) if sigma is None else sigma
        baseline = n
    assert centre is not None and sigma is not None
    return Chart(tuple(float(x) for x in v), float(centre), float(sigma), int(baseline), declared,
                 tuple(violations(v, centre, sigma, rules)))


def false_alarm_rate(rules: Sequence[str] = tuple(RULES), n_points: int = 30, trials: int = 2000,
                     seed: int = 0) -> float:
    """Fraction of in-control charts (``n_points`` independent normal points at the declared
    centre and sigma) on which any of ``rules`` fires at least once: the price of the rules."""
    rng = np.random.default_rng(seed)
    fired = sum(bool(violations(rng.standard_normal(n_points), 0.0, 1.0, rules)) for _ in range(trials))
    return fired / trials
