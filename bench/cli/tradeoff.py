"""``bench tradeoff``: the accuracy-versus-time table and plot of a scene.

Registered through :data:`bench.cli.COMMAND_MODULES`; imports nothing heavy at module level.

``bench tradeoff SCENE.toml [--json] [--plot FILE.png]`` prints the accuracy-versus-time table
of a scene (:func:`virtual.tradeoff.sweep`) -- or, for a ``physical`` scene, scan duration
against angular step and averaging -- plus the measured cost of each declared effect, and
draws the error-versus-time plot as small multiples (:mod:`bench.tradeoff_plot`: timings the
median of at least 3 seeded sweeps with their spread, the Pareto front from the medians, every
point labelled with its N). A physical scene's table comes from :mod:`bench.tradeoff_physical`. The adaptive budget of ``spectro``/``gonio`` is
:mod:`bench.adaptive`.

``bench tradeoff --design MODEL --bench B [--body ...] [--seeds 7,8,9] [--prior p=v,...] [--methods ...]
[--plot FILE.png] [--json]`` (no SCENE.toml) is accuracy per bench-minute instead: the fitted 95 %
interval widths of the uniform in-plane plan, designed plans and the sequential design against their
bench time, on the bench's own specimen, over seeds (:mod:`bench.identify.design_study`).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bench.cli.argtypes import count, int_list, seed, stderr_is_terminal
from bench.cli.commands import command_help
from bench.cli.common import BODIES, PLOT_SUFFIXES, add_force_option, announce_compilation, emit_json, output_file
from bench.core.errors import InputError

__all__ = ["register", "cmd_tradeoff"]


def register(subparsers: Any) -> None:
    """Add ``tradeoff`` to the ``bench`` subcommands."""
    t = subparsers.add_parser("tradeoff", help=command_help("tradeoff"))
    t.add_argument("scene", metavar="SCENE.toml", nargs="?",
                   help="the scene file (see fixtures/scenes/); not with --design")
    t.add_argument("--json", action="store_true", help="one JSON object: rows (one per configuration), effects (--design: rows per method, cpu)")
    t.add_argument("--plot", type=output_file(PLOT_SUFFIXES), metavar="FILE.png",
                   help="error-vs-time (log-log) Pareto plot (png, pdf, svg, ...; --design: interval width against bench "
                        "minutes, one panel per free parameter; default: none)")
    t.add_argument("--rays", type=int_list(1, 10**12, most=50),
                   help="comma-separated ray counts, each 1..1e12 (default: the scene's [tradeoff].rays)")
    t.add_argument("--repeats", type=count(3, 1000),
                   help="times each configuration is measured (seeded sweeps), 3..1000 (default 3: timings are their median, the plot "
                        "shows their spread)")
    t.add_argument("--seed", type=seed, help="root seed, integer 0..2^63-1 (default: the scene's)")
    t.add_argument("--no-costs", action="store_true", help="skip measuring each declared effect's cost")
    g = t.add_argument_group("accuracy per bench-minute (--design MODEL, instead of SCENE.toml)")
    g.add_argument("--design", metavar="MODEL", help="fit MODEL, e.g. \"plastic:alpha=?,kd=?\" (the ? parameters), "
                   "to the uniform in-plane plan, designed plans and the sequential design, scanned on --bench "
                   "(default: none, the scene's table)")
    g.add_argument("--bench", metavar="BENCH.toml", help="--design: the bench description; its [specimen] spec is "
                   "the specimen under test (no default: required with --design)")
    g.add_argument("--body", choices=BODIES, default=None,
                   help="--design: what executes the bench description (default: the file's kind)")
    g.add_argument("--seeds", type=int_list(0, 2**63 - 1, most=50), metavar="S,S,...",
                   help="--design: emulator/simulation seeds, one study each (default 7,8,9)")
    g.add_argument("--prior", metavar="p=VALUE,...", help="--design: the designs' prior guess of the free "
                   "parameters (default: the family's declared defaults)")
    g.add_argument("--methods", metavar="M,M,...", help="--design: methods to measure, some of uniform, "
                   "uniform-half, designed, designed-half, designed-A, sequential; uniform always (default: all)")
    add_force_option(t, "plot")
    t.set_defaults(func=cmd_tradeoff)


#: options of each form, to refuse mixing them in one line
_SCENE_ONLY = ("rays", "repeats", "seed")
_DESIGN_ONLY = ("bench", "body", "seeds", "prior", "methods")


def _check_form(args: argparse.Namespace) -> None:
    if args.scene is not None and args.design is not None:
        raise InputError(f"give SCENE.toml or --design MODEL, not both (got {args.scene} and --design)")
    if args.scene is None and args.design is None:
        raise InputError("give SCENE.toml, or --design MODEL --bench BENCH.toml")
    if args.design is None:
        given = [n for n in _DESIGN_ONLY if getattr(args, n) is not None]
        if given:
            raise InputError(f"--{given[0]} applies to --design MODEL only, not to SCENE.toml")
        return
    given = [n for n in _SCENE_ONLY if getattr(args, n) is not None] + (["no-costs"] if args.no_costs else [])
    if given:
        raise InputError(f"--{given[0]} applies to SCENE.toml only, not to --design")
    if args.bench is None:
        raise InputError("--design needs --bench BENCH.toml (the bench and its specimen)")


def _cmd_design(args: argparse.Namespace) -> int:
    """Accuracy per bench-minute. JSON keys: ``model``, ``specimen``, ``truth`` (null when the
    specimen is not of the model's family), ``prior``, ``bench``, ``body``, ``seeds``, ``cpu``,
    ``designs``, ``rows`` (:func:`bench.identify.design_study.rows`)."""
    from bench.core.parsing import read_toml
    from bench.identify import design_study
    from bench.identify.design_io import parse_prior

    methods = design_study.parse_methods(args.methods)
    prior = parse_prior(args.prior) if args.prior else None
    description = read_toml(args.bench, "bench config")
    say = (lambda text: print(text, file=sys.stderr)) if stderr_is_terminal() else None
    m = design_study.measure(args.design, description, seeds=args.seeds or design_study.SEEDS, body=args.body,
                             prior=prior, methods=methods, progress=say)
    if args.plot:
        design_study.plot_study(m, args.plot)
    if args.json:
        emit_json({k: m[k] for k in ("model", "specimen", "truth", "prior", "bench", "body", "seeds", "cpu",
                                      "designs")} | {"rows": design_study.rows(m)})
        return 0
    print(f"accuracy per bench-minute: {design_study.describe(m)}")
    print("95% interval widths: median [range] over the seeds; bench s: `bench plan`'s estimate (median)")
    print(_table(design_study.header(m), design_study.summary(m)))
    for n, x in m["designs"].items():
        print(f"  {n}: {x['points']} points at {x['integration_s']:g} s, predicted widths "
              + ", ".join(f"{k} {v:.3g}" for k, v in x["predicted_widths"].items()))
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if v == 0 or 1e-3 <= abs(v) < 1e6:
            return f"{v:.4g}"
        return f"{v:.3e}"
    if isinstance(v, int):
        return f"{v:,}"
    return str(v)


def _table(header: list[str], rows: list[list[Any]]) -> str:
    cells = [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(header)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join(lines)


def cmd_tradeoff(args: argparse.Namespace) -> int:
    _check_form(args)
    if args.design is not None:
        return _cmd_design(args)
    from virtual.scene import effect_costs, load_scene

    scene = load_scene(args.scene)  # validated by the scene schema: one line naming file, key, value
    announce_compilation()
    rays = args.rays  # a list of ints, checked by argparse
    if scene.instrument == "physical":
        from bench.tradeoff_physical import physical_sweep, plot_physical

        rows = physical_sweep(scene)
        if args.plot:
            plot_physical(rows, args.plot, title=f"{scene.name}: scan duration")
        if args.json:
            emit_json({"scene": scene.name, "instrument": "physical", "rows": rows})
            return 0
        print(f"scene {scene.name} (physical bench): scan duration against angular step and averaging")
        print(_table(["step_deg", "averages", "points", "seconds", "motion_s", "acquisition_s", "rel. uncertainty"],
                     [[r["step_deg"], r["averages"], r["points"], r["seconds"], r["motion_s"], r["acquisition_s"],
                       r["relative_uncertainty"]] for r in rows]))
        if args.plot:
            print(f"plot: {args.plot}")
        return 0
    from bench.tradeoff_plot import MIN_REPEATS, plot_small_multiples, repeated_sweep

    rows = repeated_sweep(scene, rays=rays, repeats=args.repeats or MIN_REPEATS, seed=args.seed,
                          progress=stderr_is_terminal())
    costs = [] if args.no_costs or not scene.effects.declared() else effect_costs(
        scene, rays=min(scene.n_rays, 1_000_000), repeat=3)
    unit = "1/sr" if scene.instrument == "goniophotometer" else "reflectance, 1"
    if args.plot:
        plot_small_multiples(rows, args.plot, title=f"{scene.name}: accuracy versus time", error_unit=unit)
    if args.json:
        emit_json({"scene": scene.name, "instrument": scene.instrument, "effects": scene.effects.declared(),
                   "positions_sampled": scene.needs_positions, "rows": rows, "effect_costs": costs})
        return 0
    print(f"scene {scene.name}: {scene.instrument}, specimen {scene.specimen.label}, beam {scene.beam.kind}, "
          f"incidence {scene.incidence[0]:g} deg, effects: {', '.join(scene.effects.declared()) or 'none'}"
          f"{' (positions sampled)' if scene.needs_positions else ''}")
    print(f"errors in {unit} (max |error| and its bound alike); seconds: median of {rows[0]['repeats']} runs "
          f"[fastest, slowest]")
    print(_table(["strategy", "collector", "budget", "method", "N", "seconds", "[lo, hi]", "max_abs_error",
                  "rms_error", "predicted_bound", "predicted_max", "predicted_rms", "within", "pareto"],
                 [[r["strategy"], r["collector"], r["budget"], r["method"], r["N"], r["seconds"],
                   f"[{r['seconds_lo']:.3g}, {r['seconds_hi']:.3g}]", r["max_abs_error"],
                   r["rms_error"], r["predicted_bound"], r["predicted_max"], r["predicted_rms"], r["within_bound"],
                   "*" if r["pareto"] else ""] for r in rows]))
    for r in rows:
        if r["budget"] == "adaptive":
            print(f"adaptive ({r['collector']}): {r['N']:,} rays against eq. 3.5/3.12's {r['hoeffding_N']:,} "
                  f"({r['saved_fraction']:.0%} saved)")
    if costs:
        print("cost of each declared effect (best of 3, same run):")
        print(_table(["effects", "seconds", "x bare", "rays/s", "path", "positions"],
                     [[c["effects"], c["seconds"], c["ratio_to_bare"], c["rays_per_second"], c["method"],
                       c["positions_sampled"]] for c in costs]))
    if args.plot:
        print(f"plot: {args.plot}")
    return 0
