"""Accuracy per bench-minute: fitted interval widths of the uniform in-plane plan, designed plans
and the sequential design, scanned and fitted on a bench over several seeds.

The one implementation behind ``bench tradeoff --design MODEL --bench B`` (:mod:`bench.cli.tradeoff`)
and ``python -m benchmarks design`` (:mod:`benchmarks.bench_design`, a thin wrapper).

:func:`measure` scans every method on every seed and fits ``MODEL`` to each scan with the bench's
likelihood (:func:`bench.identify.design_sequential.fit_readings`: the readings' full covariance).
The methods (:data:`METHODS`): the uniform in-plane plan (``fixtures/plans/in-plane.toml``), the
same at half the theta_r density, a D-optimal design within the uniform plan's bench time, one in
half that time, an A-optimal one, and the sequential design (:func:`sequential_scan`) with the
uniform plan's time as its budget. The designs start from the prior (default: the family's
declared defaults) -- a guess, not the truth -- and are made once, on the first seed's bench
(they do not depend on the seed). Bench time is ``bench plan``'s estimate.

The truth is the bench description's ``[specimen] spec`` when its family is the model's
(:func:`truth_of`), else unknown (the "truth in" column says n/a). :func:`summary` gives the table's
rows, :func:`rows` the JSON rows, :func:`plot_study` the figure: one panel per free parameter, 95 %
interval width against bench minutes, the median over seeds with the seeds' range as error bars.
"""

from __future__ import annotations

import copy
import logging
import statistics
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

from bench.core.errors import InputError
from bench.core.records import BSDFRecord
from bench.core.outputs import save_figure

if TYPE_CHECKING:  # for the annotations only: the study imports its machinery when it runs, as measure() does
    from bench.identify.model_spec import ModelSpec
    from matplotlib.figure import Figure

    from bench.plans import Plan

__all__ = ["METHODS", "SEEDS", "UNIFORM", "measure", "summary", "rows", "header", "plot_study", "truth_of",
           "parse_methods"]

log = logging.getLogger("bench.identify.design_study")

#: the uniform in-plane plan every design is measured against (its bench time is the budget)
UNIFORM = Path(__file__).resolve().parent.parent.parent / "fixtures" / "plans" / "in-plane.toml"
#: emulator seeds of the study
SEEDS = (7, 8, 9)
#: method key (``--methods``) -> the name the table and the plot show
METHODS = {"uniform": "uniform in-plane", "uniform-half": "uniform, 10 deg", "designed": "designed",
           "designed-half": "designed, half time", "designed-A": "designed, A-optimal", "sequential": "sequential"}
#: the integration times (s) a design chooses from, each read as the uniform plan reads its points
INTEGRATIONS = (0.005, 0.01, 0.02, 0.05)
#: designed methods: key -> (fraction of the uniform plan's time, criterion)
_DESIGNED = {"designed": (1.0, "D"), "designed-half": (0.5, "D"), "designed-A": (1.0, "A")}


def parse_methods(text: str | None) -> tuple[str, ...]:
    """``--methods a,b,...`` -> method keys in :data:`METHODS` order (default: all); the uniform plan
    is always among them (it is the reference of the ratios and the budget)."""
    if text is None:
        return tuple(METHODS)
    keys = [t.strip() for t in str(text).split(",") if t.strip()]
    unknown = [k for k in keys if k not in METHODS]
    if unknown or not keys:
        raise InputError(f"--methods {text!r}: expected some of {', '.join(METHODS)} separated by commas")
    if "uniform" not in keys:
        raise InputError(f"--methods {text!r}: must include uniform (the reference of the ratios)")
    return tuple(k for k in METHODS if k in keys)


def truth_of(spec: ModelSpec, specimen: str) -> dict[str, float] | None:
    """The free parameters' true values when the bench's specimen is of the model's family (and
    they are constants, not spectral tables), else None."""
    from virtual.specimens import parse_specimen

    s = parse_specimen(specimen)
    if getattr(s, "name", None) != spec.family.name:
        return None
    out = {}
    for n in spec.names:
        v = getattr(s, n)
        if getattr(v, "wavelengths", None) is not None:  # a spectral table: no one true value to check
            return None
        out[n] = float(getattr(v, "values", [v])[0])
    return out


def _uniform_half() -> Plan:
    """The uniform in-plane plan at half the theta_r density (10 deg steps): about half its time."""
    from bench.core.parsing import read_toml
    from bench.plans import plan_from_dict

    t = read_toml(UNIFORM, "plan file")
    t["in_plane"]["theta_r"] = {"start": -20, "stop": 80, "step": 10}
    t["name"] = "in-plane-10deg"
    return plan_from_dict(t, name="in-plane-10deg")


def _seeded(description: Mapping[str, Any], seed: int) -> dict[str, Any]:
    d = copy.deepcopy(dict(description))
    if isinstance(d.get("emulated"), dict):  # the emulators' noise (the file's seed wins over load_bench's)
        d["emulated"]["seed"] = seed
    return d


