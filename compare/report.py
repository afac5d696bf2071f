"""Comparison reports: one self-contained HTML page, a Markdown summary and a JSON summary.

:func:`compare_records` is the one entry point (the ``bench compare`` command calls it), in two
halves: :func:`compare_candidates` aligns every candidate with the actual record, computes the
statistics of :mod:`compare.stats`, ranks the candidates, judges them by the acceptance criterion
and runs the physical checks of :mod:`compare.checks` on BSDF records, writing nothing (a
:class:`RecordComparison`); :func:`write_report` draws the figures and writes

* ``report.html`` -- figures embedded as base64 PNG (no external resource of any kind), each
  ``<img>`` with a stable ``id`` and ``alt`` (see :func:`figure_ids`);
* ``report.md`` -- the same tables, figures referenced as ``figures/<id>.png``;
* ``summary.json`` -- the returned summary (stable keys);
* ``figures/<id>.png``.

Figures: spectra -- ``fig-spectral-overlay`` (values with k-sigma uncertainty bands) and
``fig-spectral-z`` (discrepancy in sigma units against wavelength); BSDF -- ``fig-in-plane``
(points with ``phi_r`` at ``phi_i`` or ``phi_i + 180``), ``fig-polar-actual``,
``fig-polar-<candidate>`` and ``fig-sigma-<candidate>`` (hemispherical maps of the actual, each
candidate and the discrepancy in sigma units); always ``fig-bland-altman``.
"""

from __future__ import annotations

import base64
import html
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from bench.core.outputs import write_text
from bench.core.records import json_default
from bench.core.roles import Spectrum

from compare.align import AlignmentError, as_record, record_kind, record_meta, record_quantity
from compare.checks import run_checks
from compare.figures import report_figures, slug
from compare.stats import (DEFAULT_ILLUMINANT, DEFAULT_OBSERVER, Comparison, compare, nominal_fraction,
                           group_keys, rank)
from bench.core.budget import budget_summary
from compare.verdict import Criterion, group_verdicts, model_verdict
from compare.report_tables import (budget_note, budget_rows, check_rows, criterion_rows, expected_failure, fit_note,
                                   fit_rows, fmt, frame_rows, group_rows, html_table, md_table, metric_rows,
                                   ranking_rows, verdict_rows)

__all__ = ["compare_records", "compare_candidates", "write_report", "RecordComparison"]


def _json_safe(o: Any) -> Any:
    """Strict JSON values for ``summary.json``: non-finite floats become null; numpy values and
    anything else go through the project's one encoder, :func:`bench.core.records.json_default`."""
    if isinstance(o, dict):
        return {str(k): _json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_json_safe(v) for v in o]
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if o is None or isinstance(o, (bool, int, str)):
        return o
    return _json_safe(json_default(o))


