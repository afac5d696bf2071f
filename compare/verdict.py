"""Verdicts: does a model agree with the actual record, as a whole and in every group?

The acceptance criterion (:class:`Criterion`) is stated before any number is looked at:

* ``alpha`` -- the family-wise false-rejection rate of a model that is right. Every group
  (incidence x wavelength for a BSDF, specimen x CIE geometry for spectra, per specimen and
  collector when the record holds several) is tested at ``alpha / n_groups`` (Bonferroni), so a
  correct model is rejected anywhere with probability <= ``alpha``.
* ``k`` -- coverage factor of the "fraction within k u_c" shown next to the test.
* ``instrument_uncertainty`` (and its kind) -- the actual instrument's standard uncertainty,
  entering ``u_c`` (see :func:`compare.stats.point_table`).
* ``tolerance`` -- how far a model may be from the truth and still be accepted: a standard
  uncertainty of the model, relative to the actual value for a BSDF (0.05 = 5 %) and absolute
  for spectra, added in quadrature to ``u_c``. 0 asks "is the model statistically
  indistinguishable from the record".
* ``delta_e_tolerance`` -- spectra: largest CIEDE2000 accepted per spectrum (None: not used).
* ``min_points``, ``max_rel_uncertainty`` -- a group with fewer points carrying an uncertainty,
  or whose median ``u_c / |actual|`` is above this, cannot reject a model twice off: its
  verdict is *inconclusive* (not accept).

Group verdict: ``reject`` when chi-square of ``z = (virtual - actual) / sqrt(u_c^2 + u_tol^2)``
(with the full covariance of the differences when the actual record has GUM budgets:
``d^T (C + diag u_tol^2)^-1 d``) has ``p < alpha / n_groups``; ``inconclusive`` as above; else ``accept``. Model verdict:
``reject`` naming every failing group (even when the pooled statistics look fine), else
``inconclusive`` when no group could decide, else ``accept`` (with the count of inconclusive
groups).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from compare._covariance import chi_square, sub_covariance

__all__ = ["Criterion", "group_verdicts", "model_verdict", "VERDICTS"]

VERDICTS = ("accept", "reject", "inconclusive")


@dataclass(frozen=True)
class Criterion:
    """The acceptance criterion (see the module docstring)."""

    alpha: float = 0.01
    k: float = 2.0
    instrument_uncertainty: float | None = None
    instrument_uncertainty_kind: str | None = None
    tolerance: float = 0.0
    delta_e_tolerance: float | None = None
    min_points: int = 3
    max_rel_uncertainty: float = 0.5

    def __post_init__(self) -> None:
        if not (0 < self.alpha < 1):
            raise InputError(f"alpha must be in (0, 1), got {self.alpha}")
        if not (math.isfinite(self.k) and self.k > 0):
            raise InputError(f"k must be finite and > 0, got {self.k}")
        if not (math.isfinite(self.tolerance) and self.tolerance >= 0):
            raise InputError(f"tolerance must be finite and >= 0, got {self.tolerance}")
        if self.instrument_uncertainty is not None and not (math.isfinite(self.instrument_uncertainty)
                                                            and self.instrument_uncertainty >= 0):
            raise InputError(f"instrument uncertainty must be finite and >= 0, got {self.instrument_uncertainty}")
        if self.instrument_uncertainty_kind not in (None, "absolute", "relative"):
            raise InputError(f"instrument uncertainty kind must be 'absolute' or 'relative', "
                             f"got {self.instrument_uncertainty_kind!r}")
        if self.delta_e_tolerance is not None and not (self.delta_e_tolerance > 0):
            raise InputError(f"delta E tolerance must be > 0, got {self.delta_e_tolerance}")
        if self.min_points < 1:
            raise InputError(f"min_points must be >= 1, got {self.min_points}")
        if not self.max_rel_uncertainty > 0:
            raise InputError(f"max_rel_uncertainty must be > 0, got {self.max_rel_uncertainty}")

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any]) -> "Criterion":
        """From a config mapping (the ``[criterion]`` table of a compare config); unknown keys
        are an :class:`InputError` naming them."""
        known = set(cls.__dataclass_fields__)
        bad = sorted(set(m) - known)
        if bad:
            raise InputError(f"unknown criterion key(s) {bad}; known: {sorted(known)}")
        return cls(**dict(m))

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def describe(self, kind: str) -> str:
        tol = (f"{self.tolerance:g} relative" if kind == "bsdf" else f"{self.tolerance:g} absolute")
        u = ("the record's own / the instrument default" if self.instrument_uncertainty is None
             else f"{self.instrument_uncertainty:g} {self.instrument_uncertainty_kind or 'default kind'}")
        de = "" if self.delta_e_tolerance is None else f"; CIEDE2000 <= {self.delta_e_tolerance:g} per spectrum"
        return (f"reject when chi-square of z = (virtual - actual) / sqrt(u_c^2 + u_tol^2) has p < alpha / "
                f"n_groups in any group (alpha = {self.alpha:g}, family-wise); instrument uncertainty {u}; "
                f"model tolerance u_tol {tol}; k = {self.k:g}; a group with < {self.min_points} points with "
                f"uncertainty or median u_c/|actual| > {self.max_rel_uncertainty:g} is inconclusive{de}")


def _tol_z(p: pd.DataFrame, crit: Criterion, kind: str) -> np.ndarray:
    a = p.actual_value.to_numpy(float)
    u_tol = crit.tolerance * (np.abs(a) if kind == "bsdf" else np.ones_like(a))
    u = np.sqrt(p.u_combined.to_numpy(float) ** 2 + u_tol ** 2)
    d = p["diff"].to_numpy(float)
    ok = (p.z_note.to_numpy(object) == "") & (u > 0)
    return np.where(ok, d / np.where(u > 0, u, 1.0), np.nan)


def _test(p: pd.DataFrame, crit: Criterion, kind: str, alpha: float, cov: np.ndarray | None = None) -> dict[str, Any]:
    from scipy.stats import chi2 as chi2_dist

    z = _tol_z(p, crit, kind)
    ok = np.isfinite(z)
    z = z[ok]
    a = np.abs(p.actual_value.to_numpy(float))
    uc = p.u_combined.to_numpy(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(a > 0, uc / a, np.inf)
    med_rel = float(np.median(rel)) if rel.size else math.inf
    out: dict[str, Any] = {"n_points": int(len(p)), "dof": int(z.size), "chi2": None, "p_value": None,
                           "alpha_group": alpha, "median_rel_uncertainty": med_rel,
                           "fraction_within": float(np.mean(np.abs(z) <= crit.k)) if z.size else None}
    if len(p) and bool((p["diff"].to_numpy(float) == 0).all()):
        out.update(verdict="accept", reason="identical values")
        return out
    if z.size < crit.min_points:
        out.update(verdict="inconclusive", reason=f"{z.size} points with an uncertainty (< {crit.min_points})")
        return out
    if cov is None:
        chi2 = float(np.sum(z ** 2))
    else:  # the full covariance of the differences, the model tolerance on its diagonal
        a = p.actual_value.to_numpy(float)[ok]
        u_tol = crit.tolerance * (np.abs(a) if kind == "bsdf" else np.ones_like(a))
        chi2 = chi_square(p["diff"].to_numpy(float)[ok], cov[np.ix_(ok, ok)] + np.diag(u_tol**2))
    pv = float(chi2_dist.sf(chi2, z.size))
    out.update(chi2=chi2, p_value=pv)
    if pv < alpha:
        out.update(verdict="reject", reason=f"chi2 {chi2:.4g} on {z.size} dof, p = {pv:.3g} < {alpha:.3g}")
    elif kind == "bsdf" and med_rel > crit.max_rel_uncertainty:
        out.update(verdict="inconclusive", reason=f"median u_c/|actual| = {med_rel:.3g} > "
                                                  f"{crit.max_rel_uncertainty:g}: too uncertain to decide")
    else:
        out.update(verdict="accept", reason=f"chi2 {chi2:.4g} on {z.size} dof, p = {pv:.3g} >= {alpha:.3g}")
    return out


def _label(keys: Sequence[str], key: tuple) -> str:
    parts = []
    for k, v in zip(keys, key):
        if k in ("theta_i", "phi_i"):
            parts.append(f"{k} = {float(v):g} deg")
        elif k == "wavelength_nm":
            parts.append(f"{float(v):g} nm")
        else:
            parts.append(f"{k} {v}")
    return ", ".join(parts)


def group_verdicts(points: pd.DataFrame, keys: Sequence[str], crit: Criterion, kind: str,
                   delta_e: Sequence[Mapping[str, Any]] | None = None,
                   covariance: np.ndarray | None = None) -> pd.DataFrame:
    """One row per group of ``keys``: ``group`` (a readable label), the key values, ``verdict``,
    ``reason``, ``chi2``, ``dof``, ``p_value``, ``fraction_within``, ``median_rel_uncertainty``.
    Rows are sorted worst first (reject, then by p-value). With ``covariance`` (of the
    differences, rows as ``points``: :attr:`compare.stats.Comparison.covariance`) each group's
    chi-square is ``d^T C^-1 d`` on its block (Bonferroni holds under any correlation between
    groups)."""
    groups = list(points.groupby(list(keys), sort=True, dropna=False)) if keys else [((), points)]
    n = max(len(groups), 1)
    rows = []
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        test = _test(g, crit, kind, crit.alpha / n, sub_covariance(points, g, covariance))
        r = {"group": _label(keys, key), **dict(zip(keys, key)), **test}
        if delta_e is not None and crit.delta_e_tolerance is not None:
            kv = dict(zip(keys, key))
            de = [d["delta_e2000"] for d in delta_e
                  if all(str(d.get(c)) == str(kv[c]) for c in ("specimen", "geometry", "channel") if c in kv)]
            worst = max(de) if de else None
            r["delta_e2000"] = worst
            if worst is not None and worst > crit.delta_e_tolerance:
                r["verdict"] = "reject"
                r["reason"] = f"CIEDE2000 {worst:.3g} > {crit.delta_e_tolerance:g}; " + r["reason"]
        rows.append(r)
    df = pd.DataFrame(rows)
    order = {"reject": 0, "inconclusive": 1, "accept": 2}
    df["_o"] = df.verdict.map(order)
    df["_p"] = pd.to_numeric(df.p_value, errors="coerce").fillna(1.0)
    return df.sort_values(["_o", "_p"], kind="stable").drop(columns=["_o", "_p"]).reset_index(drop=True)


def model_verdict(groups: pd.DataFrame, pooled: Mapping[str, Any], crit: Criterion) -> dict[str, Any]:
    """The verdict on one model from its group verdicts (and the pooled test, reported along)."""
    rej = groups[groups.verdict == "reject"]
    inc = groups[groups.verdict == "inconclusive"]
    n = len(groups)
    if len(rej):
        names = "; ".join(rej.group.head(5)) + (f" (and {len(rej) - 5} more)" if len(rej) > 5 else "")
        return {"verdict": "reject", "failing_groups": list(rej.group),
                "reason": f"{len(rej)} of {n} groups fail: {names}"}
    if len(inc) == n:
        return {"verdict": "inconclusive", "failing_groups": [],
                "reason": f"no group could decide ({inc.reason.iloc[0] if n else 'no groups'})"}
    note = f"; {len(inc)} inconclusive" if len(inc) else ""
    return {"verdict": "accept", "failing_groups": [],
            "reason": f"all {n - len(inc)} decided groups consistent at family-wise alpha {crit.alpha:g}{note}"}
