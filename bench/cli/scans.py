"""Scans on a bench and the runs they leave: ``bench plan``, ``scan``, ``resume``, ``runs``,
``show`` and ``export``.

Plans and bench configs load through :mod:`bench.plans` and :mod:`bench.config`; runs are read
from the store (:mod:`bench.store`); exports are written through :mod:`bench.io`.
"""

from __future__ import annotations

import argparse
import sys

from bench.cli.argtypes import RegistryChoices, real, run_id, seed
from bench.cli.commands import command_help
from bench.cli.common import (DEFAULT_STORE, add_bench_options, announce_compilation, check_output, emit_json, hms,
                               open_store, report_run)
from bench.core.errors import InputError

__all__ = ["register", "cmd_plan", "cmd_scan", "cmd_resume", "cmd_runs", "cmd_show", "cmd_export"]


def _plan_and_bench(args: argparse.Namespace):
    from bench.config import load_bench
    from bench.plans import load_plan

    plan = load_plan(args.plan)
    bench = load_bench(args.bench, seed=getattr(args, "seed", None), body=args.body)
    return plan, bench


def cmd_plan(args: argparse.Namespace) -> int:
    """Check and time a plan on a bench: JSON keys ``points`` (all of the plan's), ``refused``
    (each with theta_i, phi_i, theta_r, phi_r, rule, message), ``seconds`` and ``motion_s`` (of the
    reachable points), ``calibration_refused`` (a calibration step the bench cannot take, or null).
    A plan ``bench scan`` would refuse exits 2 (its JSON still printed)."""
    from bench.core.errors import CalibrationRefused, PlanError
    from bench.plans import MotionProfile, estimate, order_for_travel, refusal_message, refusals
    from bench.preflight import check_calibration_steps
    from bench.runner import stored_white

    plan, bench = _plan_and_bench(args)
    with bench:
        refused = refusals(plan, bench.goniometer.check)
        calibration = None  # what `bench scan` would refuse about the calibration steps, if anything
        try:
            check_calibration_steps(bench, plan, stored_white(bench) if plan.white != "none" else None)
        except CalibrationRefused as exc:
            calibration = str(exc)
        skipped = {r.index for r in refused}
        profile = bench.motion or MotionProfile.instantaneous()
        kw = {"joints": bench.joints} if bench.joints is not None else {}
        given_order = [i for i in range(len(plan.points)) if i not in skipped]
        order = [i for i in order_for_travel(plan.points) if i not in skipped] if plan.order == "travel" else given_order
        est = estimate(plan, profile, order, **kw)
        given = estimate(plan, profile, given_order, **kw)
    out = {"plan": plan.name, "kind": plan.kind, "bench": bench.name, "bench_kind": bench.kind, **est,
           "points": len(plan.points), "reachable": len(order), "unreachable": plan.unreachable,
           "refused": [r.as_dict() for r in refused], "calibration_refused": calibration,
           "seconds_in_given_order": given["seconds"], "integration_s": plan.integration_s,
           "averages": plan.averages}
    refuse = bool(refused) and plan.unreachable != "skip"
    if args.json:
        emit_json(out)
        return 2 if refuse or calibration else 0
    if refuse:
        raise PlanError(refusal_message(plan, refused))
    if calibration:
        raise CalibrationRefused(calibration)
    head = (f"all {est['points']} points reachable" if not refused else
            f"{len(order)} of {len(plan.points)} points reachable, {len(refused)} skipped "
            f"({', '.join(sorted({r.rule for r in refused}))})")
    print(f"plan {plan.name} ({plan.kind}) on bench {bench.name} ({bench.kind}): {head}, {est['incidences']} incidences")
    print(f"  estimated duration {hms(est['seconds'])}: motion {hms(est['motion_s'])}, acquisition "
          f"{hms(est['acquisition_s'])}, references {hms(est['references_s'])}"
          f"  (in the order given: {hms(given['seconds'])})")
    print(f"  expected relative uncertainty per point {est['relative_uncertainty']:.2%} "
          f"({plan.averages} averages x {plan.integration_s:g} s)")
    return 0


