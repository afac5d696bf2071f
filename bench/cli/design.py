"""``bench plan --design`` and ``bench scan --sequential``: plans designed to identify a model
within a bench-time budget, one-shot or sequential.

Not a command module of its own: :mod:`bench.cli.scans` declares these options on ``bench plan``
and ``bench scan`` and calls :func:`cmd_plan_design` / :func:`cmd_scan_sequential` when
``--design`` / ``--sequential`` is given; the design code is imported only then.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from bench.cli.argtypes import real, renamed
from bench.cli.common import add_force_option, check_output, emit_json, output_file
from bench.core.errors import InputError

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading the design modules
    from bench.config import Bench
    from bench.identify.design import ModelPoint
    from bench.identify.model_spec import ModelSpec
    from bench.identify.time_model import ReadingSettings

#: the default prior range factor (bench.identify.design.PRIOR_SPREAD, not imported: the design code
#: is imported only when a design is asked for); tests/test_design_prior.py checks they agree
PRIOR_SPREAD = 4.0

__all__ = ["add_design_options", "add_sequential_options", "refuse_unused", "cmd_plan_design", "cmd_scan_sequential", "open_design"]

#: the default integration times of a design (bench.identify.time_model.DEFAULT_INTEGRATIONS, not
#: imported, as PRIOR_SPREAD); tests/test_design_prior.py checks they agree
DEFAULT_INTEGRATIONS = "0.005,0.01,0.02,0.05"
#: wall-clock limit of ``bench plan --design`` (s): the search then writes its best design so far
DEFAULT_MAX_SECONDS = 120.0


def _times(text: str) -> str:
    try:
        values = [float(t) for t in str(text).split(",") if t.strip()]
    except ValueError:
        values = []
    if not values or not all(0.001 <= v <= 60.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected integration times 0.001..60 s separated by commas, got {text!r}")
    return text


def _add_common(g: argparse._ArgumentGroup, what: str) -> None:
    g.add_argument("--budget-seconds", type=real(0.0, 1e7, lo_open=True), metavar="S",
                   help=f"{what}: the bench-time budget, s (as `bench plan` estimates it; no default: required)")
    renamed(g, "--seconds", "--budget-seconds", "was the bench-time budget; --budget-seconds names it (a time "
            "limit is --max-seconds in every command)")
    g.add_argument("--criterion", choices=("D", "A", "E"), default="D",
                   help=f"{what}: D (log det of the Fisher information, default), A (mean variance), E (worst "
                   "direction)")
    g.add_argument("--prior", metavar="p=VALUE,...", help=f"{what}: prior guess of the free parameters "
                   "(default: the family's declared defaults)")
    g.add_argument("--prior-spread", type=real(1.0, 1e3), metavar="F", help=f"{what}: the prior range: the "
                   "criterion is averaged over points with each free parameter from its guess / F to its guess x F "
                   f"(pseudo-Bayesian; default {PRIOR_SPREAD:g}; 1: at the guess alone)")
    g.add_argument("--like", metavar="PLAN.toml", help=f"{what}: read every point as this plan does "
                   "(averages, dark, white; default 2 averages, darks per incidence, one white)")
    g.add_argument("--integration-s", type=_times, default=DEFAULT_INTEGRATIONS, metavar="T[,T...]",
                   help=f"{what}: integration times to choose from, s (default %(default)s; the design "
                   "takes the one that identifies best within the budget)")
    g.add_argument("--step", type=real(0.5, 45.0), default=5.0, metavar="DEG",
                   help=f"{what}: step of the in-plane candidate grid, deg (default %(default)s)")


def add_design_options(parser: argparse.ArgumentParser) -> None:
    """The ``bench plan --design`` options."""
    g = parser.add_argument_group("designed plans (--design)")
    g.add_argument("--design", metavar="MODEL", help="write a plan designed to identify MODEL, e.g. "
                   "\"plastic:alpha=?,kd=?\" (the ? parameters), instead of checking PLAN.toml (default: none, check PLAN.toml)")
    g.add_argument("--out", type=output_file((".toml",)), metavar="PLAN.toml", help="--design: the plan file to write (no default: required with --design)")
    g.add_argument("--compare", metavar="PLAN.toml", help="--design: also predict the interval widths of this plan (default: none)")
    g.add_argument("--max-seconds", type=real(0.0, 1e6, lo_open=True), metavar="S",
                   help="--design: time limit of the search (wall clock), s: past it the best design so far is written and "
                        f"the exit status is 1 (default {DEFAULT_MAX_SECONDS:g})")
    add_force_option(parser, "out")
    _add_common(g, "--design")


def add_sequential_options(parser: argparse.ArgumentParser) -> None:
    """The ``bench scan --sequential`` options."""
    g = parser.add_argument_group("sequential design (--sequential)")
    g.add_argument("--sequential", metavar="MODEL", help="measure, fit and re-design until the budget or the "
                   "target widths, for MODEL, e.g. \"plastic:alpha=?,kd=?\" (instead of PLAN.toml; default: none)")
    renamed(g, "--adaptive", "--sequential", "was the sequential design (measure, fit, re-design); 'adaptive' is "
            "the ray-budget rule of spectro and gonio (--no-adaptive)")
    g.add_argument("--target", metavar="p=WIDTH,...", help="--sequential: stop when each named parameter's 95%% "
                   "interval is at most this wide (default: none, the time budget alone)")
    _add_common(g, "--sequential")


def refuse_unused(args: argparse.Namespace, flag: str) -> None:
    """A design option given without ``flag`` (``--design`` / ``--sequential``) would be ignored: refuse it."""
    given = [name for name in ("budget_seconds", "out", "compare", "prior", "prior_spread", "like", "target",
                               "max_seconds")
             if getattr(args, name, None) is not None]
    if given:
        raise InputError(f"--{given[0].replace('_', '-')} applies to {flag} MODEL only")


def _model(args: argparse.Namespace, text: str) -> tuple[ModelSpec, ModelPoint, list[ReadingSettings]]:
    from bench.identify.design_io import design_inputs

    return design_inputs(text, args.prior, args.like, args.integration_s, args.prior_spread)


def cmd_scan_sequential(args: argparse.Namespace) -> int:
    """Sequential design into the store. JSON keys: ``runs`` (one per step), ``seconds`` (bench
    seconds spent, as estimated), ``budget_s``, ``stopped`` (``budget`` or ``target``),
    ``estimates``, ``intervals``, ``widths``, ``steps``."""
    import sys

    from bench.cli.common import open_store
    from bench.config import load_bench
    from bench.identify.design_sequential import sequential_scan, parse_targets, session_candidates, session_key

    if args.plan is not None:
        raise InputError(f"give a plan file or --sequential, not both (got {args.plan} and --sequential)")
    if args.budget_seconds is None:
        raise InputError("--sequential needs --budget-seconds S (the bench-time budget)")
    spec, point, settings = _model(args, args.sequential)
    targets = parse_targets(args.target, spec.names, spec.canonical)
    key = session_key(spec.text, args.bench, args.body, args.budget_seconds, args.criterion, args.prior, args.integration_s,
                      args.like, args.step, args.target, args.seed,
                      *([] if args.prior_spread is None else [args.prior_spread]))  # earlier sessions' keys stand
    bench = load_bench(args.bench, seed=args.seed, body=args.body)
    with bench, open_store(args.store) as store:
        candidates = session_candidates(bench, args.step, settings)
        result = sequential_scan(bench, store, spec, point, args.budget_seconds, settings, candidates, args.criterion,
                               targets, seed=getattr(bench.goniometer, "seed", args.seed), key=key,
                               progress=not args.quiet and sys.stderr.isatty())
    label = spec.labels  # every parameter named as the model string wrote it
    if args.json:
        out = result.as_dict()
        out["steps"] = [dict(step) for step in out["steps"]]
        for table in (out, *out["steps"]):
            for key in ("estimates", "intervals", "widths"):
                if isinstance(table.get(key), dict):
                    table[key] = {label.get(n, n): v for n, v in table[key].items()}
        emit_json(out)
        return 0
    for k, s in enumerate(result.steps):
        print(f"step {k}: run {s.run_id}, {s.points} points, {s.seconds:.4g} s; "
              + ", ".join(f"{label.get(n, n)} = {v:.5g} (width {s.widths[n]:.3g})" for n, v in s.estimates.items()))
    print(f"stopped at the {result.stopped} after {result.seconds:.4g} s of {result.budget_s:g} s: "
          + ", ".join(f"{label.get(n, n)} = {v:.5g} [{result.intervals[n][0]:.5g}, {result.intervals[n][1]:.5g}]"
                      for n, v in result.estimates.items()))
    return 0


def open_design(args: argparse.Namespace) -> tuple[ModelSpec, ModelPoint, list[ReadingSettings], Bench]:
    """The parsed model, the model at its prior, the reading settings to choose from and the bench
    of a design command."""
    from bench.builders.described import design_bench

    spec, point, settings = _model(args, args.design)
    return spec, point, settings, design_bench(args.bench, body=args.body)


def cmd_plan_design(args: argparse.Namespace) -> int:
    """Design, write and check a plan. JSON keys: ``plan`` (path), ``model``, ``prior``,
    ``criterion``, ``budget_s``, ``seconds``, ``motion_s``, ``points``, ``candidates``, ``widths``
    (predicted 95 % interval widths at the prior guess), ``prior_spread`` and ``prior_points`` (the
    prior range the criterion averaged over: 1 point = the guess alone), ``width_range`` (each
    parameter's predicted [min, max] width over those points), ``compare`` (null, or the compared plan's ``plan``,
    ``seconds``, ``points``, ``widths``), ``stopped`` (null, or why ``--max-seconds`` cut the search
    short: the best design so far is written and the exit status is 1)."""
    from bench.core.errors import PlanError
    from bench.identify.design import design_for_bench, information, interval_widths
    from bench.identify.design_io import as_written, prior_lines, widths_text, write_design
    from bench.identify.design_noise import bench_reading_model
    from bench.identify.identifiability import refuse_unidentifiable
    from bench.identify.time_model import ReadingSettings, bench_time_model, candidate_grid, reachable
    from bench.plans import load_plan, refusal_message, refusals

    if args.plan is not None:
        raise InputError(f"give a plan file or --design, not both (got {args.plan} and --design)")
    if args.budget_seconds is None or args.out is None:
        raise InputError("--design needs --budget-seconds S (the bench-time budget) and --out PLAN.toml")
    out = check_output(args.out)
    compare = load_plan(args.compare) if args.compare else None
    spec, point, settings, bench = open_design(args)
    with bench:
        check = bench.goniometer.check
        # nor one the detector saturates at the shortest integration (each longer one leaves out more)
        candidates = reachable(candidate_grid(args.step), check, settings[0], bench.config,
                               min(s.integration_s for s in settings))
        if not candidates:
            raise InputError(f"bench {bench.name!r} refuses every point of the in-plane candidate grid")
        everything = information(point, candidates, bench_reading_model(bench, settings[0])).total(range(len(candidates)))
        refuse_unidentifiable(everything, [spec.labels[n] for n in spec.names], spec.upper - spec.lower, bench.name)
        design = design_for_bench(point, bench, candidates, args.budget_seconds, settings, args.criterion,
                                  max_seconds=args.max_seconds or DEFAULT_MAX_SECONDS)
        write_design(out, design, spec.text, bench.name, bench.kind, len(candidates), args.budget_seconds, spec.labels)
        written = load_plan(out)
        refused = refusals(written, check)
        if refused:  # the design chose only reachable points: this would be a bug, said as the validator says it
            raise PlanError(refusal_message(written, refused))
        other = None
        if compare is not None:
            refused = refusals(compare, check)
            pts = [g for i, g in enumerate(compare.points) if i not in {r.index for r in refused}]
            like = ReadingSettings.like(compare)
            fisher = information(point, pts, bench_reading_model(bench, like)).total(range(len(pts)))
            other = {"plan": compare.name, "points": len(pts),
                     "seconds": bench_time_model(bench, like).seconds(pts)["seconds"],
                     "widths": as_written(interval_widths(fisher, point.free), spec.labels)}
    # every parameter named as the model string wrote it (an alias such as albedo, not reflectance)
    result = {"plan": str(out), "model": spec.text, "prior": as_written(point.values, spec.labels),
              "criterion": design.criterion,
              "budget_s": args.budget_seconds, "seconds": design.seconds, "motion_s": design.estimate["motion_s"],
              "points": len(design.points), "candidates": len(candidates), "integration_s": design.settings.integration_s,
              "averages": design.settings.averages, "widths": as_written(design.widths, spec.labels), "compare": other,
              "prior_spread": point.spread, "prior_points": design.prior_points,
              "width_range": {k: list(v) for k, v in as_written(design.width_range or {}, spec.labels).items()},
              "stopped": design.stopped}
    if design.stopped:  # the best design so far is written: say why it may not be the best there is
        import sys

        print(f"bench plan: stopped: {design.stopped}; {out} holds the best design so far", file=sys.stderr)
    if args.json:
        emit_json(result)
        return 1 if design.stopped else 0
    print(f"wrote {out}: {len(design.points)} points ({design.criterion}-optimal for {spec.text}) of "
          f"{len(candidates)} reachable on bench {bench.name}, {design.settings.integration_s:g} s x "
          f"{design.settings.averages} per point, estimated {design.seconds:.4g} s of {args.budget_seconds:g} s")
    for line in prior_lines(design, "  ", spec.labels):
        print(line)
    if other is not None:
        print(f"  plan {other['plan']}: {other['points']} points, {other['seconds']:.4g} s, widths "
              f"{widths_text(other['widths'])}")
    return 1 if design.stopped else 0