def _fit(model: str, records: list[BSDFRecord]) -> dict[str, tuple[float, float, float]]:
    from bench.identify.design_sequential import fit_readings

    fit = fit_readings(model, records)
    return {n: (e.value, e.ci[0], e.ci[1]) for n, e in fit.parameters.items()}


def measure(model: str, description: Mapping[str, Any], *, seeds: Sequence[int] = SEEDS, body: str | None = None,
            prior: Mapping[str, float] | None = None, methods: Sequence[str] = tuple(METHODS),
            progress: Callable[[str], None] | None = None, spread: float | None = None) -> dict[str, Any]:
    """Scan and fit every method on every seed on the bench ``description`` (a bench config dict)
    executed by ``body`` (default: its kind). Returns the model, truth (None when unknown), prior,
    designs, per-method per-seed results (``seconds``, ``fit``: parameter -> (value, lo, hi)) and cpu.
    ``spread``: the designs' prior range factor (default that of ``bench plan --design``; 1: at the
    guess alone).

    Raises :class:`InputError` (one line) for an unknown family, no free parameter, no seed, an
    unknown method, or a bench that refuses points of the uniform plan."""
    from bench.config import load_bench
    from bench.identify.design import design_for_bench, integration_choices
    from bench.identify.design_io import model_point
    from bench.identify.design_sequential import sequential_scan
    from bench.identify.model_spec import parse_model_spec
    from bench.identify.time_model import ReadingSettings, bench_time_model, candidate_grid, plan_of_points, reachable
    from bench.machine import cpu_info
    from bench.plans import load_plan, refusal_message, refusals
    from bench.runner import run_scan
    from bench.store import RunStore

    say = progress or (lambda text: log.info("%s", text))
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise InputError("the design study needs at least 1 seed")
    methods = parse_methods(",".join(methods))
    spec = parse_model_spec(model)
    point = model_point(spec, prior) if spread is None else model_point(spec, prior, spread)
    specimen = str(description.get("specimen", {}).get("spec", ""))
    truth = truth_of(spec, specimen) if specimen else None
    uniform = load_plan(UNIFORM)
    half = _uniform_half()
    like = ReadingSettings.like(uniform)
    settings = integration_choices(like, INTEGRATIONS)
    results: dict[str, list[dict[str, Any]]] = {}
    designs: dict[str, Any] = {}
    kind = None
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            with load_bench(_seeded(description, seed), seed=seed, body=body) as bench, \
                    RunStore(Path(tmp) / f"runs-{seed}.sqlite") as store:
                kind = bench.kind
                refused = refusals(uniform, bench.goniometer.check)
                if refused:
                    raise InputError(f"bench {bench.name!r} refuses the uniform plan: {refusal_message(uniform, refused)}")
                times = bench_time_model(bench, like)
                budget = times.seconds(list(uniform.points))["seconds"]
                # the candidates bench plan --design takes: none the detector saturates at the shortest
                # integration (each longer one the design tries leaves out more)
                candidates = reachable(candidate_grid(), bench.goniometer.check, settings[0], bench.config,
                                       min(INTEGRATIONS))
                if not designs:  # the prior's designs do not depend on the seed
                    for key, (share, crit) in _DESIGNED.items():
                        if key in methods:
                            say(f"designing {METHODS[key]} ({budget * share:.3g} s)")
                            designs[METHODS[key]] = design_for_bench(point, bench, candidates, budget * share,
                                                                     settings, crit)
                plans = [("uniform in-plane", uniform, budget)]
                if "uniform-half" in methods:
                    plans.append(("uniform, 10 deg", half, times.seconds(list(half.points))["seconds"]))
                plans += [(n, plan_of_points(x.points, x.settings, name=n.replace(" ", "-").replace(",", "")),
                           x.seconds) for n, x in designs.items()]
                for name, plan, seconds in plans:
                    say(f"seed {seed}: {name}")
                    run = run_scan(bench, plan, store, seed=seed)
                    est = _fit(model, [store.to_record(run.run_id)])
                    results.setdefault(name, []).append({"seed": seed, "seconds": seconds, "fit": est})
                if "sequential" in methods:
                    say(f"seed {seed}: sequential")
                    seq = sequential_scan(bench, store, spec, point, budget, settings, candidates, key=f"bench-{seed}",
                                        seed=seed)
                    est = {n: (seq.estimates[n], seq.intervals[n][0], seq.intervals[n][1]) for n in seq.estimates}
                    results.setdefault("sequential", []).append({"seed": seed, "seconds": seq.seconds, "fit": est,
                                                                 "steps": len(seq.runs)})
    return {"cpu": cpu_info(), "truth": truth, "model": spec.text, "specimen": specimen, "parameters": list(spec.names),
            "units": list(spec.units), "prior": dict(point.values), "bench": str(description.get("name", "?")),
            "body": kind, "seeds": seeds,
            "designs": {n: {"points": len(x.points), "integration_s": x.settings.integration_s,
                            "seconds": x.seconds, "predicted_widths": x.widths,
                            "prior_points": x.prior_points, "predicted_range": x.width_range} for n, x in designs.items()},
            "results": results}


