"""The tables of a comparison report (:mod:`compare.report`): rows built from the summary, and
their HTML and Markdown forms. Every cell goes through :func:`fmt`, so a number reads the same
in the HTML page, the Markdown summary and the fit section."""

from __future__ import annotations

import html
import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

__all__ = ["fmt", "metric_value", "metric_rows", "ranking_rows", "criterion_rows", "verdict_rows", "group_rows",
           "budget_rows", "budget_note", "expected_failure", "check_rows", "frame_rows", "fit_rows", "fit_note",
           "html_table", "md_table"]

_METRIC_ROWS = [("n_points", "points compared"), ("mean_abs_discrepancy_pct", "mean |discrepancy| (%)"),
                ("rmse", "RMSE"), ("bias", "bias (virtual - actual)"), ("max_abs", "max |difference|"),
                ("chi2", "chi-square (all points, u_c only: criterion-free)"), ("dof", "degrees of freedom"),
                ("chi2_per_dof", "chi-square / dof (criterion-free)"),
                ("p_value", "p-value (all points, u_c only: criterion-free; the verdict tests each group with "
                            "the tolerance)"),
                ("fraction_within_uncertainty", "fraction within k u_c"),
                ("fraction_band", "band of that fraction for a right model (nominal +- 3 binomial s.e.)"),
                ("ba_bias", "Bland-Altman bias"),
                ("ba_limits", "Bland-Altman 95 % limits"), ("delta_e2000_mean", "mean CIEDE2000"),
                ("n_reference_zero", "zero references (excluded from %)"), ("n_both_zero", "zero in both"),
                ("n_no_uncertainty", "no uncertainty"), ("n_unmatched", "unmatched actual points"),
                ("u_model", "instrument uncertainty")]


def fmt(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        v = float(v)
        if not math.isfinite(v):
            return "n/a"
        if v == 0:
            return "0"
        return f"{v:.4g}" if 1e-3 <= abs(v) < 1e5 else f"{v:.3e}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(fmt(x) for x in v) + "]"
    return str(v)


def metric_value(s: Mapping[str, Any], key: str) -> Any:
    ba = s.get("bland_altman") or {}
    if key == "ba_bias":
        return ba.get("bias")
    if key == "ba_limits":
        return None if ba.get("lower") is None else [ba["lower"], ba["upper"]]
    if key == "u_model":
        u = s.get("uncertainty_model") or {}
        return f"{fmt(u.get('instrument'))} {u.get('kind', '')} ({u.get('source', '')})"
    return s.get(key)


