"""The ``bench`` command line.

Starts fast: heavy modules (numba kernels, colour-science, matplotlib, pandas) are imported
inside the commands that use them. Exit status: 0 ok, 2 bad input, 1 a failed run. Every
command that reports numbers has ``--json`` with stable keys.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from bench.core.errors import BenchError, InputError

log = logging.getLogger("bench")


def _emit_json(obj: Any) -> None:
    from bench.core.records import json_default

    print(json.dumps(obj, indent=None, sort_keys=False, default=json_default))


# --- bench rays -----------------------------------------------------------------------------


def cmd_rays(args: argparse.Namespace) -> int:
    from virtual.bounds import budget_report

    report = budget_report(args.uncertainty, args.delta, args.patches, rays_per_second=args.rate)
    if args.json:
        _emit_json({**report, "bound": "eq. 3.12" if args.patches > 1 else "eq. 3.5"})
    else:
        print(report["N"])
        if args.verbose:
            print(f"about {report['seconds']:.3g} s at {args.rate:.3g} rays/s", file=sys.stderr)
    return 0


# --- bench spectro --------------------------------------------------------------------------


def _spectrum_json(s: Any) -> dict[str, Any]:
    return {
        "N": int(s.N[0]), "seed": s.seed, "geometry": s.geometry, "delta": s.delta,
        "wavelength_nm": s.wavelengths.tolist(), "reflectance": s.reflectance.tolist(),
        "transmittance": s.transmittance.tolist(), "reflectance_ci": s.reflectance_ci.tolist(),
        "transmittance_ci": s.transmittance_ci.tolist(), "absorptance": s.absorptance.tolist(),
        "quantity": s.meta.get("quantity"), "measured_as": s.meta.get("measured_as"),
        "specimen": s.meta.get("specimen"), "beam": s.meta.get("beam"),
    }


def _spectro_instrument(args: argparse.Namespace):
    from virtual.spectrophotometer import VirtualSpectrophotometer

    kw: dict[str, Any] = {"beam": args.beam, "seed": args.seed, "delta": args.delta}
    if args.rays is not None:
        kw["rays"] = args.rays
    else:
        kw["uncertainty"] = args.uncertainty
    return VirtualSpectrophotometer(args.specimen, **kw)


def cmd_spectro(args: argparse.Namespace) -> int:
    from bench.core.geometry import cie_geometry

    cie_geometry(args.geometry)  # bad geometry: exit 2 before any work
    sp = _spectro_instrument(args)
    adaptive = None
    if args.rays is None and not args.no_adaptive:  # --uncertainty/--delta: the adaptive rule
        from bench.cli_tradeoff import adaptive_measure

        adaptive = adaptive_measure(sp, args.uncertainty, args.delta, geometry=args.geometry,
                                    wavelengths=args.wavelengths, max_seconds=args.max_seconds)
        s = adaptive["result"]
    else:
        s = sp.measure(args.geometry, args.wavelengths)
    if args.csv:
        from bench.export import spectrum_to_csv

        spectrum_to_csv(s, args.csv)
    if args.plot:
        from bench.plotting import plot_spectrum

        plot_spectrum(s, args.plot)
    if args.json:
        out = _spectrum_json(s)
        if adaptive:
            out["budget"] = _budget(adaptive)
        _emit_json(out)
        return 0
    print(f"specimen {s.meta['specimen']}  geometry {s.geometry}  beam {sp.beam.kind}  "
          f"N = {int(s.N[0])} rays/wavelength  seed {s.seed}  confidence {1 - s.delta:g}")
    if adaptive:
        print(adaptive["message"])
    q = "RF" if s.meta.get("quantity") == "reflectance factor" else "R"
    print(f"{'nm':>7} {q:>8} {'[lo, hi]':>20} {'T':>8} {'[lo, hi]':>20}")
    for i, w in enumerate(s.wavelengths):
        print(f"{w:7.1f} {s.reflectance[i]:8.5f} [{s.reflectance_ci[i, 0]:.5f}, {s.reflectance_ci[i, 1]:.5f}] "
              f"{s.transmittance[i]:8.5f} [{s.transmittance_ci[i, 0]:.5f}, {s.transmittance_ci[i, 1]:.5f}]")
    return 0


# --- bench gonio ----------------------------------------------------------------------------


def _incidence(text: str) -> tuple[float, float]:
    try:
        parts = [float(p) for p in str(text).split(",")]
    except ValueError:
        raise InputError(f"--incidence {text!r}: expected THETA or THETA,PHI in degrees") from None
    if len(parts) not in (1, 2):
        raise InputError(f"--incidence {text!r}: expected THETA or THETA,PHI in degrees")
    return parts[0], (parts[1] if len(parts) == 2 else 0.0)


def gonio_json(record: Any) -> dict[str, Any]:
    """The stable JSON of a goniophotometric record (scalars for the first wavelength)."""
    t, m = record.table, record.meta
    first = float(t.wavelength_nm.iloc[0])
    sub = t[t.wavelength_nm == first]
    patches = [{"hemisphere": r.hemisphere, "theta_min": r.theta_min, "theta_max": r.theta_max,
                "phi_min": r.phi_min, "phi_max": r.phi_max, "theta": r.theta_r, "phi": r.phi_r,
                "psa": r.psa, "count": int(r.count), "value": r.value, "ci": [r.ci_lo, r.ci_hi]}
               for r in sub.itertuples(index=False)]
    tot = m["totals"][0]
    return {"N": int(m["rays"]), "seed": m["seed"], "collector": m["collector"], "beam": m["beam"],
            "method": m["method"], "kernel": m.get("kernel"), "specimen": m["specimen"], "incidence": [float(t.theta_i.iloc[0]),
                                                                           float(t.phi_i.iloc[0])],
            "wavelength_nm": first, "delta": m["delta"], "reflectance": tot["reflectance"],
            "transmittance": tot["transmittance"], "absorbed": tot["absorbed"], "missed": tot["missed"],
            "by_wavelength": m["totals"], "patches": patches}


def cmd_gonio(args: argparse.Namespace) -> int:
    from virtual.goniophotometer import VirtualGoniophotometer

    theta_i, phi_i = _incidence(args.incidence)
    kw: dict[str, Any] = {"collector": args.collector, "beam": args.beam, "seed": args.seed, "delta": args.delta,
                          "wavelengths": args.wavelengths, "method": args.method}
    if args.rays is not None:
        kw["rays"] = args.rays
    elif args.uncertainty is not None:
        kw["uncertainty"] = args.uncertainty
    g = VirtualGoniophotometer(args.specimen, **kw)
    adaptive = None
    if args.uncertainty is not None and args.rays is None and not args.no_adaptive:
        from bench.cli_tradeoff import adaptive_measure

        adaptive = adaptive_measure(g, args.uncertainty, args.delta, theta_i=theta_i, phi_i=phi_i,
                                    max_seconds=args.max_seconds)
        record = adaptive["result"]
    else:
        record = g.measure_bsdf(theta_i, phi_i)
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        record.table.to_csv(args.csv, index=False, float_format="%.8g")
    if args.plot:
        from bench.plotting import plot_bsdf_polar

        plot_bsdf_polar(record, args.plot)
    if args.json:
        out = gonio_json(record)
        if adaptive:
            out["budget"] = _budget(adaptive)
        _emit_json(out)
        return 0
    m = record.meta
    print(f"specimen {m['specimen']}  incidence ({theta_i:g}, {phi_i:g}) deg  collector {g.collector}  "
          f"beam {g.beam.kind}  N = {m['rays']:,}  method {m['method']} ({m.get('kernel')} kernel)  seed {g.seed}")
    if adaptive:
        print(adaptive["message"])
    for tot in m["totals"]:
        print(f"  {tot['wavelength_nm']:7.1f} nm  reflectance {tot['reflectance']:.5f}  "
              f"transmittance {tot['transmittance']:.5f}  absorbed {tot['absorbed']:,}")
    t = record.table
    top = t.sort_values("value", ascending=False).head(5)
    print("  brightest patches (hemisphere, theta, phi, BSDF [1/sr], interval):")
    for r in top.itertuples(index=False):
        print(f"    {r.hemisphere}  {r.theta_r:6.2f} {r.phi_r:7.2f}  {r.value:.5g}  [{r.ci_lo:.5g}, {r.ci_hi:.5g}]")
    return 0


# --- scans: plan, scan, resume, runs, show, export -------------------------------------------------

DEFAULT_STORE = "goniobench-runs.sqlite"


def _plan_and_bench(args: argparse.Namespace):
    from bench.config import load_bench
    from bench.plans import load_plan

    plan = load_plan(args.plan)
    bench = load_bench(args.bench, seed=getattr(args, "seed", None))
    return plan, bench


def cmd_plan(args: argparse.Namespace) -> int:
    from bench.plans import MotionProfile, estimate, order_for_travel, validate

    plan, bench = _plan_and_bench(args)
    with bench:
        validate(plan, bench.goniometer.check)
        profile = bench.motion or MotionProfile.instantaneous()
        kw = {"joints": bench.joints} if bench.joints is not None else {}
        order = order_for_travel(plan.points) if plan.order == "travel" else None
        est = estimate(plan, profile, order, **kw)
        given = estimate(plan, profile, None, **kw)
    out = {"plan": plan.name, "kind": plan.kind, "bench": bench.name, "bench_kind": bench.kind, **est,
           "seconds_in_given_order": given["seconds"], "integration_s": plan.integration_s,
           "averages": plan.averages}
    if args.json:
        _emit_json(out)
        return 0
    print(f"plan {plan.name} ({plan.kind}) on bench {bench.name} ({bench.kind}): all {est['points']} points "
          f"reachable, {est['incidences']} incidences")
    print(f"  estimated duration {_hms(est['seconds'])}: motion {_hms(est['motion_s'])}, acquisition "
          f"{_hms(est['acquisition_s'])}, references {_hms(est['references_s'])}"
          f"  (in the order given: {_hms(given['seconds'])})")
    print(f"  expected relative uncertainty per point {est['relative_uncertainty']:.2%} "
          f"({plan.averages} averages x {plan.integration_s:g} s)")
    return 0


def _hms(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600:d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _store(path: str, create: bool = True):
    from bench.store import RunStore

    return RunStore(path, create=create)


def cmd_scan(args: argparse.Namespace) -> int:
    from bench.runner import run_scan

    plan, bench = _plan_and_bench(args)
    with bench, _store(args.store) as store:
        result = run_scan(bench, plan, store, seed=getattr(bench.goniometer, "seed", args.seed),
                          progress=not args.quiet and sys.stderr.isatty())
    return _report_run(result, args.json)


def _report_run(result: Any, as_json: bool) -> int:
    """What scan and resume print: the run id (or the result as JSON)."""
    if as_json:
        _emit_json(result.__dict__)
    else:
        print(result.run_id)
    return 0


def cmd_resume(args: argparse.Namespace) -> int:
    from bench.config import load_bench
    from bench.runner import resume_scan

    with _store(args.store, create=False) as store:
        kind = store.run(args.run)["kind"]
    if kind == "sweep":
        from bench.cli_sweep import resume_run

        return resume_run(args.run, args.store, quiet=args.quiet, json=args.json)
    with _store(args.store, create=False) as store:
        info = store.run(args.run)
        config = args.bench if args.bench else info["bench"]
        bench = load_bench(config, seed=info.get("seed"))
        with bench:
            result = resume_scan(bench, store, args.run, progress=not args.quiet and sys.stderr.isatty())
    return _report_run(result, args.json)


def cmd_runs(args: argparse.Namespace) -> int:
    with _store(args.store, create=False) as store:
        runs = store.runs()
    if args.json:
        _emit_json(runs)
        return 0
    print(f"{'run':<24} {'kind':<6} {'status':<12} {'points':>11}  created (UTC)")
    for r in runs:
        pts = f"{r['points_done']}/{r['n_planned'] if r['n_planned'] is not None else '?'}"
        print(f"{r['run_id']:<24} {r['kind']:<6} {r['status']:<12} {pts:>11}  {r['created_utc']}"
              + (f"  ({r['reason']})" if r["reason"] else ""))
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    with _store(args.store, create=False) as store:
        s = store.summary(args.run)
    if args.json:
        _emit_json(s)
        return 0
    print(f"run {s['run_id']} ({s['kind']}): {s['status']}" + (f" - {s['reason']}" if s["reason"] else ""))
    print(f"  points {s['points_done']}/{s['points_planned']}, readings {s['readings']}, "
          f"wavelengths {s['wavelengths']['n']} ({s['wavelengths']['min']}..{s['wavelengths']['max']} nm)")
    for k, (lo, hi) in s["geometry"].items():
        print(f"  {k:8s} {lo} .. {hi} deg")
    v = s["value"]
    print(f"  value {v['min']} .. {v['max']} ({v['n']} values, {v['n_missing']} masked), saturated {s['saturated']}")
    t = s["timing"]
    print(f"  created {t['created_utc']}, finished {t['finished_utc']}, elapsed {t['elapsed_s']} s, "
          f"mean per point {t['mean_point_s']} s")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from bench import export

    with _store(args.store, create=False) as store:
        record = store.to_record(args.run)
    out = Path(args.out or f"{args.run}.{ {'csv': 'csv', 'parquet': 'parquet', 'astm': 'astm.csv', 'zemax': 'bsdf'}[args.format]}")
    path = export.export_record(record, out, args.format)
    print(path)
    return 0


def _budget(adaptive: dict[str, Any]) -> dict[str, Any]:
    return {k: adaptive[k] for k in ("N", "hoeffding_N", "saved_rays", "saved_fraction", "per_wavelength", "mode")}


# --- bench demo -----------------------------------------------------------------------------


def cmd_demo(args: argparse.Namespace) -> int:
    from bench.demo import run_demo

    summary = run_demo(Path(args.out), seed=args.seed)
    if args.json:
        _emit_json(summary)
    else:
        for line in summary["lines"]:
            print(line)
    return 0


# --- parser ---------------------------------------------------------------------------------


def _positive_int(text: str) -> int:
    try:
        v = int(float(text)) if "e" in text.lower() else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


#: Modules that add subcommands: each has ``register(subparsers)`` and imports nothing heavy at
#: module level (the CLI must start fast). One module per feature keeps this file small.
COMMAND_MODULES = ["bench.cli_compare", "bench.cli_tradeoff", "bench.cli_sweep", "bench.cli_emulate"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bench", description="goniobench: real, emulated and virtual "
                                "goniophotometry and spectrophotometry behind one interface.")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    r = sub.add_parser("rays", help="ray budget of eq. 3.5 (eq. 3.12 with --patches)")
    r.add_argument("--uncertainty", "-u", type=_float, required=True, help="uncertainty v of the real instrument")
    r.add_argument("--delta", "-d", type=_float, required=True, help="confidence delta, in (0, 1)")
    r.add_argument("--patches", type=int, default=1, help="collector patches m (eq. 3.12)")
    r.add_argument("--rate", type=_float, default=5e7, help="rays/s for the time estimate in --json (default 5e7)")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_rays)

    s = sub.add_parser("spectro", help="virtual spectrophotometric measurement")
    s.add_argument("--specimen", required=True, help="e.g. 'lambert:reflectance=0.375', 'colorchecker:dark skin'")
    s.add_argument("--geometry", default="8/d", help="CIE geometry: 45/0, 0/45, d/0, 0/d, 8/d, 8/de")
    s.add_argument("--wavelengths", default="400:700:10", help="START:STOP:STEP or a,b,c (nm)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--rays", type=_positive_int, help="rays per wavelength")
    g.add_argument("--uncertainty", type=_float, default=0.005, help="v for eq. 3.5 (default 0.005)")
    s.add_argument("--delta", type=_float, default=0.01, help="confidence delta (default 0.01)")
    s.add_argument("--beam", choices=("collimated", "conical"), default="collimated")
    s.add_argument("--no-adaptive", action="store_true",
                   help="with --uncertainty: the fixed eq. 3.5 ray count instead of the adaptive rule")
    s.add_argument("--max-seconds", type=_float, default=3600.0,
                   help="refuse budgets estimated to take longer (reports N and the time)")
    s.add_argument("--seed", type=int)
    s.add_argument("--json", action="store_true")
    s.add_argument("--plot", metavar="FILE.png")
    s.add_argument("--csv", metavar="FILE")
    s.set_defaults(func=cmd_spectro)

    g = sub.add_parser("gonio", help="virtual goniophotometric measurement (whole collector sphere)")
    g.add_argument("--specimen", required=True, help="e.g. 'lambert:albedo=0.5', 'ggx:alpha=0.2,eta=1.5,k=0'")
    g.add_argument("--incidence", default="30", help="THETA[,PHI] in degrees (default 30)")
    g.add_argument("--collector", default="equal-psa:9x36", help="SCHEME:NTHxNPHI, e.g. equal-psa:9x36")
    gb = g.add_mutually_exclusive_group()
    gb.add_argument("--rays", type=_positive_int, help="rays per wavelength (default 1e7)")
    gb.add_argument("--uncertainty", type=_float, help="v for eq. 3.12 (patches = collector patches)")
    g.add_argument("--delta", type=_float, default=0.01)
    g.add_argument("--wavelengths", default="550", help="START:STOP:STEP or a,b,c (nm)")
    g.add_argument("--beam", choices=("collimated", "conical"), default="collimated")
    g.add_argument("--method", choices=("auto", "rays", "fast"), default="auto",
                   help="rays: count rays; fast: one multinomial over integrated patch probabilities")
    g.add_argument("--no-adaptive", action="store_true",
                   help="with --uncertainty: the fixed eq. 3.12 ray count instead of the adaptive rule")
    g.add_argument("--max-seconds", type=_float, default=3600.0,
                   help="refuse budgets estimated to take longer (reports N and the time)")
    g.add_argument("--seed", type=int)
    g.add_argument("--json", action="store_true")
    g.add_argument("--csv", metavar="FILE")
    g.add_argument("--plot", metavar="FILE.png")
    g.set_defaults(func=cmd_gonio)

    pl = sub.add_parser("plan", help="check a plan on a bench and estimate its duration")
    pl.add_argument("plan", metavar="PLAN.toml")
    pl.add_argument("--bench", required=True, metavar="BENCH.toml")
    pl.add_argument("--json", action="store_true")
    pl.set_defaults(func=cmd_plan)

    sc = sub.add_parser("scan", help="run a plan on a bench; prints the run id")
    sc.add_argument("plan", metavar="PLAN.toml")
    sc.add_argument("--bench", required=True, metavar="BENCH.toml")
    sc.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite")
    sc.add_argument("--seed", type=int, help="root seed of virtual devices")
    sc.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    sc.add_argument("--json", action="store_true")
    sc.set_defaults(func=cmd_scan)

    rs = sub.add_parser("resume", help="finish an interrupted run")
    rs.add_argument("run", metavar="RUN")
    rs.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite")
    rs.add_argument("--bench", metavar="BENCH.toml", help="bench config (default: the one stored with the run)")
    rs.add_argument("--quiet", "-q", action="store_true")
    rs.add_argument("--json", action="store_true")
    rs.set_defaults(func=cmd_resume)

    ru = sub.add_parser("runs", help="list the runs in a store")
    ru.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite")
    ru.add_argument("--json", action="store_true")
    ru.set_defaults(func=cmd_runs)

    sh = sub.add_parser("show", help="summarize one run")
    sh.add_argument("run", metavar="RUN")
    sh.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite")
    sh.add_argument("--json", action="store_true")
    sh.set_defaults(func=cmd_show)

    ex = sub.add_parser("export", help="export a run: csv, parquet, astm, zemax")
    ex.add_argument("run", metavar="RUN")
    ex.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite")
    ex.add_argument("--format", choices=("csv", "parquet", "astm", "zemax"), default="csv")
    ex.add_argument("--out", metavar="FILE")
    ex.set_defaults(func=cmd_export)

    d = sub.add_parser("demo", help="end-to-end demo on the embedded default bench")
    d.add_argument("--out", default="demo-out", help="output folder (default ./demo-out)")
    d.add_argument("--seed", type=int, default=20261122)
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=cmd_demo)

    import importlib

    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:  # the module exists but something it needs is missing
                raise
            continue
        module.register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except InputError as exc:
        print(f"bench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BenchError as exc:
        print(f"bench {args.command}: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bench {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