def _widths(runs: Sequence[Mapping[str, Any]], p: str) -> list[float]:
    return [r["fit"][p][2] - r["fit"][p][1] for r in runs]


def rows(m: Mapping[str, Any]) -> list[dict[str, Any]]:
    """JSON rows: ``method``, ``seconds`` (median) with ``seconds_min``/``seconds_max``, and per
    parameter ``widths`` (median, min, max), ``ratio_to_uniform`` (of medians) and ``truth_in``
    (seeds whose interval holds the truth; None when the truth is unknown), ``seeds``."""
    params = list(m["parameters"])
    truth = m["truth"]
    ref = {p: statistics.median(_widths(m["results"]["uniform in-plane"], p)) for p in params}
    out = []
    for name, runs in m["results"].items():
        secs = [r["seconds"] for r in runs]
        row: dict[str, Any] = {"method": name, "seconds": statistics.median(secs), "seconds_min": min(secs),
                               "seconds_max": max(secs), "seeds": len(runs), "widths": {}, "ratio_to_uniform": {},
                               "truth_in": {}}
        for p in params:
            w = _widths(runs, p)
            row["widths"][p] = {"median": statistics.median(w), "min": min(w), "max": max(w)}
            row["ratio_to_uniform"][p] = statistics.median(w) / ref[p] if ref[p] > 0 else None
            row["truth_in"][p] = (None if truth is None else
                                  sum(r["fit"][p][1] <= truth[p] <= r["fit"][p][2] for r in runs))
        out.append(row)
    return out


def header(m: Mapping[str, Any]) -> list[str]:
    """The table's column names (see :func:`summary`)."""
    out = ["method", "bench s"]
    for p in m["parameters"]:
        out += [f"{p} width (median [range])", f"{p} / uniform", f"{p} truth in"]
    return out


def summary(m: Mapping[str, Any]) -> list[list[Any]]:
    """Rows: method, bench s, then per parameter median width [range], ratio to uniform, truth hits."""
    out = []
    for r in rows(m):
        row: list[Any] = [r["method"], r["seconds"]]
        for p in m["parameters"]:
            w, ratio, hits = r["widths"][p], r["ratio_to_uniform"][p], r["truth_in"][p]
            row += [f"{w['median']:.3g} [{w['min']:.3g}, {w['max']:.3g}]",
                    "n/a" if ratio is None else f"{ratio:.2f}", "n/a" if hits is None else f"{hits}/{r['seeds']}"]
        out.append(row)
    return out


def describe(m: Mapping[str, Any]) -> str:
    """One line: model, truth, bench, body, seeds, CPU (the plot's title and the table's heading)."""
    truth = m["truth"]
    said = ", ".join(f"{k}={v:g}" for k, v in truth.items()) if truth else f"unknown ({m['specimen'] or 'no specimen'})"
    return (f"{m['model']} on bench {m['bench']} ({m['body']} body), truth {said}, seeds "
            f"{','.join(map(str, m['seeds']))}, CPU {m['cpu'].get('model', '?')}")


def plot_study(m: Mapping[str, Any], path: str | Path) -> Figure:
    """One panel per free parameter: 95 % interval width (log when they span a factor > 3) against bench minutes, one marker per
    method at the median over seeds, bars the seeds' range on both axes, legend below. Returns the
    saved figure (closed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params, units = list(m["parameters"]), list(m["units"])
    table = rows(m)
    fig, axes = plt.subplots(1, len(params), figsize=(4.8 * len(params), 4.4), squeeze=False, layout="constrained")
    markers = "osD^v<>ph*"
    tab10 = plt.get_cmap("tab10")
    colours = [tab10(k) for k in range(tab10.N)]
    for ax, p, unit in zip(axes.flat, params, units):
        for k, r in enumerate(table):
            x, w = r["seconds"] / 60.0, r["widths"][p]
            ax.errorbar([x], [w["median"]], xerr=[[x - r["seconds_min"] / 60.0], [r["seconds_max"] / 60.0 - x]],
                        yerr=[[w["median"] - w["min"]], [w["max"] - w["median"]]], fmt=markers[k % len(markers)],
                        color=colours[k % len(colours)], ms=7, capsize=3, label=r["method"])
        truth = m["truth"]
        span = [v for r in table for v in (r["widths"][p]["min"], r["widths"][p]["max"])]
        if min(span) > 0 and max(span) / min(span) > 3:  # log y only when the widths span a factor > 3
            ax.set_yscale("log")
        ax.set_xlabel("bench time, as `bench plan` estimates it (min)")
        ax.set_ylabel(f"95 % interval width of {p} ({unit or '1'})")
        ax.set_title(p + (f" (truth {truth[p]:g})" if truth else ""), fontsize=9)
        ax.set_xlim(left=0)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 3), fontsize=8,
               title=f"method: median over {len(m['seeds'])} seed(s); bars: the seeds' range", title_fontsize=8)
    fig.suptitle("Accuracy per bench-minute: " + describe(m), fontsize=9, wrap=True)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return fig