def metric_rows(summary: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    names = list(summary["candidates"])
    rows = []
    k = summary["k"]
    for key, label in _METRIC_ROWS:
        if key == "delta_e2000_mean" and summary["kind"] != "spectrum":
            continue
        label = label.replace("k u_c", f"k u_c (k = {k:g})").replace(
            "nominal +- 3", f"nominal {summary['nominal_fraction']:.2%} at k = {k:g}, +- 3")
        rows.append([label] + [fmt(metric_value(summary["candidates"][n], key)) for n in names])
    return ["metric"] + names, rows


def ranking_rows(summary: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    metrics = ["chi2_per_dof", "mean_abs_discrepancy_pct", "rmse", "abs_bias", "max_abs"]
    if summary["kind"] == "spectrum":
        metrics.append("delta_e2000_mean")
    head = ["rank", "candidate"] + [f"{m} (primary)" if m == summary["primary_metric"] else m for m in metrics] + [
        "p_value", "fraction_within_uncertainty", "note"]
    rows = [[fmt(r["rank"]), r["name"]] + [fmt(r[m]) for m in metrics] + [
        fmt(r["p_value"]), fmt(r["fraction_within_uncertainty"]), r["note"]] for r in summary["ranking"]]
    return head, rows


def criterion_rows(summary: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    c = summary["criterion"]
    rows = []
    for key, v in c.items():
        if key == "statement" or (key == "instrument_uncertainty_kind" and v is None):
            continue
        text = fmt(v)
        if key == "instrument_uncertainty" and v is None:  # not given: say what the metrics used instead
            used = sorted({metric_value(s, "u_model") for s in summary["candidates"].values()})
            text = "not given; used " + "; ".join(used)
        rows.append([key, text])
    return ["setting", "value"], rows


def verdict_rows(summary: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    rows = []
    for r in summary["ranking"]:
        v = summary["verdicts"][r["name"]]
        rows.append([r["name"], fmt(r["rank"]), v["verdict"], v["reason"]])
    return ["model", "rank", "verdict", "reason"], rows


def group_rows(summary: Mapping[str, Any], name: str) -> tuple[list[str], list[list[str]]]:
    gs = summary["verdicts"][name]["groups"]
    return (["group", "verdict", "reason", "chi2", "dof", "p-value", "fraction within k u_c"],
            [[g["group"], g["verdict"], g["reason"], fmt(g["chi2"]), fmt(g["dof"]), fmt(g["p_value"]),
              fmt(g["fraction_within"])] for g in gs])


def budget_rows(summary: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    b = summary["uncertainty_budget"]
    head = ["component", "type", "shared between readings", "u (median)", "sensitivity (median)", "contribution (median)",
            "% of value (median)", "% of value (max)"]
    rows = [[c["name"], c["type"], "yes" if c["shared"] else "", fmt(c["standard_uncertainty"]), fmt(c["sensitivity"]),
             fmt(c["contribution"]), fmt(c["relative_pct"]), fmt(c["max_relative_pct"])] for c in b["components"]]
    rows.append(["combined u_c", "", "", "", "", "", fmt(b["combined_relative_pct"]), ""])
    return head, rows


def budget_note(summary: Mapping[str, Any]) -> str:
    b = summary["uncertainty_budget"]
    return (f"GUM budget of the actual record's {b['n_readings']} readings (method {', '.join(b['method'])}, "
            f"k = {', '.join(f'{k:g}' for k in b['k'])}); components shared by the run's readings enter the "
            f"covariance of the comparison once, not once per point.")


#: a physical check -> the specimen property (record metadata) that, when declared false, makes
#: its failure expected, and why
_DECLARED = {"reciprocity": ("reciprocal", "not reciprocal by construction"),
             "isotropy": ("isotropic", "anisotropic by construction")}


def expected_failure(check: str, meta: Mapping[str, Any]) -> str | None:
    """Why a failed ``check`` is expected from what the record's specimen declares (its
    ``reciprocal`` / ``isotropic`` flags), or None when nothing declared explains it."""
    prop = _DECLARED.get(check)
    if prop is None or meta.get(prop[0]) is not False:
        return None
    spec = meta.get("specimen")
    name = str(spec.get("spec", spec) if isinstance(spec, Mapping) else spec or "the specimen")
    return f"expected: {name} declares {prop[0]} = false ({prop[1]})"


def check_rows(check_results: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    head = ["record", "check", "result", "statistic", "p-value", "max z", "n", "offending", "message"]
    rows = []
    for rec, res in check_results.items():
        for name, r in res.items():
            result = ("passed" if r["passed"] else "FAILED") if r["tested"] else "not tested"
            why = r.get("expected") if r["tested"] and not r["passed"] else None
            rows.append([rec, name, result + (" (expected)" if why else ""), fmt(r["statistic"]),
                         fmt(r["p_value"]), fmt(r["max_z"]), fmt(r["n"]), fmt(r["n_offending"]),
                         r["message"] + (f"; {why}" if why else "")])
    return head, rows


def frame_rows(df: pd.DataFrame, cols: Sequence[str], limit: int) -> tuple[list[str], list[list[str]]]:
    cols = [c for c in cols if c in df.columns]
    return list(cols), [[fmt(v) if not isinstance(v, str) else v for v in row]
                        for row in df[cols].head(limit).itertuples(index=False)]


def html_table(head: Sequence[str], rows: Sequence[Sequence[str]], cls: str = "") -> str:
    e = html.escape
    h = "".join(f"<th>{e(str(x))}</th>" for x in head)
    b = "".join("<tr>" + "".join(f"<td>{e(str(x))}</td>" for x in r) + "</tr>" for r in rows)
    return f'<div class="scroll"><table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table></div>'


def md_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    def cell(x: Any) -> str:
        return str(x).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(cell(x) for x in head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(cell(x) for x in r) + " |" for r in rows]
    return "\n".join(lines)


def fit_rows(fit: Mapping[str, Any]) -> tuple[list[str], list[list[str]]]:
    """One row per free parameter of a ``bench fit --json`` document: value, interval, unit."""
    rows = [[name, fmt(p["value"]), fmt(p["ci"][0]), fmt(p["ci"][1]), p.get("unit") or ""]
            for name, p in fit["parameters"].items()]
    return ["parameter", "value", "interval low", "interval high", "unit"], rows


def fit_note(fit: Mapping[str, Any], confidence: float) -> str:
    """The goodness of fit and the correlations of a fit document, in one sentence."""
    names = list(fit["parameters"])
    corr = fit.get("correlation") or {}
    pairs = [f"{a}/{b} {corr[a][b]:+.3f}" for i, a in enumerate(names) for b in names[i + 1:]
             if isinstance((corr.get(a) or {}).get(b), (int, float))]
    state = "converged" if fit["converged"] else "NOT converged (best point reached shown)"
    return (f"{fit['model']}: chi-square {fmt(fit['chi2'])} on {fmt(fit['dof'])} dof, p {fmt(fit['p_value'])}; "
            f"{fit['method']} at {confidence:g} confidence; {state}"
            + (f"; correlation {', '.join(pairs)}" if pairs else "") + ".")
