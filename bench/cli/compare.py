"""``bench compare ACTUAL CANDIDATE [CANDIDATE ...]``: discrepancy statistics and a report.

Each record is a run id in ``--store`` or a file in any format of the :mod:`bench.io` registry
(tidy CSV, Parquet, ASTM CSV, Zemax ``.bsdf``, spectrum CSV); ``NAME=RUN`` labels a record. The
files are read here, through :func:`bench.io.read_record`: :mod:`compare` takes records only.
The summary keys of ``--json`` are stable.

The acceptance criterion (:class:`compare.verdict.Criterion`) is stated up front: ``--alpha``,
``--k``, ``--instrument-uncertainty`` (``--uncertainty-kind``), ``--tolerance``,
``--delta-e-tolerance``, or a ``--config FILE.toml`` whose ``[criterion]`` table holds the same
keys (``alpha``, ``k``, ``instrument_uncertainty``, ``instrument_uncertainty_kind``,
``tolerance``, ``delta_e_tolerance``, ``min_points``, ``max_rel_uncertainty``) and whose
``[compare]`` table may set ``metric``, ``title``, ``angle_tol_deg``, ``wavelength_tol_nm``.
Flags win over the file. The text output prints the criterion, then one verdict per model
(accept / reject / inconclusive with the reason) and the failing groups.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from bench.cli.argtypes import real, renamed, stderr_is_terminal
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, output_dir
from bench.core.errors import InputError

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading the records or the fit
    from bench.identify.likelihood import FitInput
    from bench.identify.model_spec import ModelSpec

#: the confidence of the intervals of `bench compare --fit` (that of `bench fit`'s default)
FIT_CONFIDENCE = 0.95

HEADLINE = ("n_points", "mean_abs_discrepancy_pct", "rmse", "bias", "max_abs", "chi2", "p_value",
            "fraction_within_uncertainty", "delta_e2000_mean")


class _Tolerances(TypedDict, total=False):
    """The alignment tolerances a settings file gives (:func:`compare.align.align`'s keywords)."""

    angle_tol_deg: float
    wavelength_tol_nm: float


def _load(ref: str, store_path: str) -> tuple[str, FitInput]:
    """(label, record) for ``[NAME=]RUN_OR_FILE``."""
    name, _, what = ref.rpartition("=") if "=" in ref and not Path(ref).exists() else ("", "", ref)
    path = Path(what)
    if path.exists():
        from bench.io import read_record

        return name or path.stem, read_record(path)
    from bench.store import RunStore

    if not Path(store_path).exists():
        raise InputError(f"{what!r} is neither a file nor a run (no store at {store_path})")
    from bench.io import load_run

    with RunStore(store_path, create=False, readonly=True) as store:
        record = load_run(store, what)
    meta = record[0].meta if isinstance(record, tuple) else record.meta
    spec = None if isinstance(record, tuple) else ((meta.get("bench") or {}).get("specimen") or {}).get("spec")
    return name or (f"{what} ({spec})" if spec else what), record


_CRITERION_FLAGS = {"alpha": "alpha", "k": "k", "instrument_uncertainty": "instrument_uncertainty",
                    "uncertainty_kind": "instrument_uncertainty_kind", "tolerance": "tolerance",
                    "delta_e_tolerance": "delta_e_tolerance"}


def _settings(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """(criterion, compare options) from ``--config`` and the flags (flags win)."""
    from bench.core.parsing import read_toml
    from compare.verdict import Criterion

    cfg = read_toml(args.config, "compare config") if args.config else {}
    unknown = sorted(set(cfg) - {"criterion", "compare"})
    if unknown:
        raise InputError(f"compare config {args.config}: unknown table(s) {unknown}; known: criterion, compare")
    crit = dict(cfg.get("criterion", {}))
    for flag, key in _CRITERION_FLAGS.items():
        if getattr(args, flag) is not None:
            crit[key] = getattr(args, flag)
    opts = dict(cfg.get("compare", {}))
    bad = sorted(set(opts) - {"metric", "title", "angle_tol_deg", "wavelength_tol_nm"})
    if bad:
        raise InputError(f"compare config {args.config}: unknown [compare] key(s) {bad}")
    if args.metric is not None:
        opts["metric"] = args.metric
    if args.title is not None:
        opts["title"] = args.title
    return Criterion.from_mapping(crit), opts


def _fit_models(strings: list[str]) -> dict[str, ModelSpec]:
    from bench.identify import parse_model_spec

    return {m: parse_model_spec(m) for m in dict.fromkeys(strings)}


def _fits(actual: FitInput, models: dict[str, ModelSpec], out: Path, draw_figures: bool) -> dict[str, dict[str, Any]]:
    """``bench fit`` of each ``--fit`` model to the actual record, for the report's fit section."""
    if not models:
        return {}
    from bench.identify import fit_record
    from bench.identify.figure import plot_residuals
    from compare.figures import slug

    fits = {}
    for m, spec in models.items():
        result = fit_record(actual, spec, confidence=FIT_CONFIDENCE)
        figure = None
        if draw_figures:  # drawn where the report keeps it (compare.report's fig-fit-<slug>), not copied
            (out / "figures").mkdir(parents=True, exist_ok=True)
            figure = str(plot_residuals(result, out / "figures" / f"fig-fit-{slug(m)}.png"))
        fits[m] = {"fit": result.to_json(), "confidence": FIT_CONFIDENCE, "figure": figure}
    return fits


def _assurance_figures(actual: FitInput, store_path: str, out: Path, draw_figures: bool) -> list[dict[str, Any]]:
    """The control charts of the check standards the actual run relied on (a ``bench scan`` on a
    bench declaring ``assurance``), each up to the check the scan relied on, drawn for the report."""
    meta = (actual[0].meta if isinstance(actual, tuple) else getattr(actual, "meta", None)) or {}
    if not draw_figures or not meta.get("assurance") or not Path(store_path).exists():
        return []
    from bench.assurance import relied_charts
    from bench.cli.assurance import plot_charts
    from bench.store import RunStore

    with RunStore(store_path, create=False, readonly=True) as store:
        charts = relied_charts(store, meta)
    if not charts:
        return []
    path = out / "figures" / "fig-assurance.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    plot_charts(charts, str(path), str((meta.get("bench") or {}).get("name", "bench")))
    names = ", ".join(c.name for c, _, _ in charts)
    return [{"id": "fig-assurance", "path": str(path), "group": "assurance",
             "alt": f"control charts of the check standards the actual run relied on ({names})",
             "caption": f"Measurement assurance: the Shewhart charts of {names} up to the check the actual run "
                        f"relied on (centre and 1-3 sigma limits; squares: a Western Electric / Nelson rule "
                        f"broken)."}]


def cmd_compare(args: argparse.Namespace) -> int:
    from compare.report import compare_records

    from tqdm import tqdm

    criterion, opts = _settings(args)
    models = _fit_models(args.fit or [])  # a bad model string costs no record reading
    # progress with an ETA on a terminal: one step per record read, one for the statistics and report
    with tqdm(total=len(args.candidates) + 2, disable=not stderr_is_terminal(), desc="compare", unit="step",
              leave=False, dynamic_ncols=True) as bar:
        actual_name, actual = _load(args.actual, args.store)
        bar.update()
        candidates = {}
        for c in args.candidates:
            name, record = _load(c, args.store)
            candidates[name] = record
            bar.update()
        out = Path(args.out or "compare-report")
        fits = _fits(actual, models, out, draw_figures=not args.no_figures)
        align_kw = _Tolerances()
        if "angle_tol_deg" in opts:
            align_kw["angle_tol_deg"] = float(opts["angle_tol_deg"])
        if "wavelength_tol_nm" in opts:
            align_kw["wavelength_tol_nm"] = float(opts["wavelength_tol_nm"])
        summary = compare_records(actual, candidates, out, primary_metric=opts.get("metric", "chi2_per_dof"),
                                  title=opts.get("title") or f"{', '.join(candidates)} against {actual_name}",
                                  on_error="skip" if args.skip_bad else "raise", criterion=criterion,
                                  draw_figures=not args.no_figures, fits=fits,
                                  extra_figures=_assurance_figures(actual, args.store, out, not args.no_figures),
                                  **align_kw)
        bar.update()
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"actual: {actual_name}")
    print(f"criterion: {summary['criterion']['statement']}")
    for rank, entry in enumerate(summary["ranking"], 1):
        name = entry["name"]
        s = summary["candidates"][name]
        v = summary["verdicts"][name]
        parts = [f"{k} {s[k]:.4g}" for k in HEADLINE if isinstance(s.get(k), (int, float))]
        print(f"  #{rank} {name}: {v['verdict'].upper()} ({v['reason']})")
        print("      " + ", ".join(parts))
    for name, err in summary["errors"].items():
        print(f"  not compared: {name}: {err}")
    for model, f in summary["fits"].items():
        fit = f["fit"]
        values = ", ".join(f"{n} {p['value']:.5g} [{p['ci'][0]:.5g}, {p['ci'][1]:.5g}]"
                           for n, p in fit["parameters"].items())
        p_value = "n/a" if fit["p_value"] is None else f"{fit['p_value']:.3g}"
        print(f"  fit {model}: {values}; chi2 {fit['chi2']:.4g}, dof {fit['dof']}, p {p_value}"
              + ("" if fit["converged"] else " (NOT converged)"))
    for w in summary["warnings"]:
        print(f"  warning: {w}")
    print(f"report: {summary['report_html']} (and {summary['report_md']})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help=command_help("compare"))
    p.add_argument("actual", metavar="ACTUAL", help="[NAME=]RUN or FILE")
    p.add_argument("candidates", metavar="CANDIDATE", nargs="+", help="[NAME=]RUN or FILE")
    p.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite",
                   help="the run store holding RUN ids, opened read-only (default %(default)s)")
    p.add_argument("--out", type=output_dir, metavar="DIR", help="output folder of the report (default ./compare-report)")
    renamed(p, "--report", "--out", "was the report folder; --out names every command's output, a file or a folder "
            "(bench demo --out DIR)")
    p.add_argument("--config", metavar="FILE.toml",
                   help="compare config: [criterion] and [compare] tables (default: none, the flags below)")
    p.add_argument("--alpha", type=real(0, 1, lo_open=True, hi_open=True),
                   help="family-wise false-rejection rate of a right model (default 0.01)")
    p.add_argument("--k", type=real(0, 100, lo_open=True),
                   help="coverage factor of 'fraction within k u_c' (default 2)")
    p.add_argument("--instrument-uncertainty", type=real(0, 1e6), metavar="U",
                   help="the actual instrument's standard uncertainty (default: the record's or the instrument "
                        "default)")
    p.add_argument("--uncertainty-kind", choices=("absolute", "relative"),
                   help="kind of --instrument-uncertainty (default: relative for BSDF, absolute for spectra)")
    p.add_argument("--tolerance", type=real(0, 1e6),
                   help="model tolerance: standard uncertainty a model may have (relative for BSDF, absolute "
                        "for spectra), added in quadrature (default 0)")
    p.add_argument("--delta-e-tolerance", type=real(0, 1000), metavar="DE",
                   help="spectra: reject a model with a CIEDE2000 above DE for any spectrum (default: none)")
    p.add_argument("--metric", default=None,
                   choices=("chi2_per_dof", "mean_abs_discrepancy_pct", "rmse", "abs_bias", "max_abs",
                            "delta_e2000_mean"), help="ranking metric, lower is better (default chi2_per_dof)")
    p.add_argument("--title", help="report title (default: the candidates against the actual)")
    p.add_argument("--no-figures", action="store_true",
                   help="write the report's tables and verdicts without drawing its figures (faster)")
    p.add_argument("--skip-bad", action="store_true", help="leave out candidates that cannot be compared")
    p.add_argument("--fit", action="append", metavar="FAMILY:p=?,...",
                   help="also fit this model to the actual record (as `bench fit`, intervals at "
                        f"{FIT_CONFIDENCE:g}) and report its parameters, goodness of fit and residuals; "
                        "repeat for more models (default: no fit)")
    p.add_argument("--json", action="store_true", help="the summary as one JSON object with stable keys")
    p.set_defaults(func=cmd_compare)