def cmd_scan(args: argparse.Namespace) -> int:
    from bench.runner import run_scan

    plan, bench = _plan_and_bench(args)
    if bench.kind == "virtual":
        announce_compilation()
    with bench, open_store(args.store) as store:
        result = run_scan(bench, plan, store, seed=getattr(bench.goniometer, "seed", args.seed),
                          progress=not args.quiet and sys.stderr.isatty())
    return report_run(result, args.json)


def cmd_resume(args: argparse.Namespace) -> int:
    from bench.config import load_bench
    from bench.runner import resume_scan

    with open_store(args.store, create=False, readonly=True) as store:
        stored = store.run(args.run)
    kind = stored["kind"]
    if kind == "bluesky" and "bluesky_plan" in (stored.get("plan") or {}):
        raise InputError(f"run {args.run} was recorded by a Bluesky RunEngine from its plan "
                         f"{stored['plan'].get('bluesky_plan')!r}: a RunEngine resumes a paused run only in the "
                         f"process that paused it, so run that plan again (a bench plan run through the RunEngine, "
                         f"or by `bench scan`, can be finished here)")
    if kind == "sweep":
        from bench.cli.sweep import resume_run

        return resume_run(args.run, args.store, quiet=args.quiet, json=args.json)
    with open_store(args.store, create=False) as store:
        info = store.run(args.run)
        config = args.bench if args.bench else info["bench"]
        body = args.body or (info.get("meta") or {}).get("bench_kind")  # the body the run started on
        bench = load_bench(config, seed=info.get("seed"), body=body)
        with bench:
            result = resume_scan(bench, store, args.run, progress=not args.quiet and sys.stderr.isatty())
    return report_run(result, args.json)


def cmd_runs(args: argparse.Namespace) -> int:
    with open_store(args.store, create=False, readonly=True) as store:
        runs = store.runs()
    if args.json:
        emit_json(runs)
        return 0
    print(f"{'run':<24} {'kind':<6} {'status':<12} {'points':>11}  created (UTC)")
    for r in runs:
        pts = f"{r['points_done']}/{r['n_planned'] if r['n_planned'] is not None else '?'}"
        status, reason = r["status"], r["reason"]
        if r.get("process_gone"):
            status, reason = "interrupted", "process gone; `bench resume` finishes it"
        print(f"{r['run_id']:<24} {r['kind']:<6} {status:<12} {pts:>11}  {r['created_utc']}"
              + (f"  ({reason})" if reason else ""))
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    with open_store(args.store, create=False, readonly=True) as store:
        s = store.summary(args.run)
        held = (store.run(args.run).get("meta") or {}).get("device_faults") or {}
    s["device_faults"] = {"points": len(held.get("points") or {}), "total": held.get("total") or {}}
    if args.json:
        emit_json(s)
        return 0
    print(f"run {s['run_id']} ({s['kind']}): {s['status']}" + (f" - {s['reason']}" if s["reason"] else ""))
    print(f"  points {s['points_done']}/{s['points_planned']}, readings {s['readings']}, "
          f"wavelengths {s['wavelengths']['n']} ({s['wavelengths']['min']}..{s['wavelengths']['max']} nm)")
    for k, (lo, hi) in s["geometry"].items():
        print(f"  {k:8s} {lo} .. {hi} deg")
    v = s["value"]
    print(f"  value {v['min']} .. {v['max']} ({v['n']} values, {v['n_missing']} masked), saturated {s['saturated']}")
    steps = s.get("calibration_steps")
    if steps:
        print(f"  calibration: dark {steps['dark']}, white {steps['white']} ({steps['white_source']}), "
              f"integration {steps['integration_s']} s, averages {steps['averages']}")
    t = s["timing"]
    print(f"  created {t['created_utc']}, finished {t['finished_utc']}, elapsed {t['elapsed_s']} s, "
          f"mean per point {t['mean_point_s']} s")
    if s["device_faults"]["points"]:
        print(f"  device faults: {fault_summary(s['device_faults'])}")
    return 0


