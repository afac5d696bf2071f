"""The judge of a conformance cell: the invariant's statistics, apart from how the cell ran
(:mod:`harness`). Every function takes an outcome with the attributes of :class:`harness.Outcome`.

False-alarm rates: the matrix as a whole has family-wise rate ``ALPHA_MATRIX`` = 1 %, shared
(Bonferroni) by at most ``MAX_CELLS`` = 200 cells, so each cell has ``ALPHA_CELL`` = 5e-5, split
as 1/2 for its readings (Sidak over them: k = 4.9 for 30 readings), 1/4 for its relative bias
(k = 4.4) and 1/4 for the scatter of repeated triggers; the scatter over seeds of a cell is one
more test at ``ALPHA_CELL / 4``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from truth import truth_of

ALPHA_MATRIX = 0.01
MAX_CELLS = 200
ALPHA_CELL = ALPHA_MATRIX / MAX_CELLS
BLUESKY = ("count", "list_scan", "grid_scan")

Outcome = Any  # harness.Outcome (not imported: the harness imports this module)


def _type_a(budget: Any) -> tuple[float, list[tuple[str, float]]]:
    """(unshared Type A variance, shared Type A (key, signed contribution)) of one budget."""
    var, shared = 0.0, []
    for c in (budget or {}).get("components", []):
        if c.get("type") != "A":
            continue
        contrib = float(c["sensitivity"]) * float(c["standard_uncertainty"])
        if c.get("shared"):
            shared.append((str(c["shared"]), contrib))
        else:
            var += contrib**2
    return var, shared


def sidak_k(alpha: float, n: int) -> float:
    """Two-sided normal quantile so that ``n`` independent readings all pass with prob. 1 - alpha."""
    per = 1.0 - (1.0 - alpha) ** (1.0 / max(n, 1))
    return float(stats.norm.isf(per / 2.0))


def covariance(df: pd.DataFrame, type_a_only: bool = False) -> np.ndarray:
    """The readings' covariance from their GUM budgets: unshared components on the diagonal,
    components sharing a key (within a run; the white certificate across runs: one standard)
    as ``c_i c_j``; a reading without a budget contributes its ``std`` on the diagonal."""
    n = len(df)
    cov = np.zeros((n, n))
    groups: dict[str, list[tuple[int, float]]] = {}
    for i, (budget, std, rid) in enumerate(zip(df.get("uncertainty_budget", [None] * n), df["std"], df["run_id"])):
        comps = (budget or {}).get("components") if isinstance(budget, dict) else None
        if not comps:
            cov[i, i] += 0.0 if type_a_only and budget is not None else float(std) ** 2
            continue
        for c in comps:
            if type_a_only and c.get("type") != "A":
                continue
            contrib = float(c["sensitivity"]) * float(c["standard_uncertainty"])
            if c.get("shared"):
                key = c["shared"] if c["name"] == "white standard certificate" else f"{rid}|{c['shared']}"
                groups.setdefault(f"{c['name']}|{key}", []).append((i, contrib))
            else:
                cov[i, i] += contrib**2
    for members in groups.values():
        idx = np.array([m[0] for m in members])
        c = np.array([m[1] for m in members])
        cov[np.ix_(idx, idx)] += np.outer(c, c)
    return cov


def plainly_completed(outcome: Outcome) -> bool:
    """The run says ``completed`` and nothing else: stored status and reported status both
    ``completed`` and the report names no masked readings."""
    rep = outcome.reported or {}
    said_masked = any(rep.get(k) for k in ("masked", "readings_masked", "masked_readings", "saturated"))
    return (all(s == "completed" for s in outcome.statuses) and rep.get("status", "completed") == "completed"
            and not said_masked)


def check_refusal(outcome: Outcome) -> list[str]:
    """A refusal: exit 2, exactly one line, no motion, no stored point."""
    bad = []
    lines = [ln for ln in outcome.stderr.splitlines() if ln.strip()]
    if outcome.exit_code != 2:
        bad.append(f"refused with exit status {outcome.exit_code}, not 2: {outcome.refusal!r}")
    if outcome.cell.interface not in ("count", "list_scan", "grid_scan") and len(lines) != 1:
        bad.append(f"refusal is {len(lines)} lines, not one: {outcome.stderr[-500:]!r}")
    if "Traceback" in outcome.stderr:
        bad.append("refusal printed a traceback")
    if outcome.moves:
        bad.append(f"refused after {outcome.moves} goniometer moves")
    if outcome.readings is not None and len(outcome.readings):
        bad.append(f"refused but {len(outcome.readings)} readings were stored")
    return bad


def check_invariant(outcome: Outcome, truth: np.ndarray | None = None, scale: float = 1.0,
                    alpha: float = ALPHA_CELL) -> list[str]:
    """The violations of the invariant by ``outcome`` (empty: the cell holds). ``truth`` (one
    value per reading) defaults to :func:`truth.truth_of` the cell's specimen; ``scale``
    multiplies it (a power check: ``scale=1.03`` is a truth 3 % off)."""
    if outcome.refused:
        return check_refusal(outcome)
    df = outcome.readings
    if df is None or len(df) == 0:
        return [f"no refusal and no readings (exit {outcome.exit_code}, statuses {outcome.statuses})"]
    bad = []
    if any(s != "completed" for s in outcome.statuses):
        bad.append(f"run statuses {outcome.statuses} after exit {outcome.exit_code}")
    if df["masked"].any() and plainly_completed(outcome):
        reasons = df.loc[df["masked"], "extra"].map(lambda e: (e or {}).get("mask")).value_counts().to_dict()
        bad.append(f"{int(df['masked'].sum())} of {len(df)} readings masked ({reasons}) in a run reported as "
                   f"plain 'completed'")
    ok = df[~df["masked"]].reset_index(drop=True)
    if len(ok) == 0:
        return bad
    t = (truth_of(outcome.cell.specimen, ok, outcome.aperture_deg) if truth is None
         else np.asarray(truth)[~df["masked"].to_numpy()]) * scale
    value, std = ok["value"].to_numpy(float), ok["std"].to_numpy(float)
    z = (value - t) / std
    k = sidak_k(alpha / 2, len(ok))
    worst = int(np.argmax(np.abs(z)))
    if abs(z[worst]) > k:
        r = ok.iloc[worst]
        bad.append(f"{int(np.sum(np.abs(z) > k))} readings beyond k = {k:.2f}: worst z = {z[worst]:+.2f} at "
                   f"({r.theta_i:.4g}, {r.phi_i:.4g}, {r.theta_r:.4g}, {r.phi_r:.4g}) {r.wavelength_nm:g} nm: "
                   f"{value[worst]:.5g} +- {std[worst]:.2g} vs truth {t[worst]:.5g}")
    b, u_b = relative_bias(ok, t)
    k_b = float(stats.norm.isf(alpha / 8))
    if abs(b) > k_b * u_b:
        bad.append(f"relative bias {b:+.3%} +- {u_b:.3%} beyond k = {k_b:.2f} (GLS over {len(ok)} readings)")
    if outcome.cell.interface == "count":
        bad += check_trigger_scatter(ok, alpha / 4)
    return bad


def relative_bias(ok: pd.DataFrame, t: np.ndarray) -> tuple[float, float]:
    """GLS estimate of the common relative bias ``value / truth - 1`` and its standard
    uncertainty, from the readings' full covariance (:func:`covariance`)."""
    r = ok["value"].to_numpy(float) / t - 1.0
    cov = covariance(ok) / np.outer(t, t)
    cov += np.eye(len(r)) * 1e-12 * np.trace(cov) / len(r)
    one = np.ones(len(r))
    w = np.linalg.solve(cov, one)
    var = 1.0 / float(one @ w)
    return float(var * (w @ r)), float(np.sqrt(var))


