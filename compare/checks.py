"""Physical checks on any BSDF record, each with its evidence.

* :func:`reciprocity` -- Helmholtz: ``f(wi -> wo) = f(wo -> wi)`` (reflection only). Pairs are
  built wherever the swapped geometry exists in the record: with several incidences, the value
  at incidence I1 seen in the patch (or direction) containing I2 against the value at I2 seen
  in the patch containing I1.
* :func:`energy_conservation` -- ``sum value * psa <= 1`` per incidence and wavelength (the
  directional-hemispherical albedo), flagged only when significantly above 1.
* :func:`isotropy` -- with several ``phi_i`` at the same ``theta_i``: values at the same
  ``(theta_r, phi_r - phi_i)`` agree; with a single incidence: mirror symmetry about the plane of
  incidence, ``f(phi) = f(2 phi_i - phi)`` (an anisotropic specimen whose symmetry axis lies in
  the plane of incidence passes this one; turn the specimen to see its anisotropy).

Discrepancies are in units of the combined standard uncertainty of the two values
(``sqrt(s1^2 + s2^2 + (u_rel f1)^2 + (u_rel f2)^2)``; the relative instrument term defaults to 0
for virtual records and to 0.5 % for measured ones). A check is ``passed`` when its p-value is at
least ``alpha`` (default 0.01); ``tested`` is False when the record holds no usable evidence
(then ``passed`` is True and the message says what is missing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from bench.core.records import BSDFRecord

from compare.align import _bsdf_long, _locate_patch, angular_distance_deg, as_record, is_virtual
from compare.stats import GONIO_UNCERTAINTY

__all__ = ["CheckResult", "reciprocity", "energy_conservation", "isotropy", "run_checks"]


@dataclass
class CheckResult:
    """Outcome of one physical check.

    Attributes
    ----------
    name : ``"reciprocity"``, ``"energy_conservation"`` or ``"isotropy"``
    passed : bool
    tested : False when the record has no evidence for this check
    statistic : chi-square of the pair z-scores (reciprocity, isotropy) or the largest albedo z
        (energy conservation); None when not tested
    p_value : chi-square p-value (``scipy.stats.chi2.sf``), or the Bonferroni-corrected one-sided
        normal p-value of the largest albedo excess
    max_z : largest ``|z|`` (pairs) or largest ``(albedo - 1) / u`` (energy)
    n : number of pairs or groups examined
    evidence : every pair/group with its z (DataFrame)
    offending : the rows of ``evidence`` beyond the threshold
    message : one line for people
    """

    name: str
    passed: bool
    tested: bool
    statistic: float | None
    p_value: float | None
    max_z: float | None
    n: int
    evidence: pd.DataFrame = field(repr=False)
    offending: pd.DataFrame = field(repr=False)
    message: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "passed": self.passed, "tested": self.tested, "statistic": self.statistic,
                "p_value": self.p_value, "max_z": self.max_z, "n": self.n, "n_offending": int(len(self.offending)),
                "message": self.message}


def _rel_u(rec: BSDFRecord, instrument_uncertainty: float | None) -> float:
    if instrument_uncertainty is not None:
        if not (math.isfinite(instrument_uncertainty) and instrument_uncertainty >= 0):
            raise InputError(f"instrument_uncertainty must be finite and >= 0, got {instrument_uncertainty}")
        return float(instrument_uncertainty)
    m = rec.meta.get("instrument_uncertainty")
    if m is not None:
        return float(m)
    return 0.0 if is_virtual(rec) else GONIO_UNCERTAINTY


def _lookup(group: pd.DataFrame, theta: np.ndarray, phi: np.ndarray, channel: str, tol: float) -> np.ndarray:
    """Positions in ``group`` of the patch containing each direction (or the nearest direction
    within ``tol`` when the record has no patch bounds); -1 when none."""
    if len(group) == 0:
        return np.full(len(theta), -1)
    bounds = group[["theta_min", "theta_max", "phi_min", "phi_max"]].to_numpy(float)
    if np.all(np.isfinite(bounds)):
        return _locate_patch(np.asarray(theta, float), np.mod(phi, 360.0), np.full(len(theta), channel, dtype=object),
                             group)
    d = angular_distance_deg(np.asarray(theta, float)[:, None], np.asarray(phi, float)[:, None],
                             group.theta_r.to_numpy(float)[None, :], group.phi_r.to_numpy(float)[None, :])
    j = np.argmin(d, axis=1)
    return np.where(d[np.arange(len(theta)), j] <= tol, j, -1)


def _pair_result(name: str, ev: pd.DataFrame, alpha: float, k_offend: float, what: str,
                 missing: str) -> CheckResult:
    from scipy.stats import chi2 as chi2_dist

    if ev.empty:
        return CheckResult(name, True, False, None, None, None, 0, ev, ev, f"not tested: {missing}")
    z = ev.z.to_numpy(float)
    usable = np.isfinite(z)
    if not usable.any():
        return CheckResult(name, True, False, None, None, None, int(len(ev)), ev, ev.iloc[0:0],
                           f"not tested: {len(ev)} {what} but none has an uncertainty (std missing or both zero)")
    chi2 = float(np.sum(z[usable] ** 2))
    dof = int(usable.sum())
    p = float(chi2_dist.sf(chi2, dof))
    max_z = float(np.max(np.abs(z[usable])))
    offending = ev[usable & (np.abs(np.nan_to_num(z)) > k_offend)]
    passed = p >= alpha
    msg = (f"{'passed' if passed else 'FAILED'}: {dof} {what}, chi2 = {chi2:.4g} on {dof} dof, p = {p:.3g} "
           f"(alpha {alpha:g}), max |z| = {max_z:.3g}, {len(offending)} beyond {k_offend:g} sigma")
    return CheckResult(name, passed, True, chi2, p, max_z, dof, ev, offending, msg)


def _pair_z(f1: np.ndarray, s1: np.ndarray, f2: np.ndarray, s2: np.ndarray, u_rel: float) -> np.ndarray:
    u = np.sqrt(np.nan_to_num(s1) ** 2 + np.nan_to_num(s2) ** 2 + (u_rel * f1) ** 2 + (u_rel * f2) ** 2)
    both0 = (f1 == 0) & (f2 == 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((u > 0) & ~both0, (f1 - f2) / np.where(u > 0, u, 1.0), np.nan)


def _pairs_with_z(rows: list[dict[str, Any]], first: str, second: str, u_rel: float) -> pd.DataFrame:
    """The pairs as a frame with the z-score of ``f_<first>`` against ``f_<second>``."""
    ev = pd.DataFrame(rows)
    if not ev.empty:
        f1, s1, f2, s2 = (ev[f"{q}_{side}"].to_numpy(float) for side in (first, second) for q in ("f", "std"))
        ev["z"] = _pair_z(f1, s1, f2, s2, u_rel)
    return ev


def reciprocity(record: Any, *, angle_tol_deg: float = 1.0, alpha: float = 0.01, k_offend: float = 3.0,
                instrument_uncertainty: float | None = None) -> CheckResult:
    """Helmholtz reciprocity between every pair of incidences (same wavelength, reflection).

    For incidences I1 = (t1, p1) and I2 = (t2, p2) the record must hold a value at I1 viewed in
    the patch containing direction I2 (``f12``) and one at I2 viewed in the patch containing I1
    (``f21``); ``z = (f12 - f21) / sqrt(s12^2 + s21^2 + u_inst^2)``. Patch values are averages
    over a patch, so a BRDF that varies strongly across one patch can fail even when reciprocal
    (use finer collectors for glossy specimens).
    """
    rec = as_record(record)
    if not isinstance(rec, BSDFRecord):
        raise InputError("reciprocity needs a BSDF record")
    u_rel = _rel_u(rec, instrument_uncertainty)
    t = _bsdf_long(rec)
    t = t[t.channel == "R"]
    rows = []
    for w, gw in t.groupby("wavelength_nm", sort=True):
        incs = [tuple(k) for k, _ in gw.groupby(["theta_i", "phi_i"], sort=True)]
        groups = {k: g.reset_index(drop=True) for k, g in gw.groupby(["theta_i", "phi_i"], sort=True)}
        for a in range(len(incs)):
            for b in range(a + 1, len(incs)):
                i1, i2 = incs[a], incs[b]
                if float(angular_distance_deg(i1[0], i1[1], i2[0], i2[1])) <= angle_tol_deg:
                    continue
                g1, g2 = groups[i1], groups[i2]
                j12 = int(_lookup(g1, np.array([i2[0]]), np.array([i2[1]]), "R", angle_tol_deg)[0])
                j21 = int(_lookup(g2, np.array([i1[0]]), np.array([i1[1]]), "R", angle_tol_deg)[0])
                if j12 < 0 or j21 < 0:
                    continue
                r12, r21 = g1.iloc[j12], g2.iloc[j21]
                rows.append({"wavelength_nm": w, "theta_1": i1[0], "phi_1": i1[1], "theta_2": i2[0], "phi_2": i2[1],
                             "f_12": r12.value, "std_12": r12["std"], "view_12": (r12.theta_r, r12.phi_r),
                             "f_21": r21.value, "std_21": r21["std"], "view_21": (r21.theta_r, r21.phi_r)})
    ev = _pairs_with_z(rows, "12", "21", u_rel)
    return _pair_result("reciprocity", ev, alpha, k_offend, "reciprocal pairs",
                        "no reciprocal pairs (needs records at two or more incidences whose swapped "
                        "geometries are both present)")


def energy_conservation(record: Any, *, alpha: float = 0.01, instrument_uncertainty: float | None = None,
                        ) -> CheckResult:
    """Albedo ``A = sum value * psa`` (both hemispheres) per incidence and wavelength <= 1.

    Its standard uncertainty is the binomial ``sqrt(A (1 - A) / N)`` when the record has counts
    and ``N`` (a virtual collector: the total is one binomial count), else
    ``sqrt(sum (std psa)^2)``, plus the relative instrument term ``u_inst A``. A group is flagged
    when ``z = (A - 1) / u`` exceeds the one-sided normal quantile at ``alpha / n_groups``
    (Bonferroni); ``p_value`` is the corrected p-value of the largest z. Records without ``psa``
    (or without a whole-hemisphere coverage) cannot be tested; the coverage ``sum psa`` is
    reported (pi for a full hemisphere).
    """
    from scipy.stats import norm

    rec = as_record(record)
    if not isinstance(rec, BSDFRecord):
        raise InputError("energy conservation needs a BSDF record")
    u_rel = _rel_u(rec, instrument_uncertainty)
    tab = rec.table
    if "psa" not in tab or not np.all(np.isfinite(tab.psa.to_numpy(float))):
        ev = pd.DataFrame()
        return CheckResult("energy_conservation", True, False, None, None, None, 0, ev, ev,
                           "not tested: the record has no projected solid angles (psa) for every point")
    rows = []
    for (w, ti, pi_), g in tab.groupby(["wavelength_nm", "theta_i", "phi_i"], sort=True):
        psa = g.psa.to_numpy(float)
        a = float(np.sum(g.value.to_numpy(float) * psa))
        if {"count", "N"} <= set(g.columns) and np.all(np.isfinite(g["count"].to_numpy(float))) \
                and float(g.N.iloc[0]) > 0:
            n = float(g.N.iloc[0])
            p = float(np.sum(g["count"].to_numpy(float))) / n
            u = math.sqrt(max(p * (1 - p), 0.25 / n) / n)  # never 0: at p in {0,1} use the 1/(2N) floor
            how = "binomial"
        else:
            s = g["std"].to_numpy(float) if "std" in g else np.full(len(g), np.nan)
            u = float(np.sqrt(np.nansum((s * psa) ** 2)))
            how = "sum of patch std"
        u = math.sqrt(u ** 2 + (u_rel * a) ** 2)
        coverage = {h: float(g[g.hemisphere == h].psa.sum()) for h in ("R", "T")} if "hemisphere" in g else {}
        rows.append({"wavelength_nm": w, "theta_i": ti, "phi_i": pi_, "albedo": a, "u": u, "u_method": how,
                     "z": (a - 1.0) / u if u > 0 else (math.inf if a > 1 else -math.inf),
                     "psa_R": coverage.get("R"), "psa_T": coverage.get("T"), "n_patches": int(len(g))})
    ev = pd.DataFrame(rows)
    n = len(ev)
    zc = float(norm.isf(alpha / n))
    max_z = float(ev.z.max())
    p = min(1.0, float(norm.sf(max_z)) * n)
    off = ev[ev.z > zc]
    passed = off.empty
    msg = (f"{'passed' if passed else 'FAILED'}: {n} incidence/wavelength groups, albedo "
           f"{ev.albedo.min():.4g}-{ev.albedo.max():.4g}, largest (A - 1)/u = {max_z:.3g} "
           f"(threshold {zc:.3g}, one-sided, Bonferroni alpha {alpha:g}); {len(off)} above 1 significantly")
    return CheckResult("energy_conservation", passed, True, max_z, p, max_z, n, ev, off, msg)


def isotropy(record: Any, *, angle_tol_deg: float = 1.0, alpha: float = 0.01, k_offend: float = 3.0,
             instrument_uncertainty: float | None = None) -> CheckResult:
    """Isotropy: values at the same ``(theta_i, theta_r, phi_r - phi_i)`` but different ``phi_i``
    agree; for a ``theta_i`` present at a single ``phi_i``, mirror symmetry about the plane of
    incidence (``f(theta_r, phi)`` vs ``f(theta_r, 2 phi_i - phi)``, each unordered pair once)."""
    rec = as_record(record)
    if not isinstance(rec, BSDFRecord):
        raise InputError("isotropy needs a BSDF record")
    u_rel = _rel_u(rec, instrument_uncertainty)
    t = _bsdf_long(rec)
    rows = []
    for (w, ch, ti), g in t.groupby(["wavelength_nm", "channel", "theta_i"], sort=True):
        phis = sorted(g.phi_i.unique())
        groups = {p: g[g.phi_i == p].reset_index(drop=True) for p in phis}
        if len(phis) > 1 and ti > 1e-9:
            ref = groups[phis[0]]
            for p in phis[1:]:
                other = groups[p]
                rel_phi = other.phi_r.to_numpy(float) - p + phis[0]
                j = _lookup(ref, other.theta_r.to_numpy(float), rel_phi, ch, angle_tol_deg)
                for r, jj in zip(other.itertuples(index=False), j):
                    if jj < 0:
                        continue
                    q = ref.iloc[int(jj)]
                    rows.append({"test": "rotation", "wavelength_nm": w, "hemisphere": ch, "theta_i": ti,
                                 "phi_i_1": phis[0], "phi_i_2": p, "theta_r": r.theta_r,
                                 "dphi": (r.phi_r - p) % 360.0, "f_1": q.value, "std_1": q["std"],
                                 "f_2": r.value, "std_2": r.std})
        else:
            p = phis[0]
            grp = groups[p]
            mirror = (2.0 * p - grp.phi_r.to_numpy(float)) % 360.0
            j = _lookup(grp, grp.theta_r.to_numpy(float), mirror, ch, angle_tol_deg)
            seen = set()
            for i, jj in enumerate(j):
                if jj < 0 or jj == i or (min(i, jj), max(i, jj)) in seen:
                    continue
                seen.add((min(i, jj), max(i, jj)))
                a, b = grp.iloc[i], grp.iloc[int(jj)]
                rows.append({"test": "mirror", "wavelength_nm": w, "hemisphere": ch, "theta_i": ti,
                             "phi_i_1": p, "phi_i_2": p, "theta_r": a.theta_r, "phi_r_1": a.phi_r,
                             "phi_r_2": b.phi_r, "f_1": a.value, "std_1": a["std"], "f_2": b.value,
                             "std_2": b["std"]})
    ev = _pairs_with_z(rows, "1", "2", u_rel)
    return _pair_result("isotropy", ev, alpha, k_offend, "symmetric pairs",
                        "no symmetric pairs (needs patches mirrored about the plane of incidence, or the same "
                        "theta_i at several phi_i)")


def run_checks(record: Any, **kwargs: Any) -> dict[str, CheckResult]:
    """All three checks with shared keyword arguments (those a check does not take are ignored)."""
    out = {}
    pairs = {"angle_tol_deg", "alpha", "k_offend", "instrument_uncertainty"}
    for name, fn, keys in (("reciprocity", reciprocity, pairs),
                           ("energy_conservation", energy_conservation, {"alpha", "instrument_uncertainty"}),
                           ("isotropy", isotropy, pairs)):
        out[name] = fn(record, **{k: v for k, v in kwargs.items() if k in keys})
    return out
