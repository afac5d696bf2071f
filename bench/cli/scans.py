"""Scans on a bench and the runs they leave: ``bench plan``, ``scan``, ``resume``, ``runs``,
``show`` and ``export``.

Plans and bench configs load through :mod:`bench.plans` and :mod:`bench.config`; runs are read
from the store (:mod:`bench.store`); exports are written through :mod:`bench.io`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bench.cli.argtypes import RegistryChoices, iso_date, real, run_id, seed
from bench.cli.commands import command_help
from bench.cli.design import add_sequential_options, add_design_options, refuse_unused
from bench.cli.common import (DEFAULT_STORE, add_bench_options, add_force_option, announce_compilation, check_output,
                               emit_json, hms, open_store, report_run, warn_if_radians)
from bench.core.errors import InputError

__all__ = ["register", "cmd_plan", "cmd_scan", "cmd_resume", "cmd_runs", "cmd_show", "cmd_export"]


def _plan_and_bench(args: argparse.Namespace, planning: bool = False):
    """The plan and the bench that runs it, refused first from the description alone (nothing
    opened); ``planning``: the bench as the description alone gives it (:mod:`bench.builders.described`)."""
    from bench.builders.described import planning_bench
    from bench.builders.drift import on_day
    from bench.config import load_bench, load_description
    from bench.exposure import resolve_integration
    from bench.plan_check import refuse_before_opening
    from bench.plans import load_plan

    plan = load_plan(args.plan)
    thetas = [a for g in plan.points for a in (g.theta_i, g.theta_r)]
    warn_if_radians(f"plan {args.plan} theta_i/theta_r", sorted(set(thetas)))
    seed = getattr(args, "seed", None)
    if planning:
        bench = planning_bench(args.bench, seed=seed, body=args.body)
        return resolve_integration(plan, bench.config), bench  # integration_s = "auto": chosen here
    d, body = load_description(args.bench, args.body)
    d = on_day(d, getattr(args, "date", None))  # a declared [drift] simulated on --date
    plan = resolve_integration(plan, d)
    refuse_before_opening(plan, d, body)
    return plan, load_bench(d, seed=seed, body=body)


def cmd_plan(args: argparse.Namespace) -> int:
    """Check and time a plan on a bench: JSON keys ``points`` (all of the plan's), ``refused``
    (each with theta_i, phi_i, theta_r, phi_r, rule, message), ``seconds`` and ``motion_s`` (of the
    reachable points), ``calibration_refused`` (a calibration step the bench cannot take, or null).
    A plan ``bench scan`` would refuse exits 2 (its JSON still printed). With ``--design MODEL``
    it writes a designed plan instead (:func:`bench.cli.design.cmd_plan_design`)."""
    if args.design is not None:
        from bench.cli.design import cmd_plan_design

        return cmd_plan_design(args)
    if args.plan is None:
        raise InputError("give a plan file to check, or --design MODEL to write one")
    refuse_unused(args, "--design")
    from bench.core.errors import CalibrationRefused, PlanError
    from bench.plans import MotionProfile, default_joints, estimate, order_for_travel, refusal_message, refusals
    from bench.calibration_chain import decide_calibration
    from bench.exposure import predict_exposure

    plan, bench = _plan_and_bench(args, planning=True)  # nothing opened: the description alone
    exposure = predict_exposure(plan, bench.config)  # the counts each reading will hold, vs full scale
    noise = {} if exposure is None else {"relative_noise_per_reading": exposure.relative_noise}
    with bench:
        refused = refusals(plan, bench.goniometer.check)
        calibration = None  # what `bench scan` would refuse about the calibration steps, if anything
        try:
            decide_calibration(bench, plan)  # the runner's own decision: which white, which darks
        except CalibrationRefused as exc:
            calibration = str(exc)
        skipped = {r.index for r in refused}
        profile = bench.motion or MotionProfile.instantaneous()
        joints = bench.joints if bench.joints is not None else default_joints
        given_order = [i for i in range(len(plan.points)) if i not in skipped]
        order = [i for i in order_for_travel(plan.points) if i not in skipped] if plan.order == "travel" else given_order
        est = estimate(plan, profile, order, joints, **noise)
        given = estimate(plan, profile, given_order, joints, **noise)
    out = {"plan": plan.name, "kind": plan.kind, "bench": bench.name, "bench_kind": bench.kind, **est,
           "points": len(plan.points), "reachable": len(order), "unreachable": plan.unreachable,
           "refused": [r.as_dict() for r in refused], "calibration_refused": calibration,
           "seconds_in_given_order": given["seconds"], "integration_s": plan.integration_s,
           "averages": plan.averages, "exposure": None if exposure is None else exposure.as_dict()}
    refuse = bool(refused) and plan.unreachable != "skip"
    saturates = exposure is not None and exposure.saturates
    if args.json:
        emit_json(out)
        return 2 if refuse or calibration or saturates else 0
    if refuse:
        raise PlanError(refusal_message(plan, refused))
    if calibration:
        raise CalibrationRefused(calibration)
    if exposure is not None and exposure.saturates:  # `saturates`, spelled so the checker sees exposure is set
        raise PlanError(exposure.refusal(plan.name, bench.name))
    head = (f"all {est['points']} points reachable" if not refused else
            f"{len(order)} of {len(plan.points)} points reachable, {len(refused)} skipped "
            f"({', '.join(sorted({r.rule for r in refused}))})")
    print(f"plan {plan.name} ({plan.kind}) on bench {bench.name} ({bench.kind}): {head}, {est['incidences']} incidences")
    print(f"  estimated duration {hms(est['seconds'])}: motion {hms(est['motion_s'])}, acquisition "
          f"{hms(est['acquisition_s'])}, references {hms(est['references_s'])}"
          f"  (in the order given: {hms(given['seconds'])})")
    print(f"  expected relative uncertainty per point {est['relative_uncertainty']:.2%} "
          f"({plan.averages} averages x {plan.integration_s:g} s)")
    if exposure is not None:
        e = exposure.as_dict()
        print(f"  exposure: brightest reading {e['brightest']} at {e['fraction_of_full_scale']:.0%} of full scale "
              f"({e['brightest_counts']:.0f} of {e['full_scale']:.0f} counts per scan)")
    return 0


def cmd_scan(args: argparse.Namespace) -> int:
    if args.sequential is not None:
        from bench.cli.design import cmd_scan_sequential

        return cmd_scan_sequential(args)
    if args.plan is None:
        raise InputError("give a plan file to scan, or --sequential MODEL")
    refuse_unused(args, "--sequential")
    from bench.runner import run_scan

    from bench.cli.assurance import scan_gate

    plan, bench = _plan_and_bench(args)
    assurance = scan_gate(bench.config, args.store, bench.kind, args.date)  # the checks it relies on, or refused
    if args.uncertainty_method:  # the run stores its description, so a resume evaluates budgets alike
        bench.config["uncertainty"] = {**dict(bench.config.get("uncertainty") or {}), "method": args.uncertainty_method}
    if bench.kind == "virtual":
        announce_compilation()
    with bench, open_store(args.store) as store:
        result = run_scan(bench, plan, store, seed=getattr(bench.goniometer, "seed", args.seed),
                          progress=not args.quiet and sys.stderr.isatty(),
                          extra_meta=None if assurance is None else {"assurance": assurance})
    return report_run(result, args.json)


def cmd_resume(args: argparse.Namespace) -> int:
    from bench.calibration_chain import check_resume_body
    from bench.config import load_bench, load_description
    from bench.plan_check import refuse_before_opening
    from bench.plans import plan_from_dict
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
        d, body = load_description(config, body)
        plan = plan_from_dict(info["plan"], name=info["plan"].get("name", "plan"))
        if info["status"] != "completed":  # (a completed run is refused by resume_scan, naming it)
            check_resume_body(args.run, info, body)  # its white on another body: refused before opening
            refuse_before_opening(plan, d, body, calibrated=bool(info.get("calibration")), resuming=True)
        bench = load_bench(d, seed=info.get("seed"), body=body)
        with bench:
            result = resume_scan(bench, store, args.run, progress=not args.quiet and sys.stderr.isatty())
    return report_run(result, args.json)


def run_identity(info: dict[str, Any]) -> dict[str, str | None]:
    """What a run is of and where it ran: ``specimen`` (a sweep's specimens joined by ``; ``),
    ``bench``, ``body`` and ``plan`` (None when the run does not say)."""
    from bench.core.records import record_identity, record_provenance

    meta = {**(info.get("meta") or {}), "bench": info.get("bench"), "plan": info.get("plan")}
    specimen = record_identity(meta)["specimen"]
    sweep = (info.get("plan") or {}).get("sweep") or {}
    if specimen is None and sweep.get("specimens"):
        specimen = "; ".join(str(x) for x in sweep["specimens"])
    prov = record_provenance(meta)
    plan = prov.get("plan") or sweep.get("name") or (info.get("plan") or {}).get("bluesky_plan")
    return {"specimen": specimen, "bench": prov.get("bench"), "body": prov.get("body"), "plan": plan}


def rounded(x: float | None, u: float | None) -> str:
    """``x`` with the decimals its standard uncertainty ``u`` supports (two significant digits of
    ``u``); six significant digits when ``u`` is unknown."""
    import math

    if x is None:
        return "n/a"
    if not u or not math.isfinite(u) or u <= 0:
        return f"{x:.6g}"
    decimals = max(0, 1 - math.floor(math.log10(u)))
    return f"{x:.{decimals}f}"


def _duration(info: dict[str, Any]) -> str:
    end, start = info.get("finished_epoch"), info.get("started_epoch")
    return "-" if end is None or start is None else f"{end - start:.3g} s"


def cmd_runs(args: argparse.Namespace) -> int:
    with open_store(args.store, create=False, readonly=True) as store:
        runs = store.runs()  # a damaged run is listed with its reason, the others as usual
        infos = {r["run_id"]: {} if r["damaged"] else store.run(r["run_id"]) for r in runs}
    for r in runs:
        r.update(run_identity(infos[r["run_id"]]), duration_s=None)
        i = infos[r["run_id"]]
        if i.get("finished_epoch") is not None and i.get("started_epoch") is not None:
            r["duration_s"] = i["finished_epoch"] - i["started_epoch"]
    damaged = [r for r in runs if r["damaged"]]
    if args.json:
        emit_json(runs)
        return _damaged_runs(damaged)
    print(f"{'run':<20} {'kind':<7} {'status':<11} {'points':>9} {'duration':>9}  {'specimen':<28} "
          f"{'bench (body)':<22} {'plan':<16} created (UTC)")
    for r in runs:
        pts = f"{r['points_done']}/{r['n_planned'] if r['n_planned'] is not None else '?'}"
        status, reason = r["status"], r["reason"]
        if r.get("process_gone"):
            status, reason = "interrupted", "process gone; `bench resume` finishes it"
        if r["damaged"]:
            status, reason = "damaged", r["damaged"]
        where = f"{r['bench'] or '?'} ({r['body'] or '?'})"
        print(f"{r['run_id']!s:<20} {r['kind']!s:<7} {status:<11} {pts:>9} {_duration(infos[r['run_id']]):>9}  "
              f"{r['specimen'] or 'n/a':<28} {where:<22} {r['plan'] or 'n/a':<16} {r['created_utc']}"
              + (f"  ({reason})" if reason else ""))
    return _damaged_runs(damaged)


def _damaged_runs(damaged: list[dict[str, Any]]) -> int:
    """After the whole list: one line naming the damaged runs, exit 2 (0 when none is)."""
    if not damaged:
        return 0
    first = damaged[0]
    more = f" and {len(damaged) - 1} more" if len(damaged) > 1 else ""
    print(f"bench runs: error: {len(damaged)} damaged run(s) listed: {first['run_id']} ({first['damaged']}){more}",
          file=sys.stderr)
    return 2


def cmd_show(args: argparse.Namespace) -> int:
    from bench.core.records import value_unit

    with open_store(args.store, create=False, readonly=True) as store:
        store.check_run(args.run)  # a damaged field is named (run, point, field), not shown as a number
        s = store.summary(args.run)
        points = store.reading_budgets(args.run)  # each reading's GUM budget (bench.core.budget)
        info = store.run(args.run)
    if args.json:
        s["points"] = points
    if s["kind"] == "fit":  # a fit has no points: its result and the record it was fitted to
        meta = info.get("meta") or {}
        s["fit"] = {k: meta.get(k) for k in ("fit", "specimen", "record", "record_run_id")}
    s["identity"] = run_identity(info)
    s["value"]["unit"] = value_unit(info.get("meta") or {})
    held = (info.get("meta") or {}).get("device_faults") or {}
    s["device_faults"] = {"points": len(held.get("points") or {}), "total": held.get("total") or {}}
    s["assurance"] = (info.get("meta") or {}).get("assurance")  # the check standards this run relied on
    s["check"] = (info.get("meta") or {}).get("check") if s["kind"] == "check" else None
    if args.json:
        emit_json(s)
        return 0
    ident = s["identity"]
    print(f"run {s['run_id']} ({s['kind']}): {s['status']}" + (f" - {s['reason']}" if s["reason"] else ""))
    if "fit" in s:
        fit = s["fit"]["fit"] or {}
        print(f"  record {s['fit']['record']}  model {fit.get('model')}  ({fit.get('method')})")
        for name, p in (fit.get("parameters") or {}).items():
            print(f"  {name:10s} {p['value']:.6g}  [{p['ci'][0]:.6g}, {p['ci'][1]:.6g}] {p['unit']}".rstrip())
        print(f"  chi2 {fit.get('chi2')}, dof {fit.get('dof')}, p {fit.get('p_value')}, converged {fit.get('converged')}")
        return 0
    print(f"  specimen {ident['specimen'] or 'n/a'}; bench {ident['bench'] or 'n/a'} ({ident['body'] or 'n/a'} body); "
          f"plan {ident['plan'] or 'n/a'}")
    wl = s["wavelengths"]
    wl_range = f"{wl['min']:g}..{wl['max']:g} nm" if wl["n"] else "none"
    planned = "?" if s["points_planned"] is None else s["points_planned"]
    print(f"  points {s['points_done']}/{planned}, readings {s['readings']}, "
          f"wavelengths {wl['n']} ({wl_range})")
    for k, (lo, hi) in s["geometry"].items():
        if lo is not None:
            print(f"  {k:8s} {round(lo, 3):g} .. {round(hi, 3):g} deg")
    v = s["value"]
    u = v.get("std_min")
    print(f"  value {rounded(v['min'], u)} .. {rounded(v['max'], u)} {v['unit']} ({v['n']} values, "
          f"{v['n_missing']} masked; smallest standard uncertainty {'n/a' if u is None else f'{u:.2g}'} "
          f"{v['unit']}), saturated {s['saturated']}")
    for name, c in ((s["assurance"] or {}).get("checks") or {}).items():
        print(f"  check standard {name}: {c['state']}" + (f" (run {c['run']} of {c['date']})" if c.get("run") else ""))
    if s["check"] and "value" in s["check"]:
        c = s["check"]
        print(f"  check {c['check']} on {c['date']}: value {c['value']:.5f} x reference, max |E_n| {c['max_abs_E_n']:.2f}")
    steps = s.get("calibration_steps")
    if steps:
        print(f"  calibration: dark {steps['dark']}, white {steps['white']} ({steps['white_source']}), "
              f"integration {steps['integration_s']:g} s, averages {steps['averages']}")
        drift = steps.get("lamp_drift")
        if drift:  # white = "repeated": the Type A estimate every reading is corrected for
            print(f"  lamp drift: {drift['per_lit_reading']:.3g} +- {drift['standard_uncertainty']:.2g} per lit "
                  f"reading (Type A, {drift['repeats']} white readings, {drift['dof']} dof); readings corrected")
    budgets = [p["uncertainty_budget"] for p in points if p["uncertainty_budget"]]
    rel = sorted(100.0 * b["combined"] / abs(b["value"]) for b in budgets if b.get("value"))
    if rel:
        methods = ", ".join(sorted({str(b.get("method", "linear")) for b in budgets}))
        print(f"  uncertainty: GUM budgets on {len(budgets)} of {len(points)} readings ({methods}, k = "
              f"{budgets[0]['k']:g}), median u_c {rel[len(rel) // 2]:.3g} % of the value")
    t = s["timing"]
    elapsed = "n/a" if t["elapsed_s"] is None else f"{t['elapsed_s']:.3g} s"
    mean = "n/a" if t["mean_point_s"] is None else f"{t['mean_point_s']:.3g} s"
    print(f"  created {t['created_utc']}, finished {t['finished_utc']}, duration {elapsed}, mean per point {mean}")
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


def export_format(fmt: str | None, out: str | None) -> str:
    """The format of an export: ``--format``, else the suffix of ``--out``, else ``csv``; a
    suffix that names another format than ``--format``, and one that names no format without
    ``--format`` (``--out run.xlsx``), are refused (one line, exit 2)."""
    from pathlib import Path

    from bench.io.registry import suffix_format, suffixes

    by_suffix = suffix_format(out) if out else None
    if fmt is not None and by_suffix is not None and by_suffix != fmt:
        raise InputError(f"--out {out} names format {by_suffix} but --format is {fmt}: drop one of them")
    if out and fmt is None and by_suffix is None:
        known = ", ".join(suffixes(writable=True))
        raise InputError(f"--out {out}: no export format has the suffix {Path(out).suffix or '(none)'!r}; "
                         f"use one of {known}, or name the format with --format")
    return fmt or by_suffix or "csv"


def _run_or_file(text: str) -> str:
    """A record file that exists, else a run id (see `bench runs`)."""
    from pathlib import Path

    return text if Path(text).is_file() else run_id(text)


def _records_to_export(args: argparse.Namespace) -> list[tuple[str | None, Any]]:
    """``(specimen or None, record)`` to write: a record file as read, a stored run as
    :func:`bench.io.run_records` gives it (a sweep one record per specimen)."""
    from pathlib import Path

    from bench.core.records import BSDFRecord
    from bench.io import read_record, run_records

    if Path(args.run).is_file():
        record = read_record(args.run)
        if not isinstance(record, BSDFRecord):
            raise InputError(f"{args.run}: a spectrum table; bench export converts BSDF records (csv, parquet, "
                             f"astm, zemax)")
        return [(None, record)]
    with open_store(args.store, create=False, readonly=True) as store:
        return run_records(store, args.run)


def _side(record: Any, hemisphere: str, fmt: str) -> Any:
    """The rows a BSDF file format holds: reflection unless ``--hemisphere`` asks otherwise."""
    if fmt not in ("astm", "zemax") or hemisphere == "both":
        return record
    side = record.reflection() if hemisphere == "R" else record.transmission()
    if not len(side):
        other = "T" if hemisphere == "R" else "R"
        raise InputError(f"the record has no {'reflection' if hemisphere == 'R' else 'transmission'} rows; "
                         f"--hemisphere {other} exports its {'transmission' if other == 'T' else 'reflection'}")
    return side


def _slug(text: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9.=]+", "_", text).strip("_")[:80] or "specimen"


def cmd_export(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bench.io import default_suffix, export_record, record_to_zemax_files
    from bench.io.files import require_bsdf

    if args.out is not None:  # the path itself first (empty, a folder, a device), then its suffix
        check_output(args.out, force=args.force)
    fmt = export_format(args.format, args.out)
    if args.wavelength is not None and fmt != "zemax":
        raise InputError(f"--wavelength selects the wavelength of a Zemax file; --format {fmt} holds every wavelength")
    if args.fill is not None and fmt != "zemax":
        raise InputError(f"--fill fills a Zemax grid; --format {fmt} holds the measured rows only")
    if args.hemisphere == "both" and fmt == "zemax":
        raise InputError("a Zemax file holds one side: --hemisphere R (BRDF) or T (BTDF)")
    default_name = Path(args.run).name.split(".")[0] if Path(args.run).is_file() else args.run
    out = check_output(f"{default_name}{default_suffix(fmt)}" if args.out is None else args.out,
                       force=args.force)  # before reading: a device, a missing folder, a file without --force
    if fmt == "csv":
        check_output(f"{out}.json", force=args.force)  # the sidecar
    records = _records_to_export(args)
    targets = []
    for specimen, record in records:
        target = out
        if specimen is not None:  # one file per specimen: <stem>-<specimen><suffix>
            suffix = default_suffix(fmt) if out.name.endswith(default_suffix(fmt)) else out.suffix
            stem = out.name[:len(out.name) - len(suffix)] if suffix else out.name
            target = check_output(out.with_name(f"{stem}-{_slug(specimen)}{suffix}"), force=args.force)
            if fmt == "csv":
                check_output(f"{target}.json", force=args.force)
        record = _side(record, args.hemisphere, fmt)
        if fmt in ("astm", "zemax"):  # a reflectance is never written as a BRDF: refused before any file
            require_bsdf(record, "the ASTM layout" if fmt == "astm" else "a Zemax tabular BSDF")
        targets.append((target, record))
    paths = []
    for target, record in targets:
        if fmt == "zemax":  # one wavelength per file: --wavelength, or one file per wavelength
            paths += record_to_zemax_files(record, target, wavelength_nm=args.wavelength, fill=args.fill,
                                           scatter_type="BTDF" if args.hemisphere == "T" else "BRDF")
        elif fmt == "astm":
            paths.append(export_record(record, target, fmt, scatter_type="BTDF" if args.hemisphere == "T" else "BRDF"))
        else:
            paths.append(export_record(record, target, fmt))
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
    pl.add_argument("plan", metavar="PLAN.toml", nargs="?", help="the plan file (see fixtures/plans/)")
    add_bench_options(pl, "the bench config (required)")
    pl.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    add_design_options(pl)
    pl.set_defaults(func=cmd_plan)

    sc = sub.add_parser("scan", help=command_help("scan"))
    sc.add_argument("plan", metavar="PLAN.toml", nargs="?", help="the plan file (see fixtures/plans/)")
    add_bench_options(sc, "the bench config (required)")
    sc.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    sc.add_argument("--seed", type=seed, help="root seed of virtual devices, integer 0..2^63-1 (default: the "
                    "bench's, else a fresh one)")
    sc.add_argument("--quiet", "-q", action="store_true", help="no progress bar (shown only on a terminal)")
    sc.add_argument("--json", action="store_true", help="the run result as one JSON object")
    sc.add_argument("--date", type=iso_date, default=None, metavar="YYYY-MM-DD",
                    help="the simulated day of this scan: its check standards are judged on it and a declared "
                         "[drift] acts on it (virtual and emulated bodies only; default: today)")
    sc.add_argument("--uncertainty-method", choices=("linear", "mc"),
                    help="each reading's GUM budget: law of propagation (linear) or Supplement 1 Monte Carlo "
                         "(mc); default: the bench's [uncertainty] method, else linear")
    add_sequential_options(sc)
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
    ex.add_argument("run", type=_run_or_file, metavar="RUN|FILE",
                    help="the run id (see `bench runs`) or a record file to convert")
    ex.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help=store_help)
    ex.add_argument("--format", choices=RegistryChoices(_export_formats), default=None,
                    metavar="FORMAT", help="file format: %(choices)s (default: from --out's suffix, else csv; "
                    "tidy csv writes its metadata and units to FILE.json)")
    ex.add_argument("--out", metavar="FILE", help="output file (default: RUN plus the format's suffix); a sweep "
                    "of several specimens writes one file per specimen, FILE-<specimen>")
    ex.add_argument("--hemisphere", choices=("R", "T", "both"), default="R",
                    help="astm/zemax: the side a BSDF file holds, R = BRDF (default), T = BTDF, both (astm)")
    ex.add_argument("--fill", choices=("nearest",), default=None,
                    help="zemax: fill grid nodes an in-plane scan did not measure from the nearest sample "
                    "(default: refused; when asked, recorded in the file's header)")
    ex.add_argument("--wavelength", type=real(0.0, 1e6, lo_open=True), metavar="NM",
                    help="zemax: the wavelength to write, nm (default: one file per wavelength, FILE-<w>nm.bsdf)")
    add_force_option(ex)  # the files are named once the records are known: checked in cmd_export
    ex.set_defaults(func=cmd_export)
