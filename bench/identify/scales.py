"""Shared multiplicative errors of calibrated readings, fitted as nuisance scales (no Peelle bias).

A calibrated reading is ``y_i = mu_i(theta) (1 + sum_k a_ik z_k) + e_i``: the white standard's
certificate scales every reading of the run, the white reference reading every reading of its
wavelength, the Type A lamp drift each reading by its lit index; ``z_k`` is one standard normal
per shared input and ``a_ik = c_ik u_k / y_i`` its relative loading from the reading's budget
(:data:`SCALE_INPUTS`). ``e`` holds everything else (counting noise, darks: additive, their
covariance :math:`V` from the budgets as before).

Building the covariance of the shared terms from the *measured* values (``c_i = y_i / R_w``, the
budgets' own sensitivities) gives low readings less variance and more weight, so the fit lands
below the readings (Peelle's pertinent puzzle: 1.5 and 1.0 with 10 % independent and 20 % shared
relative errors give 0.88 by generalized least squares). Here the scales are parameters of the
fit with their priors ``z_k ~ N(0, 1)``, profiled out exactly: for a given ``theta`` the
deviance ``|L^-1 (y - mu - B z)|^2 + |z|^2`` (``B = diag(mu) A``, ``L L^T = V``) is quadratic in
``z``, so the optimum ``z`` is one small linear solve (:meth:`SharedScales.profile`). Its minimum
equals ``(y - mu)^T (V + B B^T)^-1 (y - mu)``: the same as a covariance built from the model
prediction (Woodbury), which is why the design's Fisher information (rank-one certificate term
on the predicted values) and the fit agree. Each prior adds one pseudo-observation and each
scale one parameter, so the goodness of fit's degrees of freedom are unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from bench.core.budget import LAMP_DRIFT, WHITE_CERTIFICATE, WHITE_READING, budget_covariance

__all__ = ["SCALE_INPUTS", "SharedScales", "split_scales"]

#: shared inputs whose effect is a relative scale of the reading (sensitivity proportional to it)
SCALE_INPUTS = (WHITE_CERTIFICATE, WHITE_READING, LAMP_DRIFT)


@dataclass(frozen=True)
class SharedScales:
    """The shared scales of a set of readings: ``names`` (input and what shares it) and the
    relative loadings ``a`` (readings x scales)."""

    names: tuple[str, ...]
    loadings: np.ndarray

    @property
    def count(self) -> int:
        return len(self.names)

    def profile(self, chol: np.ndarray, y: np.ndarray, mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(residuals, z): the whitened residuals at the optimum scales followed by the scales'
        prior residuals ``z``; ``sum(residuals**2)`` is the profiled deviance."""
        from scipy.linalg import solve_triangular

        d = solve_triangular(chol, y - mu, lower=True)
        if not self.names:
            return d, np.zeros(0)
        g = solve_triangular(chol, mu[:, None] * self.loadings, lower=True)
        z = np.linalg.solve(g.T @ g + np.eye(self.count), g.T @ d)
        return np.concatenate([d - g @ z, z]), z

    def factors(self, z: np.ndarray) -> dict[str, float]:
        """The fitted scale of each shared input, ``1 + a z`` at a reading it loads (the median)."""
        out = {}
        for k, name in enumerate(self.names):
            a = self.loadings[:, k]
            out[name] = float(1.0 + np.median(a[a != 0]) * z[k]) if np.any(a != 0) else 1.0
        return out


def split_scales(budgets: Sequence[Any], std: np.ndarray) -> tuple[np.ndarray, SharedScales]:
    """(covariance without the shared scales, the shared scales) of readings with GUM budgets
    (dicts or JSON, as :meth:`bench.core.budget.Budget.as_dict`; ``std`` for readings without
    one). A reading whose value is 0 cannot carry a relative loading: its shared terms stay in
    the covariance."""
    parsed = [json.loads(b) if isinstance(b, str) else b for b in budgets]
    std = np.array(std, dtype=float)
    rest: list[Any] = []
    columns: dict[tuple[str, str], dict[int, float]] = {}
    for i, b in enumerate(parsed):
        if not isinstance(b, Mapping) or not b.get("components"):
            rest.append(b)
            continue
        value = float(b.get("value", 0.0))
        keep, gone2 = [], 0.0
        for c in b["components"]:
            shared = c.get("shared")
            if shared is not None and c["name"] in SCALE_INPUTS and value != 0.0:
                a = float(c["sensitivity"]) * float(c["standard_uncertainty"]) / value
                columns.setdefault((str(c["name"]), str(shared)), {})[i] = a
                gone2 += float(c["contribution"]) ** 2
            else:
                keep.append(c)
        combined = float(np.sqrt(max(float(b["combined"]) ** 2 - gone2, 0.0)))
        std[i] = combined
        rest.append({**b, "components": keep, "combined": combined} if keep else None)
    cov = budget_covariance(rest, std)
    loadings = np.zeros((len(parsed), len(columns)))
    for k, rows in enumerate(columns.values()):
        for i, a in rows.items():
            loadings[i, k] = a
    return cov, SharedScales(tuple(f"{n} ({s})" for n, s in columns), loadings)
