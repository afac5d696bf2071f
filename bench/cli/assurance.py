"""Measurement assurance on the command line: ``bench check`` (measure the bench's check
standards) and ``bench chart`` (their control charts from the store). The logic is
:mod:`bench.assurance`; this module parses, prints and plots.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from bench.cli.argtypes import iso_date, seed
from bench.cli.commands import command_help
from bench.cli.common import (DEFAULT_STORE, add_bench_options, add_force_option, announce_compilation, emit_json,
                              open_store, output_file)
from bench.core.errors import InputError

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading the schemas or the charts
    from pathlib import Path

    from bench.core.schemas import CheckTable
    from compare.control import Chart

__all__ = ["register", "cmd_check", "cmd_chart", "scan_gate", "add_date_option", "plot_charts"]


def add_date_option(parser: argparse.ArgumentParser, what: str) -> None:
    """``--date YYYY-MM-DD``: the simulated day of a check or scan (virtual and emulated bodies)."""
    parser.add_argument("--date", type=iso_date, default=None, metavar="YYYY-MM-DD",
                        help=f"the simulated day of this {what} (virtual and emulated bodies only; default: today)")


def scan_gate(description: Any, store_path: str, body: str, on: str | None = None) -> dict[str, Any] | None:
    """What ``bench scan`` asks before it opens anything (:func:`bench.assurance.gate`): None when
    the bench declares no assurance; else the state it records in the run. Out of control or
    overdue: one warning line on stderr (``assurance = "warn"``) or refused in one line, exit 2
    (``"refuse"``)."""
    from pathlib import Path

    from bench.assurance import gate

    if on is not None and body == "real":
        raise InputError("--date simulates a day on the virtual or emulated body; a real bench scans today")
    if Path(store_path).exists():
        with open_store(store_path, create=False, readonly=True) as store:
            state = gate(description, store, on)
    else:
        state = gate(description, None, on)
    if state is None:
        return None
    if state.problems:
        message = state.message(description.get("name", "bench"))
        if state.refuses:
            raise InputError(f"{message} (assurance = \"refuse\": measure the check standards with bench check)")
        print(f"warning: {message}", file=sys.stderr)
    return {"policy": state.policy, "checks": state.states, "problems": list(state.problems)}


def cmd_check(args: argparse.Namespace) -> int:
    """Measure each check standard (or those ``--check`` names) as a run of kind ``check`` and
    print every reading's E_n; JSON: ``{"checks": [{check, run, date, value, max_abs_E_n, agree,
    masked, readings: [{point, wavelength_nm, value, reference, E_n}]}]}``."""
    from bench.assurance import check_description, check_plan, checks_of, score, today
    from bench.builders.drift import day_seed, on_day
    from bench.builders.instrument import declared_aperture
    from bench.config import load_bench, load_description
    from bench.plan_check import refuse_before_opening
    from bench.plans import plan_from_dict
    from bench.runner import run_scan

    d, body = load_description(args.bench, args.body)
    if args.date is not None and body == "real":
        raise InputError("--date simulates a day on the virtual or emulated body; a real bench checks today")
    on = args.date or today()
    checks = checks_of(d, args.check or (), f"bench config {args.bench}")
    d = on_day(d, on)  # a declared [drift] simulated on that day
    plans = [(c, plan_from_dict(check_plan(c), name=f"check {c.name}"), check_description(d, c, body)) for c in checks]
    for _, plan, described in plans:  # every check refused before anything is opened
        refuse_before_opening(plan, described, body)
    if body == "virtual":
        announce_compilation()
    out = []
    with open_store(args.store) as store:
        for check, plan, described in plans:
            seed = day_seed(d, args.date, args.seed)  # a simulated day draws noise of its own
            bench = load_bench(described, seed=seed, body=body)
            with bench:
                result = run_scan(bench, plan, store, seed=getattr(bench.goniometer, "seed", seed),
                                  kind="check", extra_meta={"check": {"check": check.name, "date": on}})
            if result.status != "completed":
                raise InputError(f"check {check.name!r}: run {result.run_id} {result.status} ({result.reason}); "
                                 f"finish it with bench resume {result.run_id}")
            scored = score(check, store.readings(result.run_id), declared_aperture(described) or 0.0)
            summary = {k: v for k, v in scored.items() if k != "readings"}
            store.update_meta(result.run_id, check={**summary, "date": on})
            out.append({**scored, "run": result.run_id, "date": on})
    if args.json:
        emit_json({"bench": d.get("name", "bench"), "body": body, "checks": out})
        return 0
    for c in out:
        masked = f", {c['masked']} masked" if c["masked"] else ""
        print(f"check {c['check']} on {c['date']}: run {c['run']}, value {c['value']:.5f} x reference, "
              f"max |E_n| {c['max_abs_E_n']:.2f} ({'agrees' if c['agree'] else 'DISAGREES'}{masked})")
        for r in c["readings"]:
            flag = "" if abs(r["E_n"]) <= 1 else "  |E_n| > 1"
            print(f"  point {r['point']} {r['wavelength_nm']:.1f} nm: {r['value']:.5g} 1/sr, reference "
                  f"{r['reference']:.5g}, E_n {r['E_n']:+.2f}{flag}")
    return 0


def cmd_chart(args: argparse.Namespace) -> int:
    """The control chart of each check standard (or ``--check``): the check values of its
    completed check runs, centre and limits, and the rules broken; JSON ``{"charts": [{check,
    runs: [{run, date, value}], centre, sigma, baseline, declared, limits, violations, in_control}]}``."""
    from bench.assurance import check_chart, check_history, checks_of
    from bench.config import load_description

    d, _ = load_description(args.bench, None)
    checks = checks_of(d, args.check or (), f"bench config {args.bench}")
    name = d.get("name", "bench")
    with open_store(args.store, create=False, readonly=True) as store:
        charts = []
        for check in checks:
            history = check_history(store, name, check.name)
            charts.append((check, history, check_chart(check, history)))
    if args.plot:
        plot_charts(charts, args.plot, name)
    if args.json:
        emit_json({"bench": name, "charts": [{"check": c.name, "runs": [{k: h[k] for k in ("run", "date", "value")}
                                                                         for h in hist], **ch.as_dict()}
                                              for c, hist, ch in charts]})
        return 0
    for check, history, ch in charts:
        state = "in control" if ch.in_control else f"{len(ch.violations)} rule violation(s)"
        how = "declared" if ch.declared else f"from the first {ch.baseline} points"
        print(f"check {check.name} on bench {name}: {len(history)} runs, centre {ch.centre:.5f}, sigma {ch.sigma:.3g} "
              f"({how}): {state}")
        flags: dict[int, list[str]] = {}
        for v in ch.violations:
            flags.setdefault(v.index, []).append(v.text)
        for i, h in enumerate(history):
            mark = f"  <- {'; '.join(flags[i])}" if i in flags else ""
            print(f"  {h['date']}  {h['run']}  {h['value']:.5f}{mark}")
    return 0


def plot_charts(charts: list[tuple[CheckTable, list[dict[str, Any]], Chart]], path: str | Path, bench_name: str) -> None:
    """Draw ``(check, history, chart)`` triples into one PNG, a Shewhart chart per check (``bench
    chart --plot``, and the HTML report of ``bench compare`` for the checks a run relied on)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.core.outputs import save_figure

    fig, axes = plt.subplots(len(charts), 1, figsize=(9, 3.4 * len(charts)), squeeze=False)
    for ax, (check, history, ch) in zip(axes[:, 0], charts):
        x = list(range(len(ch.values)))
        if not ch.declared:  # the points the centre and limits come from
            ax.axvspan(-0.5, ch.baseline - 0.5, color="0.93", zorder=0, label=f"baseline ({ch.baseline} runs)")
        ax.plot(x, ch.values, "o-", color="tab:blue", ms=4, label="check value")
        ax.axhline(ch.centre, color="k", lw=1, label="centre")
        for k, style, colour in ((3, "-", "tab:red"), (2, "--", "grey"), (1, ":", "grey")):
            for sgn in (1, -1):
                ax.axhline(ch.centre + sgn * k * ch.sigma, color=colour, ls=style, lw=0.8,
                           label=f"centre +- {k} sigma" if sgn == 1 else None)
        for i, v in enumerate(ch.violations):
            ax.plot(v.index, ch.values[v.index], "s", color="tab:red", ms=9, mfc="none",
                    label="rule broken" if i == 0 else None)
        step = max(1, len(x) // 12)
        ax.set_xticks(x[::step], [str(h["date"] or "")[5:] for h in history][::step])
        ax.set_title(f"check {check.name}, bench {bench_name}: Shewhart chart, Western Electric / Nelson rules "
                     f"({'in control' if ch.in_control else 'out of control'})", fontsize=9)
        ax.set_xlabel("check run (date)")
        ax.set_ylabel("reading / reference")
        ax.legend(fontsize=7, loc="upper left", ncol=3)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``check`` and ``chart`` to the subcommands."""
    c = sub.add_parser("check", help=command_help("check"))
    add_bench_options(c, "the bench whose [[check]] standards to measure (required)")
    c.add_argument("--check", action="append", metavar="NAME", help="measure only this check (repeatable; default: all)")
    c.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help="run store (default %(default)s)")
    c.add_argument("--seed", type=seed, default=None, help="seed of the virtual and emulated bodies' noise, integer 0..2^63-1 (default: the bench's, "
                        "else a fresh one)")
    add_date_option(c, "check")
    c.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    c.set_defaults(func=cmd_check)

    h = sub.add_parser("chart", help=command_help("chart"))
    h.add_argument("--bench", required=True, metavar="BENCH.toml", help="the bench whose checks to chart (required)")
    h.add_argument("--check", action="append", metavar="NAME", help="chart only this check (repeatable; default: all)")
    h.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite", help="run store (default %(default)s)")
    h.add_argument("--plot", type=output_file((".png",)), default=None, metavar="FILE.png",
                   help="draw the charts into this PNG (default: none)")
    h.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    add_force_option(h, "plot")
    h.set_defaults(func=cmd_chart)