@dataclass(frozen=True)
class RecordComparison:
    """Every candidate against the actual record, computed (no file written, no figure drawn):
    what :func:`compare_candidates` returns and :func:`write_report` renders.

    ``comparisons`` (name -> :class:`compare.stats.Comparison`) and ``records`` (name -> the
    record) hold the candidates that could be compared, ``errors`` (name -> message) those left
    out under ``on_error="skip"``; ``ranking`` is best first by ``primary_metric``; ``checks``
    (record name -> check name -> result dict) the physical checks of BSDF records; ``verdicts``
    (name -> verdict dict with its ``groups``) and ``group_tables`` (name -> the groups as a
    DataFrame) the acceptance criterion's; ``warnings`` the candidates' warnings, rejected
    candidates first; ``uncertainty_budget`` the actual record's budget summary (or ``None``)."""

    actual: Any
    kind: str
    primary_metric: str
    criterion: Criterion
    comparisons: dict[str, Comparison]
    records: dict[str, Any]
    errors: dict[str, str]
    ranking: list[dict[str, Any]]
    checks: dict[str, Any]
    verdicts: dict[str, Any]
    group_tables: dict[str, pd.DataFrame]
    warnings: list[str]
    uncertainty_budget: Any

    @property
    def k(self) -> float:
        return self.criterion.k

    def summary(self, figures: Sequence[Mapping[str, Any]] = (), fits: Mapping[str, Mapping[str, Any]] | None = None,
                fit_figures: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:
        """The report's summary (``summary.json`` before the report paths), given the figures drawn
        and the fits reported (see :func:`compare_records`)."""
        comps, kind = self.comparisons, self.kind
        return {
            "kind": kind, "quantity": record_quantity(self.actual), "actual": _describe(self.actual),
            "primary_metric": self.primary_metric, "k": self.k, "nominal_fraction": nominal_fraction(self.k),
            "candidates": {n: c.summary for n, c in comps.items()}, "ranking": self.ranking,
            "criterion": {**self.criterion.as_dict(), "statement": self.criterion.describe(kind)},
            "verdicts": self.verdicts, "checks": self.checks,
            "unmatched": {n: int((c.aligned.unmatched.side == "actual").sum()) for n, c in comps.items()},
            "errors": self.errors, "warnings": self.warnings, "figures": [f["id"] for f in figures],
            "uncertainty_budget": self.uncertainty_budget,
            "fits": {m: {"fit": f["fit"], "confidence": float(f["confidence"]),
                         "figure": next((g["id"] for g in fit_figures if g["model"] == m), None)}
                     for m, f in (fits or {}).items()},
            "breakdown": {n: {"by_wavelength": c.by_wavelength.to_dict(orient="records"),
                              "by_incidence": c.by_incidence.to_dict(orient="records")} for n, c in comps.items()},
            "alignment": {n: {key: c.aligned.meta.get(key) for key in ("angle_tol_deg", "wavelength_tol_nm",
                                                                       "match_method", "wavelength_interpolation",
                                                                       "channels")}
                          for n, c in comps.items()},
        }


def compare_records(actual: Any, candidates: Mapping[str, Any], report_dir: str | Path, *,
                    primary_metric: str = "chi2_per_dof", title: str | None = None, k: float = 2.0,
                    instrument_uncertainty: float | None = None, instrument_uncertainty_kind: str | None = None,
                    allow_missing_uncertainty: bool = False, illuminant: str = DEFAULT_ILLUMINANT,
                    observer: str = DEFAULT_OBSERVER, checks: bool = True, on_error: str = "raise", draw_figures: bool = True,
                    map_wavelength_nm: float | None = None, map_incidence: tuple[float, float] | None = None,
                    criterion: Criterion | None = None, check_records: Mapping[str, Any] | None = None,
                    fits: Mapping[str, Mapping[str, Any]] | None = None,
                    extra_figures: Sequence[Mapping[str, Any]] = (), **align_kwargs: Any) -> dict[str, Any]:
    """Compare candidates (models, virtual records) with one actual record and write the report:
    :func:`compare_candidates`, then :func:`write_report`.

    Parameters
    ----------
    actual : BSDFRecord, Spectrum or BSDF DataFrame (files are read by the application, e.g.
        :func:`bench.io.read_record`; compare never reads files)
    candidates : mapping name -> record (same types); names label tables, figures and the ranking
    report_dir : folder for ``report.html``, ``report.md``, ``summary.json`` and ``figures/``
    primary_metric : ranking metric, one of :data:`compare.stats.RANK_METRICS` (lower is better)
    title : report title
    k, instrument_uncertainty, instrument_uncertainty_kind, allow_missing_uncertainty,
    illuminant, observer : see :func:`compare.stats.compare`
    checks : run the physical checks on BSDF records (actual and candidates)
    draw_figures : draw the report's figures (most of a report's time); ``False`` writes the
        tables, verdicts and checks only -- batch comparisons, or when only the numbers are read
    on_error : ``"raise"`` (default) or ``"skip"``: a candidate that cannot be compared (bad
        quantity, no overlap, no uncertainty) is left out and its error listed in ``errors``
    map_wavelength_nm, map_incidence : which (wavelength, (theta_i, phi_i)) the single-incidence
        hemispherical maps and the in-plane figure show (default: the worst group of the
        best-ranked model); the small multiples show every incidence
    check_records : more records (name -> BSDFRecord) to run the physical checks on, e.g. each
        model's whole-sphere patch record, on which energy conservation can be tested
    fits : model fits to the actual record to report beside the comparison (the application fits,
        e.g. ``bench compare --fit MODEL``; compare never fits): model string -> ``{"fit": the
        ``bench fit --json`` document, "confidence": its intervals' confidence, "figure": a residual
        figure's path or None}``
    extra_figures : figures the application drew into ``report_dir/figures`` (e.g. the control
        charts of the check standards the actual run relied on), each ``{"id", "path", "group",
        "alt", "caption"}``, shown after the report's own
    criterion : the acceptance criterion (:class:`compare.verdict.Criterion`); its ``k`` and
        instrument uncertainty win over the arguments of the same name
    **align_kwargs : ``angle_tol_deg``, ``wavelength_tol_nm``, ``match``, ``channels``

    Returns
    -------
    dict
        ``kind``, ``quantity``, ``actual`` (description), ``primary_metric``, ``candidates``
        (name -> summary with :data:`compare.stats.SUMMARY_KEYS` plus ``delta_e2000_mean`` etc.),
        ``ranking`` (list, best first), ``checks`` (record name -> check name -> result dict;
        BSDF only), ``unmatched`` (name -> count), ``errors`` (name -> message), ``warnings``,
        ``breakdown`` (name -> ``by_wavelength``/``by_incidence`` lists of per-group metrics),
        ``alignment`` (name -> tolerances and methods), ``fits`` (model -> fit document,
        confidence and figure id; empty when no fit was asked for),
        ``figures`` (ids), ``report_html``, ``report_md``, ``summary_json`` (paths).

    Raises
    ------
    InputError (and subclasses from :mod:`compare.align`, :mod:`compare.stats`)
    """
    result = compare_candidates(actual, candidates, primary_metric=primary_metric, k=k,
                                instrument_uncertainty=instrument_uncertainty,
                                instrument_uncertainty_kind=instrument_uncertainty_kind,
                                allow_missing_uncertainty=allow_missing_uncertainty, illuminant=illuminant,
                                observer=observer, checks=checks, on_error=on_error, criterion=criterion,
                                check_records=check_records, **align_kwargs)
    return write_report(result, report_dir, title=title, draw_figures=draw_figures,
                        map_wavelength_nm=map_wavelength_nm, map_incidence=map_incidence, fits=fits,
                        extra_figures=extra_figures)


def compare_candidates(actual: Any, candidates: Mapping[str, Any], *, primary_metric: str = "chi2_per_dof",
                       k: float = 2.0, instrument_uncertainty: float | None = None,
                       instrument_uncertainty_kind: str | None = None, allow_missing_uncertainty: bool = False,
                       illuminant: str = DEFAULT_ILLUMINANT, observer: str = DEFAULT_OBSERVER, checks: bool = True,
                       on_error: str = "raise", criterion: Criterion | None = None,
                       check_records: Mapping[str, Any] | None = None, **align_kwargs: Any) -> RecordComparison:
    """Align and compare every candidate with the actual record, rank them, judge them by the
    criterion and run the physical checks; nothing is written (parameters as :func:`compare_records`)."""
    if on_error not in ("raise", "skip"):
        raise InputError(f"on_error must be 'raise' or 'skip', got {on_error!r}")
    if not candidates:
        raise InputError("no candidates to compare with the actual record")
    act = as_record(actual)
    if criterion is None:
        criterion = Criterion(k=k, instrument_uncertainty=instrument_uncertainty,
                              instrument_uncertainty_kind=instrument_uncertainty_kind)
    slugs = [slug(n) for n in candidates]
    if len(set(slugs)) != len(slugs):
        raise InputError(f"candidate names must stay distinct as ids: {list(candidates)} -> {slugs}")
    comps: dict[str, Comparison] = {}
    errors: dict[str, str] = {}
    recs: dict[str, Any] = {}
    for name, cand in candidates.items():
        try:
            rec = as_record(cand)
            comps[name] = compare(act, rec, name=name, k=criterion.k,
                                  instrument_uncertainty=criterion.instrument_uncertainty,
                                  instrument_uncertainty_kind=criterion.instrument_uncertainty_kind,
                                  allow_missing_uncertainty=allow_missing_uncertainty, illuminant=illuminant,
                                  observer=observer, **align_kwargs)
            recs[name] = rec
        except InputError as exc:
            if on_error == "raise":
                raise
            errors[name] = f"{type(exc).__name__}: {exc}"
    if not comps:
        raise AlignmentError("no candidate could be compared: " + "; ".join(f"{n}: {e}" for n, e in errors.items()))
    kind = record_kind(act)
    ranking = rank({n: c.summary for n, c in comps.items()}, primary_metric)
    check_results: dict[str, Any] = {}
    if checks and kind == "bsdf":
        for n, rec in {"actual": act, **recs, **dict(check_records or {})}.items():
            rec = as_record(rec)
            meta = getattr(rec, "meta", {}) or {}
            check_results[n] = {c: {**r.as_dict(), "expected": expected_failure(c, meta)}
                                for c, r in run_checks(rec).items()}
    verdicts: dict[str, Any] = {}
    group_tables: dict[str, pd.DataFrame] = {}
    for n, c in comps.items():
        g = group_verdicts(c.points, group_keys(c.points, c.aligned.kind), criterion, c.aligned.kind,
                           c.summary.get("delta_e2000_groups"), c.covariance)
        group_tables[n] = g
        verdicts[n] = {**model_verdict(g, c.summary, criterion), "groups": g.to_dict(orient="records")}
    table = getattr(act, "table", None)
    budget = None if table is None or "uncertainty_budget" not in table else budget_summary(list(table.uncertainty_budget))
    warnings = sorted({w for c in comps.values() for w in c.summary["warnings"]})
    for r in ranking:
        v = verdicts.get(r["name"])
        if v and v["verdict"] == "reject":
            warnings.insert(0, f"{r['name']} (rank {r['rank']}) is rejected: {v['reason']}")
    return RecordComparison(act, kind, primary_metric, criterion, comps, recs, errors, ranking, check_results,
                            verdicts, group_tables, warnings, budget)


def write_report(result: RecordComparison, report_dir: str | Path, *, title: str | None = None,
                 draw_figures: bool = True, map_wavelength_nm: float | None = None,
                 map_incidence: tuple[float, float] | None = None, fits: Mapping[str, Mapping[str, Any]] | None = None,
                 extra_figures: Sequence[Mapping[str, Any]] = ()) -> dict[str, Any]:
    """Draw the figures of a comparison and write ``report.html``, ``report.md`` and
    ``summary.json`` into ``report_dir``; return the summary (parameters as :func:`compare_records`)."""
    out = Path(report_dir)
    figdir = out / "figures"
    figdir.mkdir(parents=True, exist_ok=True)
    comps = result.comparisons
    figures = (report_figures(result.actual, comps, result.records, figdir, result.k, map_wavelength_nm,
                              map_incidence, result.group_tables) if draw_figures else [])
    fit_figures = _fit_figures(fits or {}, figdir)
    figures += fit_figures + [dict(f) for f in extra_figures]
    summary = result.summary(figures, fits, fit_figures)
    title = title or f"Virtual vs actual: {summary['actual'].get('specimen') or result.kind}"
    html_path, md_path, json_path = out / "report.html", out / "report.md", out / "summary.json"
    summary.update({"report_html": str(html_path), "report_md": str(md_path), "summary_json": str(json_path)})
    write_text(html_path, _html(title, summary, comps, figures, result.checks))
    write_text(md_path, _markdown(title, summary, comps, figures, result.checks))
    safe = _json_safe(summary)
    write_text(json_path, json.dumps(safe, indent=1))
    return safe


def _fit_figures(fits: Mapping[str, Mapping[str, Any]], figdir: Path) -> list[dict[str, Any]]:
    """The fits' residual figures, copied into the report's figures folder."""
    import shutil

    out = []
    for m, f in fits.items():
        if f.get("figure"):
            fid = f"fig-fit-{slug(m)}"
            path = figdir / f"{fid}{Path(f['figure']).suffix}"
            if Path(f["figure"]).resolve() != path.resolve():
                shutil.copyfile(f["figure"], path)
            out.append({"id": fid, "model": m, "path": str(path), "group": "fits",
                        "alt": f"normalized residuals of the fit {m}",
                        "caption": f"Fit {m}: residuals in standard uncertainties (whitened by the readings' "
                                   "covariance) per incidence/wavelength group."})
    return out


def _describe(rec: Any) -> dict[str, Any]:
    m = record_meta(rec)
    if isinstance(rec, tuple):
        return {"kind": "spectrum", "quantity": record_quantity(rec), "specimen": ", ".join(m["specimens"]),
                "source": m.get("source"), "seed": m.get("seed"), "geometry": ", ".join(m["geometries"]),
                "n_spectra": len(rec), "n_wavelengths": int(rec[0].wavelengths.size)}
    d = {"kind": record_kind(rec), "quantity": record_quantity(rec), "specimen": m.get("specimen"),
         "source": m.get("source", "virtual" if isinstance(rec, Spectrum) and np.any(rec.N > 0) else None),
         "seed": m.get("seed", getattr(rec, "seed", None))}
    steps = m.get("calibration_steps")
    if isinstance(steps, Mapping):  # a bench run says which calibration steps it took, "none" included
        d["calibration"] = f"dark {steps.get('dark')}, white {steps.get('white')} ({steps.get('white_source')})"
    if isinstance(rec, Spectrum):
        d.update({"geometry": rec.geometry, "n_wavelengths": int(rec.wavelengths.size)})
    else:
        t = rec.table
        d.update({"n_points": int(len(t)), "incidences": sorted({(float(a), float(b)) for a, b in
                                                                 zip(t.theta_i, t.phi_i)}),
                  "wavelengths_nm": sorted(set(map(float, t.wavelength_nm)))})
    return d


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:24px auto;max-width:1200px;color:#222;
line-height:1.4;padding:0 16px}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:2em}
table{border-collapse:collapse;margin:8px 0;font-size:0.85em}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:right;vertical-align:top}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
td.msg{text-align:left}table.verdicts td:nth-child(4),table.groups td:nth-child(3){text-align:left}
.row{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}.scroll{overflow-x:auto;max-width:100%}
figure{margin:16px 0;flex:0 1 auto;max-width:100%}figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:0.85em;color:#555;max-width:900px}
.warn{background:#fff6e0;border-left:4px solid #e0a000;padding:6px 12px}
.muted{color:#666;font-size:0.85em}
"""

_UNMATCHED_LIMIT = 50
_GROUP_LIMIT = 60


def _html(title: str, summary: Mapping[str, Any], comps: Mapping[str, Comparison], figures: list[dict[str, Any]],
          check_results: Mapping[str, Any]) -> str:
    e = html.escape
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{e(title)}</title>"
             f"<style>{_CSS}</style></head><body>", f"<h1>{e(title)}</h1>"]
    parts.append(f"<p class=\"muted\">Generated {e(time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime()))}; "
                 f"quantity {e(str(summary['quantity']))}; coverage factor k = {summary['k']:g} (nominal fraction "
                 f"within {summary['nominal_fraction']:.2%}).</p>")
    parts.append("<h2 id=\"criterion\">Acceptance criterion</h2>")
    parts.append(f"<p id=\"criterion-text\">{e(summary['criterion']['statement'])}</p>")
    parts.append(html_table(*criterion_rows(summary)))
    parts.append("<h2 id=\"verdicts\">Verdicts</h2>")
    parts.append(html_table(*verdict_rows(summary), cls="verdicts"))
    if summary["warnings"]:
        parts.append("<div class=\"warn\" id=\"top-warnings\"><ul>" + "".join(
            f"<li>{e(w)}</li>" for w in summary["warnings"] if " is rejected: " in w or "fail" in w) + "</ul></div>")
    for name in comps:
        parts.append(f"<h3>Groups: {e(name)}</h3>")
        parts.append(html_table(*group_rows(summary, name), cls=f"groups groups-{e(slug(name))}"))
    parts.append("<h2 id=\"actual\">Actual record</h2>")
    parts.append(html_table(["field", "value"], [[k_, fmt(v)] for k_, v in summary["actual"].items()],
                             cls="metadata"))
    if summary.get("uncertainty_budget"):
        parts.append("<h3 id=\"budget\">Uncertainty budget</h3>")
        parts.append(f"<p class=\"muted\">{e(budget_note(summary))}</p>")
        parts.append(html_table(*budget_rows(summary), cls="budget"))
    if summary["fits"]:
        parts.append("<h2 id=\"fits\">Fits to the actual record</h2>")
        parts.append("<p class=\"muted\">Maximum-likelihood parameters of each model asked for (<code>bench fit</code>), "
                     "with intervals at the stated confidence and the goodness of fit.</p>")
        for m, f in summary["fits"].items():
            parts.append(f"<h3 id=\"fit-{e(slug(m))}\">{e(m)}</h3>")
            parts.append(f"<p>{e(fit_note(f['fit'], f['confidence']))}</p>")
            parts.append(html_table(*fit_rows(f["fit"]), cls=f"fit fit-{e(slug(m))}"))
    parts.append("<h2 id=\"ranking\">Model ranking</h2>")
    parts.append(f"<p>Ranked by <b>{e(summary['primary_metric'])}</b> (lower is better).</p>")
    parts.append(html_table(*ranking_rows(summary)))
    parts.append("<h2 id=\"metrics\">Metrics</h2>")
    parts.append(html_table(*metric_rows(summary)))
    parts.append("<p class=\"muted\">z = (virtual - actual) / u_c with u_c = sqrt(u_instrument^2 + s_virtual^2 + "
                 "s_actual^2); chi-square = sum z^2 on dof = number of z's (d^T C^-1 d with the full covariance "
                 "C of the differences when the actual record has GUM budgets); p = chi2.sf(chi2, dof).</p>")
    parts.append("<h2 id=\"figures\">Figures</h2>")
    group = None
    for f in figures:
        if f["group"] != group:
            if group is not None:
                parts.append("</div>")
            parts.append(f"<div class=\"row\" id=\"group-{e(f['group'])}\">")
            group = f["group"]
        data = base64.b64encode(Path(f["path"]).read_bytes()).decode("ascii")
        parts.append(f"<figure><img id=\"{e(f['id'])}\" alt=\"{e(f['alt'])}\" src=\"data:image/png;base64,{data}\">"
                     f"<figcaption>{e(f['caption'])}</figcaption></figure>")
    if group is not None:
        parts.append("</div>")
    if check_results:
        parts.append("<h2 id=\"checks\">Physical checks</h2>")
        head, rows = check_rows(check_results)
        parts.append(html_table(head, rows))
    for name, c in comps.items():
        parts.append(f"<h2 id=\"details-{e(slug(name))}\">Details: {e(name)}</h2>")
        parts.append(f"<p class=\"muted\">Alignment: {e(json.dumps(_json_safe(summary['alignment'][name])))}</p>")
        if len(c.by_wavelength):
            parts.append("<h3>Per wavelength</h3>")
            parts.append(html_table(*frame_rows(c.by_wavelength, list(c.by_wavelength.columns), _GROUP_LIMIT)))
            if len(c.by_wavelength) > _GROUP_LIMIT:
                parts.append(f"<p class=\"muted\">first {_GROUP_LIMIT} of {len(c.by_wavelength)} rows</p>")
        if len(c.by_incidence):
            parts.append("<h3>Per incidence</h3>")
            parts.append(html_table(*frame_rows(c.by_incidence, list(c.by_incidence.columns), _GROUP_LIMIT)))
        um = c.aligned.unmatched
        parts.append(f"<h3 id=\"unmatched-{e(slug(name))}\">Unmatched ({int((um.side == 'actual').sum())} actual "
                     f"points, {int((um.side == 'candidate').sum())} unused candidate groups)</h3>")
        if len(um):
            parts.append(html_table(*frame_rows(um, list(um.columns), _UNMATCHED_LIMIT)))
            if len(um) > _UNMATCHED_LIMIT:
                parts.append(f"<p class=\"muted\">first {_UNMATCHED_LIMIT} of {len(um)} rows</p>")
        else:
            parts.append("<p>Every actual point was matched.</p>")
    parts.append("<h2 id=\"warnings\">Warnings</h2>")
    if summary["warnings"] or summary["errors"]:
        items = [f"<li>{e(w)}</li>" for w in summary["warnings"]]
        items += [f"<li>candidate {e(n)} not compared: {e(m)}</li>" for n, m in summary["errors"].items()]
        parts.append("<div class=\"warn\"><ul>" + "".join(items) + "</ul></div>")
    else:
        parts.append("<p>None.</p>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _markdown(title: str, summary: Mapping[str, Any], comps: Mapping[str, Comparison], figures: list[dict[str, Any]],
              check_results: Mapping[str, Any]) -> str:
    out = [f"# {title}", "", f"Quantity: {summary['quantity']}; k = {summary['k']:g} (nominal fraction within "
           f"{summary['nominal_fraction']:.2%}).", "", "## Acceptance criterion", "", summary["criterion"]["statement"],
           "", md_table(*criterion_rows(summary)), "", "## Verdicts", "", md_table(*verdict_rows(summary)), "", "## Model ranking", "",
           f"Ranked by **{summary['primary_metric']}** (lower is better).", "", md_table(*ranking_rows(summary)),
           "", "## Metrics", "", md_table(*metric_rows(summary)), ""]
    if summary.get("uncertainty_budget"):
        out += ["## Uncertainty budget", "", budget_note(summary), "", md_table(*budget_rows(summary)), ""]
    for m, f in summary["fits"].items():
        out += [f"## Fit: {m}", "", fit_note(f["fit"], f["confidence"]), "", md_table(*fit_rows(f["fit"])), ""]
    out += ["## Figures", ""]
    for f in figures:
        out.append(f"![{f['alt']}](figures/{Path(f['path']).name})")
        out.append(f"*{f['caption']}*")
        out.append("")
    if check_results:
        out += ["## Physical checks", "", md_table(*check_rows(check_results)), ""]
    out += ["## Unmatched", ""]
    for name, c in comps.items():
        um = c.aligned.unmatched
        out.append(f"- {name}: {int((um.side == 'actual').sum())} actual points unmatched, "
                   f"{int((um.side == 'candidate').sum())} candidate groups unused")
        for reason, n in um[um.side == "actual"].reason.value_counts().head(5).items():
            out.append(f"  - {n} x {reason}")
    out += ["", "## Warnings", ""]
    out += [f"- {w}" for w in summary["warnings"]] or ["None."]
    out += [f"- candidate {n} not compared: {m}" for n, m in summary["errors"].items()]
    return "\n".join(out) + "\n"
