"""Accuracy per bench-minute: fitted interval widths of the uniform in-plane plan, a designed plan and
the sequential design, on the emulated bench (real drivers over the wire emulators).

Specimen ``plastic:alpha=0.15,kd=0.5`` (eta = 1.5), model ``plastic:alpha=?,kd=?``. The designs
start from the family's declared defaults (alpha = 0.1, kd = 0.5) as the prior -- a guess, not the
truth; the sequential design corrects it from its own fits. Every plan is scanned on the emulated
body with emulator seeds 7, 8, 9 and fitted with the bench's likelihood
(:func:`bench.identify.design_likelihood.bench_likelihood`: the fit's Gaussian readings with the
detector aperture). Bench time is ``bench plan``'s estimate. Reported: median and range over the
seeds of each 95 % interval width, the ratio of medians to the uniform plan's, and in how many
seeds the interval contains the truth.

The designed plans are D-optimal (the default) unless named A-optimal.

``python -m benchmarks design`` (several CPU-minutes: 18 emulated scans and 24 fits).
"""

from __future__ import annotations

import copy
import logging
import statistics
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.common import cpu_info, table

log = logging.getLogger("benchmarks")

ROOT = Path(__file__).resolve().parent.parent
MODEL = "plastic:alpha=?,kd=?"
TRUTH = {"alpha": 0.15, "kd": 0.5}
SEEDS = (7, 8, 9)
UNIFORM = ROOT / "fixtures" / "plans" / "in-plane.toml"


def description(seed: int) -> dict[str, Any]:
    """The shipped emulated bench holding the benchmark's specimen, emulator seed ``seed``."""
    from bench.core.parsing import read_toml

    d = read_toml(ROOT / "fixtures" / "benches" / "emulated.toml", "bench config")
    d = copy.deepcopy(d)
    d["specimen"]["spec"] = "plastic:" + ",".join(f"{k}={v:g}" for k, v in TRUTH.items())
    d["emulated"]["seed"] = seed
    return d


def _fit(records: list[Any]) -> dict[str, tuple[float, float, float]]:
    from bench.identify.design_sequential import fit_readings

    fit = fit_readings(MODEL, records)
    return {n: (e.value, e.ci[0], e.ci[1]) for n, e in fit.parameters.items()}


def _uniform_half() -> Any:
    """The uniform in-plane plan at half the theta_r density (10 deg steps): about half its time."""
    from bench.core.parsing import read_toml
    from bench.plans import plan_from_dict

    t = read_toml(UNIFORM, "plan file")
    t["in_plane"]["theta_r"] = {"start": -20, "stop": 80, "step": 10}
    t["name"] = "in-plane-10deg"
    return plan_from_dict(t, name="in-plane-10deg")


def measure(seeds: tuple[int, ...] = SEEDS) -> dict[str, Any]:
    """Scan and fit every method on every seed; returns rows of per-seed results."""
    from bench.config import load_bench
    from bench.identify.design import design_for_bench, integration_choices
    from bench.identify.design_io import model_point
    from bench.identify.design_sequential import adaptive_scan
    from bench.identify.model_spec import parse_model_spec
    from bench.identify.time_model import ReadingSettings, bench_time_model, candidate_grid, plan_of_points, reachable
    from bench.plans import load_plan
    from bench.runner import run_scan
    from bench.store import RunStore

    spec = parse_model_spec(MODEL)
    prior = model_point(spec)  # the declared defaults: alpha 0.1, kd 0.5
    uniform = load_plan(UNIFORM)
    half = _uniform_half()
    settings = integration_choices(ReadingSettings.like(uniform), (0.005, 0.01, 0.02, 0.05))
    results: dict[str, list[dict[str, Any]]] = {}
    designs: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            d = description(seed)
            with load_bench(d) as bench, RunStore(Path(tmp) / f"runs-{seed}.sqlite") as store:
                like = ReadingSettings.like(uniform)
                budget = bench_time_model(bench, like).seconds(list(uniform.points))["seconds"]
                candidates = reachable(candidate_grid(), bench.goniometer.check, settings[0])
                if not designs:  # the prior's designs do not depend on the seed
                    for name, s, crit in (("designed", budget, "D"), ("designed, half time", budget / 2, "D"),
                                          ("designed, A-optimal", budget, "A")):
                        log.info("designing %s (%.3g s)", name, s)
                        designs[name] = design_for_bench(prior, bench, candidates, s, settings, crit)
                plans = [("uniform in-plane", uniform, budget),
                         ("uniform, 10 deg", half, bench_time_model(bench, like).seconds(list(half.points))["seconds"])]
                plans += [(n, plan_of_points(x.points, x.settings, name=n.replace(" ", "-").replace(",", "")),
                           x.seconds) for n, x in designs.items()]
                for name, plan, seconds in plans:
                    log.info("seed %d: %s", seed, name)
                    run = run_scan(bench, plan, store, seed=seed)
                    est = _fit([store.to_record(run.run_id)])
                    results.setdefault(name, []).append({"seed": seed, "seconds": seconds, "fit": est})
                log.info("seed %d: sequential", seed)
                seq = adaptive_scan(bench, store, spec, prior, budget, settings, candidates, key=f"bench-{seed}",
                                    seed=seed)
                est = {n: (seq.estimates[n], *seq.intervals[n]) for n in seq.estimates}
                results.setdefault("sequential", []).append({"seed": seed, "seconds": seq.seconds, "fit": est,
                                                             "steps": len(seq.runs)})
    return {"cpu": cpu_info(), "truth": TRUTH, "model": MODEL, "prior": dict(prior.values),
            "designs": {n: {"points": len(x.points), "integration_s": x.settings.integration_s,
                            "seconds": x.seconds, "predicted_widths": x.widths} for n, x in designs.items()},
            "results": results}


def summary(m: dict[str, Any]) -> list[list[Any]]:
    """Rows: method, bench s, then per parameter median width [range], ratio to uniform, truth hits."""
    rows = []
    ref = {p: statistics.median(r["fit"][p][2] - r["fit"][p][1] for r in m["results"]["uniform in-plane"])
           for p in TRUTH}
    for name, runs in m["results"].items():
        row: list[Any] = [name, statistics.median(r["seconds"] for r in runs)]
        for p, truth in TRUTH.items():
            w = [r["fit"][p][2] - r["fit"][p][1] for r in runs]
            hits = sum(r["fit"][p][1] <= truth <= r["fit"][p][2] for r in runs)
            row += [f"{statistics.median(w):.3g} [{min(w):.3g}, {max(w):.3g}]",
                    f"{statistics.median(w) / ref[p]:.2f}", f"{hits}/{len(runs)}"]
        rows.append(row)
    return rows


def run() -> str:
    m = measure()
    header = ["method", "bench s"]
    for p in TRUTH:
        header += [f"{p} width (median [range])", f"{p} / uniform", f"{p} truth in"]
    cpu = m["cpu"]
    title = (f"Accuracy per bench-minute, {MODEL} on the emulated bench, truth "
             f"{', '.join(f'{k}={v:g}' for k, v in TRUTH.items())}, prior {m['prior']}, seeds {list(SEEDS)} "
             f"({cpu.get('model', '?')})")
    notes = "\n".join(f"  {n}: {x['points']} points at {x['integration_s']:g} s, predicted widths "
                      + ", ".join(f"{k} {v:.3g}" for k, v in x["predicted_widths"].items())
                      for n, x in m["designs"].items())
    return table(title, header, summary(m)) + "\n" + notes