def check_trigger_scatter(ok: pd.DataFrame, alpha: float) -> list[str]:
    """Repeated triggers at one geometry (Bluesky ``count``): their scatter about their mean per
    wavelength against the unshared Type A part of the budgets (what differs between triggers
    sharing one white and dark), two-sided chi-square at ``alpha``."""
    chi2, dof = 0.0, 0
    for _, g in ok.groupby("wavelength_nm"):
        if len(g) < 2:
            continue
        var = np.array([_type_a(b)[0] if isinstance(b, dict) else s**2
                        for b, s in zip(g.get("uncertainty_budget", [None] * len(g)), g["std"])])
        v = g["value"].to_numpy(float)
        chi2 += float(np.sum((v - v.mean()) ** 2 / var.mean()))
        dof += len(g) - 1
    if dof == 0:
        return []
    lo, hi = stats.chi2.ppf(alpha / 2, dof), stats.chi2.isf(alpha / 2, dof)
    if not lo <= chi2 <= hi:
        return [f"repeated triggers scatter chi2 = {chi2:.3g} on {dof} dof, outside [{lo:.3g}, {hi:.3g}] "
                f"(the budgets' unshared Type A part)"]
    return []


def check_repeat_scatter(outcomes: list[Outcome], alpha: float = ALPHA_CELL / 4) -> list[str]:
    """The scatter over seeds of one cell's readings against the budgets' Type A part: with
    ``d_s`` the deviations of seed ``s`` from the seeds' mean and ``C`` the Type A covariance,
    ``sum_s d_s' C^-1 d_s`` is chi-square on ``(S - 1) J`` dof (two-sided at ``alpha``)."""
    frames = [o.readings for o in outcomes if not o.refused and o.readings is not None]
    if len(frames) < 2:
        return [f"only {len(frames)} seeds with readings: no scatter to judge"]
    key = ["idx", "wavelength_nm"]
    common = set.intersection(*(set(map(tuple, f.loc[~f["masked"], key].to_numpy())) for f in frames))
    aligned = [f.set_index(key).loc[sorted(common)].reset_index() for f in frames]
    x = np.array([a["value"].to_numpy(float) for a in aligned])
    cov = np.mean([covariance(a, type_a_only=True) for a in aligned], axis=0)
    cov += np.eye(len(cov)) * 1e-12 * np.trace(cov) / len(cov)
    d = x - x.mean(axis=0)
    chi2 = float(sum(di @ np.linalg.solve(cov, di) for di in d))
    dof = (len(frames) - 1) * len(common)
    lo, hi = stats.chi2.ppf(alpha / 2, dof), stats.chi2.isf(alpha / 2, dof)
    if not lo <= chi2 <= hi:
        return [f"scatter over {len(frames)} seeds chi2 = {chi2:.4g} on {dof} dof, outside [{lo:.4g}, {hi:.4g}] "
                f"(Type A part of the budgets)"]
    return []


