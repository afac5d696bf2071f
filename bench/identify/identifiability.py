"""Which free parameters a record (``bench fit``) or a bench (``bench plan --design``) can identify,
from the Fisher information and the profile likelihood.

The Fisher information ``F`` (``J^T C^-1 J``) is scaled by each parameter's search range so that
its eigenvalues compare parameters of different units. A parameter is *not identified* when:

* no reading depends on it: its scaled diagonal is below :data:`RANK_TOL` times the largest
  eigenvalue (e.g. a Lambertian's transmittance from readings that are all reflections);
* it lies in a direction the readings do not constrain: an eigenvalue below :data:`RANK_TOL` times
  the largest, in which it weighs more than :data:`NULL_WEIGHT` (confounded with the others of
  that direction);
* its profile is flat over the whole search range: the interval is the bounds themselves
  (:func:`flat_profiles`).

``rank`` is the number of eigenvalues above the tolerance and ``condition`` the ratio of the
largest to the smallest (infinite when rank deficient). A design whose whole candidate grid, at
any time, leaves a parameter unidentified cannot be fixed by more bench time
(:func:`refuse_unidentifiable`, exit 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from bench.core.errors import InputError

__all__ = ["RANK_TOL", "NULL_WEIGHT", "Identifiability", "identifiability", "flat_profiles", "refuse_unidentifiable"]

#: an eigenvalue of the range-scaled Fisher information below this fraction of the largest is 0
RANK_TOL = 1e-9
#: a parameter whose share of an unconstrained direction exceeds this is not identified
NULL_WEIGHT = 0.05


@dataclass(frozen=True)
class Identifiability:
    """``rank`` and ``condition`` of the scaled Fisher information; ``unidentified``: parameter ->
    why (in the parameters' order)."""

    rank: int
    condition: float
    unidentified: Mapping[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"rank": self.rank, "condition": self.condition if math.isfinite(self.condition) else None,
                "unidentified": dict(self.unidentified)}

    def text(self) -> str:
        return "; ".join(f"{n}: {why}" for n, why in self.unidentified.items())


def identifiability(fisher: np.ndarray, names: Sequence[str], ranges: Sequence[float],
                    where: str = "no reading") -> Identifiability:
    """:class:`Identifiability` of ``fisher`` (parameters in ``names`` order, search ``ranges``);
    ``where`` names what holds the readings in the reasons ("no reading", "no point of the grid")."""
    f = np.asarray(fisher, float)
    n = len(names)
    if f.shape != (n, n) or not np.all(np.isfinite(f)):
        return Identifiability(0, math.inf, {k: "the Fisher information is not finite" for k in names})
    s = np.asarray(ranges, float)
    scaled = f * np.outer(s, s)
    w, v = np.linalg.eigh(0.5 * (scaled + scaled.T))
    top = float(max(w.max(), 0.0))
    why: dict[str, str] = {}
    if top <= 0.0:
        return Identifiability(0, math.inf, {k: f"{where} depends on it" for k in names})
    small = w < RANK_TOL * top
    for i, k in enumerate(names):
        if scaled[i, i] < RANK_TOL * top:
            why[k] = (f"{where} sees transmission" if "transmit" in k else f"{where} depends on it")
    for j in np.flatnonzero(small):
        vec = v[:, j] ** 2
        involved = [names[i] for i in range(n) if vec[i] > NULL_WEIGHT and names[i] not in why]
        for k in involved:
            others = [o for o in names if o != k and vec[names.index(o)] > NULL_WEIGHT]
            why[k] = (f"confounded with {', '.join(others)}: the readings fix only a combination" if others
                      else f"{where} depends on it")
    rank = int(np.count_nonzero(~small))
    condition = math.inf if small.any() else float(top / w.min())
    return Identifiability(rank, condition, {k: why[k] for k in names if k in why})


def flat_profiles(ident: Identifiability, cis: Mapping[str, tuple[float, float]],
                  bounds: Mapping[str, tuple[float, float]]) -> Identifiability:
    """``ident`` with every parameter whose interval is its whole search range added (the profile
    likelihood is flat over the bounds: the record does not identify it)."""
    why = dict(ident.unidentified)
    for k, (lo, hi) in cis.items():
        blo, bhi = bounds[k]
        if k not in why and lo <= blo and hi >= bhi:
            why[k] = f"its interval is the whole search range [{blo:g}, {bhi:g}] (flat profile)"
    return Identifiability(ident.rank, ident.condition, why)


def refuse_unidentifiable(fisher: np.ndarray, names: Sequence[str], ranges: Sequence[float], bench: str) -> None:
    """Raise :class:`InputError` (one line, exit 2) when ``fisher`` -- every candidate point of a
    bench at once, as long as any budget allows -- leaves a parameter unidentified: no bench time
    can fix that design."""
    ident = identifiability(fisher, names, ranges, where="no point of the candidate grid")
    if ident.unidentified:
        raise InputError(f"bench {bench!r} cannot identify {', '.join(ident.unidentified)} at any bench time "
                         f"({ident.text()}); fix or remove the parameter, or use another bench or geometry")
