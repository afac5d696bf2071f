"""``bench plan --design``: write a plan designed to identify a model within a bench-time budget.

Not a command module of its own: :mod:`bench.cli.scans` declares the options on ``bench plan``
and calls :func:`cmd_plan_design` when ``--design`` is given (imported then, with scipy-free
numpy design code; the model strings come from :mod:`bench.identify.model_spec`).
"""

from __future__ import annotations

import argparse
from typing import Any

from bench.cli.argtypes import real
from bench.cli.common import check_output, emit_json, hms, output_file
from bench.core.errors import InputError

__all__ = ["add_design_options", "cmd_plan_design", "open_design"]


def add_design_options(parser: argparse.ArgumentParser) -> None:
    """The ``bench plan --design`` options."""
    g = parser.add_argument_group("designed plans (--design)")
    g.add_argument("--design", metavar="MODEL", help="write a plan designed to identify MODEL, e.g. "
                   "\"plastic:alpha=?,kd=?\" (the ? parameters), instead of checking PLAN.toml")
    g.add_argument("--seconds", type=real(0.0, 1e7, lo_open=True), metavar="S",
                   help="--design: the bench-time budget, s (as `bench plan` estimates it)")
    g.add_argument("--out", type=output_file((".toml",)), metavar="PLAN.toml", help="--design: the plan file to write")
    g.add_argument("--criterion", choices=("D", "A", "E"), default="D",
                   help="--design: D (log det of the Fisher information, default), A (mean variance), E (worst "
                   "direction)")
    g.add_argument("--prior", metavar="p=VALUE,...", help="--design: prior guess of the free parameters "
                   "(default: the family's declared defaults)")
    g.add_argument("--like", metavar="PLAN.toml", help="--design: read every point as this plan does "
                   "(integration, averages, dark, white; default 0.02 s x 2, darks per incidence, one white)")
    g.add_argument("--step", type=real(0.5, 45.0), default=5.0, metavar="DEG",
                   help="--design: step of the in-plane candidate grid, deg (default %(default)s)")
    g.add_argument("--compare", metavar="PLAN.toml", help="--design: also predict the interval widths of this plan")


def open_design(args: argparse.Namespace) -> tuple[Any, Any, Any, Any]:
    """The parsed model, the model at its prior, the reading settings and the bench of a design command."""
    from bench.config import load_bench
    from bench.identify.design_io import model_point, parse_prior
    from bench.identify.model_spec import parse_model_spec
    from bench.identify.time_model import ReadingSettings
    from bench.plans import load_plan

    spec = parse_model_spec(args.design)
    point = model_point(spec, parse_prior(args.prior))
    settings = ReadingSettings.like(load_plan(args.like)) if args.like else ReadingSettings()
    bench = load_bench(args.bench, seed=getattr(args, "seed", None), body=args.body)
    return spec, point, settings, bench


def cmd_plan_design(args: argparse.Namespace) -> int:
    """Design, write and check a plan. JSON keys: ``plan`` (path), ``model``, ``prior``,
    ``criterion``, ``budget_s``, ``seconds``, ``motion_s``, ``points``, ``candidates``, ``widths``
    (predicted 95 % interval widths), ``compare`` (null, or the compared plan's ``plan``,
    ``seconds``, ``points``, ``widths``)."""
    from bench.core.errors import PlanError
    from bench.identify.design import design_plan, information, interval_widths
    from bench.identify.design_io import widths_text, write_design
    from bench.identify.design_noise import bench_reading_model
    from bench.identify.time_model import bench_time_model, candidate_grid, reachable
    from bench.plans import load_plan, refusal_message, refusals

    if args.plan is not None:
        raise InputError(f"give a plan file or --design, not both (got {args.plan} and --design)")
    if args.seconds is None or args.out is None:
        raise InputError("--design needs --seconds S (the bench-time budget) and --out PLAN.toml")
    out = check_output(args.out)
    compare = load_plan(args.compare) if args.compare else None
    spec, point, settings, bench = open_design(args)
    with bench:
        check = bench.goniometer.check
        time = bench_time_model(bench, settings)
        readings = bench_reading_model(bench, settings)
        candidates = reachable(candidate_grid(args.step), check, settings)
        if not candidates:
            raise InputError(f"bench {bench.name!r} refuses every point of the in-plane candidate grid")
        design = design_plan(point, candidates, readings, time, args.seconds, args.criterion)
        write_design(out, design, settings, spec.text, bench.name, bench.kind, len(candidates), args.seconds)
        written = load_plan(out)
        refused = refusals(written, check)
        if refused:  # the design chose only reachable points: this would be a bug, said as the validator says it
            raise PlanError(refusal_message(written, refused))
        other = None
        if compare is not None:
            refused = refusals(compare, check)
            pts = [g for i, g in enumerate(compare.points) if i not in {r.index for r in refused}]
            fisher = information(point, pts, readings).total(range(len(pts)))
            other = {"plan": compare.name, "points": len(pts), "seconds": time.seconds(pts)["seconds"],
                     "widths": interval_widths(fisher, point.free)}
    result = {"plan": str(out), "model": spec.text, "prior": dict(point.values), "criterion": design.criterion,
              "budget_s": args.seconds, "seconds": design.seconds, "motion_s": design.estimate["motion_s"],
              "points": len(design.points), "candidates": len(candidates), "widths": design.widths, "compare": other}
    if args.json:
        emit_json(result)
        return 0
    print(f"wrote {out}: {len(design.points)} points ({design.criterion}-optimal for {spec.text}) of "
          f"{len(candidates)} reachable on bench {bench.name}, estimated {hms(design.seconds)} of {hms(args.seconds)}")
    print(f"  predicted 95% interval widths: {widths_text(design.widths)}")
    if other is not None:
        print(f"  plan {other['plan']}: {other['points']} points, {hms(other['seconds'])}, widths "
              f"{widths_text(other['widths'])}")
    return 0