def fault_summary(faults: dict) -> str:
    """One line from a run's ``device_faults`` summary: recovered transactions and retries per
    device, and the fault kinds seen."""
    total, parts = faults["total"], []
    for dev in sorted({k.split(".", 1)[0] for k in total}):
        kinds = ", ".join(f"{k.split('.fault.', 1)[1]} {n}" for k, n in sorted(total.items())
                          if k.startswith(f"{dev}.fault."))
        parts.append(f"{dev} {total.get(f'{dev}.recovered', 0)} recovered after {total.get(f'{dev}.retries', 0)} "
                     f"retries" + (f" ({kinds})" if kinds else ""))
    return f"{'; '.join(parts)} -- on {faults['points']} point(s)"


def cmd_export(args: argparse.Namespace) -> int:
    from bench.io import default_suffix, export_record, record_to_zemax_files

    if args.wavelength is not None and args.format != "zemax":
        raise InputError(f"--wavelength selects the wavelength of a Zemax file; --format {args.format} "
                         f"holds every wavelength")
    out = check_output(f"{args.run}{default_suffix(args.format)}" if args.out is None else args.out)  # before reading
    with open_store(args.store, create=False, readonly=True) as store:
        record = store.to_record(args.run)
    if args.format == "zemax":  # one wavelength per file: --wavelength, or one file per wavelength
        paths = record_to_zemax_files(record, out, wavelength_nm=args.wavelength)
    else:
        paths = [export_record(record, out, args.format)]
    for path in paths:
        print(path)
    return 0


def _export_formats() -> tuple[str, ...]:
    """What ``bench export --format`` offers: every registered format that writes records."""
    from bench.io.registry import formats

    return formats(writable=True)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``plan``, ``scan``, ``resume``, ``runs``, ``show`` and ``export`` to the subcommands."""
    store_help = "the run store, an SQLite file (default %(default)s)"
    pl = sub.add_parser("plan", help=command_help("plan"))
    pl.add_argument("plan", metavar="PLAN.toml", help="the plan file (see fixtures/plans/)")
    add_bench_options(pl, "the bench config (required)")
    pl.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    pl.set_defaults(func=cmd_plan)

    sc = sub.add_parser("scan", help=command_help("scan"))
    sc.add_argument("plan", metavar="PLAN.toml", help="the plan file (see fixtures/plans/)")
    add_bench_options(sc, "the bench config (required)")
    sc.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    sc.add_argument("--seed", type=seed, help="root seed of virtual devices, integer 0..2^63-1 (default: the "
                    "bench's, else a fresh one)")
    sc.add_argument("--quiet", "-q", action="store_true", help="no progress bar (shown only on a terminal)")
    sc.add_argument("--json", action="store_true", help="the run result as one JSON object")
    sc.set_defaults(func=cmd_scan)

    rs = sub.add_parser("resume", help=command_help("resume"))
    rs.add_argument("run", type=run_id, metavar="RUN", help="the run id (see `bench runs`)")
    rs.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    add_bench_options(rs, "bench config (default: the one stored with the run)", required=False)
    rs.add_argument("--quiet", "-q", action="store_true", help="no progress bar (shown only on a terminal)")
    rs.add_argument("--json", action="store_true", help="the run result as one JSON object")
    rs.set_defaults(func=cmd_resume)

    ru = sub.add_parser("runs", help=command_help("runs"))
    ru.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    ru.add_argument("--json", action="store_true", help="a JSON list of runs")
    ru.set_defaults(func=cmd_runs)

    sh = sub.add_parser("show", help=command_help("show"))
    sh.add_argument("run", type=run_id, metavar="RUN", help="the run id (see `bench runs`)")
    sh.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    sh.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    sh.set_defaults(func=cmd_show)

    ex = sub.add_parser("export", help=command_help("export"))
    ex.add_argument("run", type=run_id, metavar="RUN", help="the run id (see `bench runs`)")
    ex.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    ex.add_argument("--format", choices=RegistryChoices(_export_formats), default="csv",
                    metavar="FORMAT", help="file format: %(choices)s (default %(default)s)")
    ex.add_argument("--out", metavar="FILE", help="output file (default: RUN plus the format's suffix)")
    ex.add_argument("--wavelength", type=real(0.0, 1e6, lo_open=True), metavar="NM",
                    help="zemax: the wavelength to write, nm (default: one file per wavelength, FILE-<w>nm.bsdf)")
    ex.set_defaults(func=cmd_export)
