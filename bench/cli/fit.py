"""``bench fit RECORD --model "FAMILY:p=?,q=VALUE,r=?lo:hi"``: maximum-likelihood parameters of a
model with intervals and a goodness of fit (:func:`bench.identify.fit_record`).

RECORD is a file any registered loader reads (tidy CSV, Parquet, ASTM, Zemax, ``bench spectro
--csv``, ``bench gonio --json``) or a run id in ``--store``. With ``--store`` the fit is kept as
a run of kind ``fit`` whose metadata links the record (``bench runs`` / ``bench show`` list it).
Exit 0 for a converged fit, 1 (with the best point reached) for one that did not converge or was
stopped by ``--max-seconds`` (default 60 s), 2 for input the user can fix.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.cli.argtypes import count, real, renamed, seed
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, PLOT_SUFFIXES, add_force_option, emit_json, open_store, output_file
from bench.core.errors import InputError

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading numpy or the fit
    import numpy as np

    from bench.identify import FitResult
    from bench.identify.likelihood import FitInput, Likelihood

#: wall-clock limit of ``bench fit`` (s): a fit that has not finished by then shows its best point
DEFAULT_MAX_SECONDS = 60.0


def _record(ref: str, store_path: str, partial: bool = False) -> tuple[FitInput, str | None, dict[str, int]]:
    """(record, run id or None, why readings without a value have none) for a file path or a
    stored run id; a run that did not complete is refused unless ``partial``."""
    path = Path(ref)
    if path.exists():
        from bench.io import read_record

        return read_record(path), None, {}
    if not Path(store_path).exists():
        raise InputError(f"{ref!r} is neither a file nor a run (no store at {store_path})")
    from bench.io import load_run

    with open_store(store_path, create=False, readonly=True) as store:
        s = store.summary(ref)
        if s["kind"] == "fit":
            raise InputError(f"run {ref} is a fit (it holds a result, not readings); fit the record it names")
        if s["status"] != "completed" and not partial:
            planned = "?" if s["points_planned"] is None else s["points_planned"]
            raise InputError(f"run {ref} is {s['status']} ({s['points_done']} of {planned} points measured): "
                             f"`bench resume {ref}` finishes it, or pass --partial to fit the points it has")
        return load_run(store, ref), ref, store.masked_readings(ref)


def _values(record: FitInput) -> np.ndarray:
    """Every reading value of a record (BSDF table or spectra), as floats."""
    import numpy as np

    from bench.core.records import BSDFRecord

    if isinstance(record, BSDFRecord):
        return record.table["value"].to_numpy(float) if "value" in record.table.columns else np.zeros(0)
    spectra = record if isinstance(record, (tuple, list)) else (record,)
    return np.concatenate([np.asarray(getattr(sp, "reflectance", ()), float) for sp in spectra] or [np.zeros(0)])


def dropped_readings(record: FitInput, lik: Likelihood, masked: dict[str, int]) -> dict[str, Any] | None:
    """What a fit of calibrated readings leaves out: ``{"dropped", "of", "reasons"}`` (the mask
    reasons the store recorded; "no value" for the rest), or None for counts or nothing dropped."""
    import numpy as np

    if getattr(lik, "kind", None) != "gaussian":
        return None
    values = _values(record)
    n = int(np.count_nonzero(~np.isfinite(values)))
    if not n:
        return None
    reasons = {str(k): int(v) for k, v in masked.items() if v}
    rest = n - sum(reasons.values())
    if rest > 0:
        reasons["no value"] = rest
    return {"dropped": n, "of": int(values.size), "reasons": reasons}


def _fit_json(result: FitResult) -> dict[str, Any]:
    """``result.to_json()`` with the intervals a fit stopped by its time limit lacks as null."""
    import math

    doc = result.to_json()
    for p in doc["parameters"].values():
        p["ci"] = [c if c is not None and math.isfinite(c) else None for c in p["ci"]]
    return doc


def _store_fit(store_path: str, result: FitResult, ref: str, run_id: str | None, args: argparse.Namespace,
               dropped: dict[str, Any] | None = None) -> str:
    """Keep the fit as a run of kind ``fit`` linked to its record (with the readings it left out
    and whether it fitted part of a run); return its id."""
    meta = {"fit": _fit_json(result), "specimen": result.specimen, "record": run_id or str(Path(ref).resolve()),
            "record_run_id": run_id, "fit_seed": args.seed, "starts": args.starts, "dropped": dropped,
            "partial": bool(run_id is not None and args.partial)}
    with open_store(store_path) as store:
        rid = store.create_run(kind="fit", meta=meta, n_planned=0)
        store.set_status(rid, "completed" if result.converged else "failed",
                         None if result.converged else f"fit did not converge: {result.message}")
    return rid


def _print(result: FitResult) -> None:
    from bench.identify.fit import OUTLIER_Z

    print(f"model {result.model}  ({result.method}, {result.confidence:g} confidence)")
    for name, p in result.parameters.items():
        unit = f" {p.unit}" if p.unit else ""
        print(f"  {result.label(name):10s} {p.value:.6g}{unit}  [{p.ci[0]:.6g}, {p.ci[1]:.6g}]")
    if len(result.parameters) > 1:
        names = [result.label(n) for n in result.parameters]
        pairs = [f"{a}/{b} {result.correlation[i, j]:+.3f}" for i, a in enumerate(names)
                 for j, b in enumerate(names) if j > i]
        print("  correlation: " + ", ".join(pairs))
    p_text = f"{result.p_value:.3g}" if result.p_value == result.p_value else "n/a"
    ident = result.identifiability
    unidentified = f", but NOT identified: {ident.text()}" if ident is not None and ident.unidentified else ""
    print(f"  chi2 {result.chi2:.4g}, dof {result.dof}, p {p_text}; "
          + (f"converged{unidentified}" if result.converged else f"NOT converged ({result.message})"))
    if result.outliers:
        print(f"  {len(result.outliers)} reading(s) more than {OUTLIER_Z:g} standard uncertainties from the fitted model"
              + (", the 5 largest:" if len(result.outliers) > 5 else ":"))
    for o in result.outliers[:5]:
        where = (f"theta_i {o['theta_i']:g}, theta_r {o['theta_r']:g} deg" if "theta_r" in o
                 else str(o.get("geometry", "")))
        print(f"  outlier: reading {o['reading']} ({where}, {o['wavelength_nm']:g} nm) value {o['value']:.6g}, "
              f"z {o['z']:+.1f}")
    print(f"  best-fit specimen: {result.specimen}")


def cmd_fit(args: argparse.Namespace) -> int:
    from bench.identify import fit_record, parse_model_spec
    from bench.identify.likelihood import GaussianReadings, likelihood_for

    spec = parse_model_spec(args.model)  # a bad model string costs no record reading
    record, run_id, masked = _record(args.record, args.store or DEFAULT_STORE, args.partial)
    if run_id is not None and args.partial:
        print(f"bench fit: --partial: fitting the points run {run_id} has", file=sys.stderr)
    lik = likelihood_for(record)
    dropped = dropped_readings(record, lik, masked)
    if dropped:
        why = ", ".join(f"{k} {v}" for k, v in sorted(dropped["reasons"].items()))
        print(f"bench fit: left out {dropped['dropped']} of {dropped['of']} readings that have no value ({why})",
              file=sys.stderr)
    n_free = len(spec.free)
    if isinstance(lik, GaussianReadings) and len(lik.values) <= n_free:  # its n_data: one per reading
        raise InputError(f"{args.record}: {len(lik.values)} readings for {n_free} free parameter(s): no degrees of "
                         f"freedom left to judge the fit (dof <= 0); measure more, or fix parameters")
    result = fit_record(record, spec, confidence=args.confidence, interval=args.interval, starts=args.starts,
                        seed=args.seed, likelihood=lik, max_seconds=args.max_seconds)
    if result.dof <= 0:
        raise InputError(f"{args.record}: {result.dof} degrees of freedom for {n_free} free parameter(s): the record "
                         f"cannot judge the fit (dof <= 0); measure more, or fix parameters")
    if args.plot:
        from bench.identify.figure import plot_residuals

        plot_residuals(result, args.plot)
    if args.store:
        rid = _store_fit(args.store, result, args.record, run_id, args, dropped)
        print(f"bench fit: stored as run {rid} in {args.store}", file=sys.stderr)
    if args.json:
        emit_json(_fit_json(result))
    else:
        _print(result)
    if not result.converged:
        print(f"bench fit: failed: the fit did not converge ({result.message}); the best point reached is "
              f"shown", file=sys.stderr)
        return 1
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help=command_help("fit"))
    p.add_argument("record", metavar="RECORD", help="a record file (any format bench reads) or a run id in --store")
    p.add_argument("--model", required=True, metavar="FAMILY:p=?,q=VALUE,r=?lo:hi",
                   help="the model: free parameters marked ?, optional ?lo:hi bounds inside the declared range, "
                        "others fixed or at their defaults (`bench specimens` lists them)")
    p.add_argument("--store", metavar="FILE.sqlite",
                   help=f"the run store: where RECORD run ids are read (default {DEFAULT_STORE}); given, the fit "
                        "is also kept there as a run of kind fit")
    p.add_argument("--confidence", type=real(0.0, 1.0, lo_open=True, hi_open=True), default=0.95,
                   help="confidence of the intervals, in (0, 1) (default %(default)s)")
    p.add_argument("--interval", choices=("profile", "hessian"), default="profile",
                   help="profile likelihood, or the Hessian's normal approximation (fast) (default %(default)s)")
    p.add_argument("--starts", type=count(0, 4096), default=None, metavar="N",
                   help="Sobol points of the global step (default 4 per free parameter; 0: defaults only)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the Sobol points (default %(default)s)")
    p.add_argument("--plot", type=output_file(PLOT_SUFFIXES), metavar="FILE.png",
                   help="also draw the residuals per incidence/wavelength to this image (png, pdf, svg, ...; "
                        "default: none)")
    renamed(p, "--figure", "--plot", "was fit's residual figure; every command draws its figure with --plot FILE")
    p.add_argument("--max-seconds", type=real(0.0, 1e6, lo_open=True), default=DEFAULT_MAX_SECONDS, metavar="S",
                   help="time limit of the fit (wall clock), s: past it the best point so far is shown, without intervals, "
                        "and the exit status is 1 (default %(default)g)")
    p.add_argument("--partial", action="store_true",
                   help="fit a stored run that did not complete (interrupted, failed, running) on the points it has "
                        "(default: refused)")
    p.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    add_force_option(p, "plot")
    p.set_defaults(func=cmd_fit)
