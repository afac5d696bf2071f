"""Sequential design: measure a small designed plan, fit, re-design from the estimate, repeat.

``bench scan --adaptive MODEL --seconds S`` runs :func:`adaptive_scan`: the first step spends a
share of the budget on a design at the prior guess; every later step fits all the readings so
far (:func:`bench.identify.fit.fit_record` with the bench's likelihood,
:class:`bench.identify.design_likelihood.BenchReadings`), designs the next plan at that estimate
with the points already measured counted in the information, and scans it. It stops when the
budget (bench seconds as ``bench plan`` estimates them) is spent or every targeted parameter's
interval is narrower than its target.

Every step is an ordinary scan run in the store, named ``adaptive-KEY-STEP`` (``KEY`` digests
the model, bench, budget and options). Run again with the same arguments after a kill, it reuses
the completed steps, finishes an interrupted one as ``bench resume`` would, and carries on: the
next designs depend only on the stored readings, so the continuation is the same.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import pandas as pd

from bench.core.errors import InputError
from bench.core.geometry import Geometry
from bench.core.records import BSDFRecord
from bench.identify.design import ModelPoint, design_for_bench
from bench.identify.design_io import parse_values
from bench.identify.design_likelihood import bench_likelihood
from bench.identify.time_model import ReadingSettings, plan_of_points

__all__ = ["AdaptiveStep", "AdaptiveResult", "adaptive_scan", "parse_targets", "session_key", "combined_record",
           "fit_readings"]

#: share of the budget the first (prior-guess) design spends; the rest is split over later steps
FIRST_SHARE = 0.4
#: steps after the first, at most
LATER_STEPS = 2


@dataclass
class AdaptiveStep:
    """One step: its run, the bench seconds its plan was estimated at, and the fit after it."""

    run_id: str
    seconds: float
    points: int
    estimates: dict[str, float]
    widths: dict[str, float]


@dataclass
class AdaptiveResult:
    """What ``bench scan --adaptive`` reports (``--json``: these keys)."""

    runs: list[str]
    seconds: float
    budget_s: float
    stopped: str  # "budget" or "target"
    estimates: dict[str, float]
    intervals: dict[str, list[float]]
    widths: dict[str, float]
    steps: list[AdaptiveStep] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {"runs": self.runs, "seconds": self.seconds, "budget_s": self.budget_s, "stopped": self.stopped,
                "estimates": self.estimates, "intervals": self.intervals, "widths": self.widths,
                "steps": [s.__dict__ for s in self.steps]}


def parse_targets(text: str | None, free: Sequence[str]) -> dict[str, float]:
    """``--target p=width,...`` -> {p: width}: each a free parameter with a width > 0."""
    out = parse_values(text, "--target", "WIDTH", positive=True)
    for key in out:
        if key not in free:
            raise InputError(f"--target {key}={out[key]:g}: {key} is not a free parameter (free: {', '.join(free)})")
    return out


def session_key(*parts: Any) -> str:
    """A short digest naming an adaptive session's runs."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:10]


def combined_record(records: Sequence[BSDFRecord]) -> BSDFRecord:
    """The readings of several runs as one record (the first run's metadata)."""
    table = pd.concat([r.table for r in records], ignore_index=True)
    return BSDFRecord(table, dict(records[0].meta))


def fit_readings(spec: Any, records: Sequence[BSDFRecord], description: Mapping[str, Any]) -> Any:
    """Fit ``spec`` to the readings of ``records`` with the bench's likelihood (Hessian intervals)."""
    from bench.identify.fit import fit_record

    record = combined_record(records)
    return fit_record(record, spec, interval="hessian", likelihood=bench_likelihood(record, description))


def _existing(store: Any, prefix: str) -> dict[int, dict[str, Any]]:
    out: dict[int, dict[str, Any]] = {}
    for r in store.runs():
        info = store.run(r["run_id"])
        name = str((info.get("plan") or {}).get("name", ""))
        if name.startswith(prefix):
            out[int(name[len(prefix):])] = info
    return out


def adaptive_scan(bench: Any, store: Any, spec: Any, prior: ModelPoint, seconds: float,
                  settings: Sequence[ReadingSettings], candidates: Sequence[Geometry], criterion: str = "D",
                  targets: Mapping[str, float] | None = None, seed: int | None = None, key: str = "",
                  progress: bool = False) -> AdaptiveResult:
    """Run the sequential design (see the module docstring) on an open ``bench`` into ``store``."""
    from bench.runner import resume_scan, run_scan

    targets = dict(targets or {})
    prefix = f"adaptive-{key}-"
    done = _existing(store, prefix)
    records: list[BSDFRecord] = []
    measured: list[Geometry] = []
    steps: list[AdaptiveStep] = []
    point, spent, stopped, fit = prior, 0.0, "budget", None
    chosen_settings = list(settings)
    for k in range(1 + LATER_STEPS):
        remaining = seconds - spent
        budget = remaining * (FIRST_SHARE if k == 0 else 1.0 / (1 + LATER_STEPS - k))
        if k in done:  # a step of this session already in the store: finish it if interrupted
            info = done[k]
            plan_table = info["plan"]
            run_id = info["run_id"]
            if info["status"] != "completed":
                resume_scan(bench, store, run_id, progress=progress)
            step_points = [Geometry(*p) for p in plan_table["points"]]
            step_settings = ReadingSettings(plan_table["integration_s"], plan_table["averages"], plan_table["dark"],
                                            plan_table["white"])
        else:
            try:
                design = design_for_bench(point, bench, candidates, budget, chosen_settings, criterion,
                                          seed_points=measured)
            except InputError:
                if k == 0:
                    raise
                break  # what is left buys no informative point
            step_points, step_settings = design.points, design.settings
            plan = plan_of_points(step_points, step_settings, name=f"{prefix}{k}",
                                  description=f"adaptive step {k} for {spec.text}: designed at "
                                  + ",".join(f"{n}={v:g}" for n, v in point.values.items()))
            run_id = run_scan(bench, plan, store, seed=seed, progress=progress).run_id
        chosen_settings = [step_settings]  # later steps read as the first design chose
        step_seconds = float(_time_of(bench, step_settings, step_points))
        spent += step_seconds
        measured += list(step_points)
        records.append(store.to_record(run_id))
        fit = fit_readings(spec, records, bench.config)
        estimates = {n: e.value for n, e in fit.parameters.items()}
        widths = {n: e.ci[1] - e.ci[0] for n, e in fit.parameters.items()}
        steps.append(AdaptiveStep(run_id, step_seconds, len(step_points), estimates, widths))
        if targets and all(widths[n] <= w for n, w in targets.items()):
            stopped = "target"
            break
        point = ModelPoint(prior.family, {**prior.values, **_inside(estimates, spec)}, prior.free)
    assert fit is not None
    return AdaptiveResult([s.run_id for s in steps], spent, seconds, stopped,
                          {n: e.value for n, e in fit.parameters.items()},
                          {n: [e.ci[0], e.ci[1]] for n, e in fit.parameters.items()},
                          {n: e.ci[1] - e.ci[0] for n, e in fit.parameters.items()}, steps)


def _inside(values: Mapping[str, float], spec: Any) -> dict[str, float]:
    """Estimates kept strictly inside the model's bounds (a design needs derivatives both ways)."""
    out = {}
    for p in spec.free:
        margin = 1e-3 * (p.hi - p.lo)
        out[p.name] = min(max(float(values[p.name]), p.lo + margin), p.hi - margin)
    return out


def _time_of(bench: Any, settings: ReadingSettings, points: Sequence[Geometry]) -> float:
    from bench.identify.time_model import bench_time_model

    return bench_time_model(bench, settings).seconds(points)["seconds"]

