"""Sequential design: measure a small designed plan, fit, re-design from the estimate, repeat.

``bench scan --sequential MODEL --budget-seconds S`` runs :func:`sequential_scan`: the first step spends a
share of the budget on a design at the prior guess; every later step fits all the readings so
far (:func:`fit_readings`: ``bench fit``'s likelihood, the readings' full covariance), designs
the next plan at that estimate with the points already measured counted in the information, and
scans it. It stops when the
budget (bench seconds as ``bench plan`` estimates them) is spent or every targeted parameter's
interval is narrower than its target.

Every step is an ordinary scan run in the store, named ``sequential-KEY-STEP`` (``KEY`` digests
the model, bench, budget and options). Run again with the same arguments after a kill, it reuses
the completed steps, finishes an interrupted one as ``bench resume`` would, and carries on: the
next designs depend only on the stored readings, so the continuation is the same.

The loop is :class:`SequentialSession`'s step function (``next_step``: the next plan or ``None`` to
stop; ``add``: a measured step's record, fitted with all before it), which the Bluesky plan
``bench.bluesky.plans.sequential_fit`` drives on a RunEngine the same way.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Callable, Any, Mapping, Sequence

import pandas as pd

from bench.core.errors import InputError
from bench.core.geometry import Geometry
from bench.config import Bench
from bench.core.records import BSDFRecord
from bench.identify.design import ModelPoint, design_for_bench
from bench.identify.design_io import parse_values
from bench.identify.fit import FitResult, fit_record
from bench.identify.model_spec import ModelSpec
from bench.plans import Plan
from bench.store import RunStore
from bench.identify.time_model import ReadingSettings, candidate_grid, plan_of_points, reachable

__all__ = ["SequentialStep", "SequentialResult", "SequentialSession", "NextStep", "sequential_scan", "parse_targets",
           "session_key", "session_candidates", "stored_steps", "combined_record", "fit_readings"]

#: share of the budget the first (prior-guess) design spends; the rest is split over later steps
FIRST_SHARE = 0.4
#: steps after the first, at most
LATER_STEPS = 2


@dataclass
class SequentialStep:
    """One step: its run, the bench seconds its plan was estimated at, and the fit after it."""

    run_id: str
    seconds: float
    points: int
    estimates: dict[str, float]
    widths: dict[str, float]


@dataclass
class SequentialResult:
    """What ``bench scan --sequential`` reports (``--json``: these keys)."""

    runs: list[str]
    seconds: float
    budget_s: float
    stopped: str  # "budget" or "target"
    estimates: dict[str, float]
    intervals: dict[str, list[float]]
    widths: dict[str, float]
    steps: list[SequentialStep] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {"runs": self.runs, "seconds": self.seconds, "budget_s": self.budget_s, "stopped": self.stopped,
                "estimates": self.estimates, "intervals": self.intervals, "widths": self.widths,
                "steps": [s.__dict__ for s in self.steps]}


def parse_targets(text: str | None, free: Sequence[str],
                  canonical: Callable[[str], str | None] | None = None) -> dict[str, float]:
    """``--target p=width,...`` -> {p: width}: each a free parameter (by its declared name or, with
    ``canonical``, an alias of it, keyed by the declared name) with a width > 0."""
    out = {}
    for key, width in parse_values(text, "--target", "WIDTH", positive=True).items():
        name = (canonical(key) if canonical is not None else None) or key
        if name not in free:
            raise InputError(f"--target {key}={width:g}: {key} is not a free parameter (free: {', '.join(free)})")
        out[name] = width
    return out


def session_key(*parts: Any) -> str:
    """A short digest naming a sequential session's runs."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:10]


def _run_scoped(budget: Any, run: int) -> Any:
    """A reading's budget with the inputs its run alone shares (white reading, darks) keyed to
    that run; the white standard's certificate stays one quantity for every run (one standard)."""
    from bench.core.budget import WHITE_CERTIFICATE

    b = json.loads(budget) if isinstance(budget, str) else budget
    if not isinstance(b, Mapping) or not b.get("components"):
        return budget
    comps = [c if c.get("shared") is None or c.get("name") == WHITE_CERTIFICATE
             else {**c, "shared": f"run {run}: {c['shared']}"} for c in b["components"]]
    return {**b, "components": comps}


def combined_record(records: Sequence[BSDFRecord]) -> BSDFRecord:
    """The readings of several runs as one record (the first run's metadata); their budgets'
    run-scoped shared inputs (each run's white reading and darks) kept apart, the white
    standard's certificate shared by all."""
    tables = []
    for i, r in enumerate(records):
        t = r.table
        if "uncertainty_budget" in t.columns:
            t = t.assign(uncertainty_budget=[_run_scoped(b, i) for b in t["uncertainty_budget"]])
        tables.append(t)
    return BSDFRecord(pd.concat(tables, ignore_index=True), dict(records[0].meta))


def fit_readings(spec: str | ModelSpec, records: Sequence[BSDFRecord]) -> FitResult:
    """Fit ``spec`` to the readings of ``records`` as ``bench fit`` does (Hessian intervals): with
    the readings' full covariance from their budgets, the white standard's certificate one error
    common to every reading of every step (as the design's information counts it)."""
    record = combined_record(records)
    return fit_record(record, spec, interval="hessian")


def session_candidates(bench: Bench, step_deg: float, settings: Sequence[ReadingSettings]) -> list[Geometry]:
    """The in-plane candidate grid (``--step``) minus every point ``bench`` refuses."""
    candidates = reachable(candidate_grid(step_deg), bench.goniometer.check, settings[0], bench.config,
                           max(s.integration_s for s in settings))  # nor one the detector would saturate at
    if not candidates:
        raise InputError(f"bench {bench.name!r} refuses every point of the in-plane candidate grid")
    return candidates


def stored_steps(store: RunStore, prefix: str) -> dict[int, dict[str, Any]]:
    """The runs of a session already in ``store`` (plan named ``PREFIX + step``), by step; of
    several runs of one step (a step measured again after an interrupted run), the completed one,
    else the latest."""
    out: dict[int, dict[str, Any]] = {}
    for r in store.runs():
        info = store.run(r["run_id"])
        name = str((info.get("plan") or {}).get("name", ""))
        if not name.startswith(prefix) or not name[len(prefix):].isdigit():
            continue
        k = int(name[len(prefix):])
        if k not in out or out[k]["status"] != "completed":
            out[k] = info
    return out


@dataclass
class NextStep:
    """What :meth:`SequentialSession.next_step` asks to measure: step ``number``'s ``points`` read
    with ``settings`` (as the ``plan`` named ``sequential-KEY-NUMBER``), designed at ``designed_at``
    for ``budget_s`` bench seconds; ``stored`` is the session's stored run of this step, if any
    (its plan is reused, not designed again)."""

    number: int
    budget_s: float
    designed_at: dict[str, float]
    points: list[Geometry]
    settings: ReadingSettings
    plan: Plan
    stored: dict[str, Any] | None = None


class SequentialSession:
    """The sequential design's state and its one step function, shared by ``bench scan
    --sequential`` (:func:`sequential_scan`) and the Bluesky plan ``bench.bluesky.plans.sequential_fit``.

    Loop: ``step = session.next_step(...)``; ``None`` means stop (budget spent, targets reached,
    or what is left of the budget buys no informative point); else measure ``step.plan`` and hand
    its record to :meth:`add`, which fits every reading so far and decides on the targets.
    """

    def __init__(self, bench: Bench, spec: ModelSpec, prior: ModelPoint, seconds: float, settings: Sequence[ReadingSettings],
                 candidates: Sequence[Geometry], criterion: str = "D", targets: Mapping[str, float] | None = None,
                 key: str = "") -> None:
        self.bench, self.spec, self.prior, self.seconds = bench, spec, prior, float(seconds)
        self.candidates, self.criterion, self.targets = list(candidates), criterion, dict(targets or {})
        self.prefix = f"sequential-{key}-"
        self.point = prior
        self.settings = list(settings)
        self.spent = 0.0
        self.stopped = "budget"
        self.fit: FitResult | None = None
        self.records: list[BSDFRecord] = []
        self.measured: list[Geometry] = []
        self.steps: list[SequentialStep] = []

    @property
    def number(self) -> int:
        """The number of the next step (steps measured so far)."""
        return len(self.steps)

    def next_step(self, stored: Mapping[str, Any] | None = None) -> NextStep | None:
        """The next step to measure, or ``None`` to stop. ``stored``: the session's stored run of
        this step (:func:`stored_steps`), whose plan is then taken as it is."""
        k = self.number
        if self.stopped == "target" or k > LATER_STEPS:
            return None
        remaining = self.seconds - self.spent
        budget = remaining * (FIRST_SHARE if k == 0 else 1.0 / (1 + LATER_STEPS - k))
        designed_at = {n: float(self.point.values[n]) for n in self.point.free}
        if stored is not None:
            table = stored["plan"]
            points = [Geometry(*p) for p in table["points"]]
            settings = ReadingSettings(table["integration_s"], table["averages"], table["dark"], table["white"],
                                       table.get("white_repeats"))
        else:
            try:
                design = design_for_bench(self.point, self.bench, self.candidates, budget, self.settings,
                                          self.criterion, seed_points=self.measured)
            except InputError:
                if k == 0:
                    raise
                return None  # what is left buys no informative point
            points, settings = list(design.points), design.settings
        plan = plan_of_points(points, settings, name=f"{self.prefix}{k}",
                              description=f"sequential step {k} for {self.spec.text}: designed at "
                              + ",".join(f"{n}={v:g}" for n, v in self.point.values.items()))
        return NextStep(k, budget, designed_at, points, settings, plan, None if stored is None else dict(stored))

    def add(self, step: NextStep, run_id: str, record: BSDFRecord) -> SequentialStep:
        """Step ``step`` measured as run ``run_id`` (its readings ``record``): fit every reading so
        far, and stop at the targets or re-centre the next design on the estimate."""
        self.settings = [step.settings]  # later steps read as the first design chose
        step_seconds = float(_time_of(self.bench, step.settings, step.points))
        self.spent += step_seconds
        self.measured += list(step.points)
        self.records.append(record)
        self.fit = fit = fit_readings(self.spec, self.records)
        estimates = {n: e.value for n, e in fit.parameters.items()}
        widths = {n: e.ci[1] - e.ci[0] for n, e in fit.parameters.items()}
        done = SequentialStep(run_id, step_seconds, len(step.points), estimates, widths)
        self.steps.append(done)
        if self.targets and all(widths[n] <= w for n, w in self.targets.items()):
            self.stopped = "target"
        else:
            self.point = ModelPoint(self.prior.family, {**self.prior.values, **_inside(estimates, self.spec)},
                                    self.prior.free)
        return done

    def result(self) -> SequentialResult:
        """What the session found so far (after at least one step)."""
        fit = self.fit
        assert fit is not None
        return SequentialResult([s.run_id for s in self.steps], self.spent, self.seconds, self.stopped,
                              {n: e.value for n, e in fit.parameters.items()},
                              {n: [e.ci[0], e.ci[1]] for n, e in fit.parameters.items()},
                              {n: e.ci[1] - e.ci[0] for n, e in fit.parameters.items()}, list(self.steps))


def sequential_scan(bench: Bench, store: RunStore, spec: ModelSpec, prior: ModelPoint, seconds: float,
                  settings: Sequence[ReadingSettings], candidates: Sequence[Geometry], criterion: str = "D",
                  targets: Mapping[str, float] | None = None, seed: int | None = None, key: str = "",
                  progress: bool = False) -> SequentialResult:
    """Run the sequential design (see the module docstring) on an open ``bench`` into ``store``."""
    from bench.runner import resume_scan, run_scan

    session = SequentialSession(bench, spec, prior, seconds, settings, candidates, criterion, targets, key)
    done = stored_steps(store, session.prefix)
    while (step := session.next_step(done.get(session.number))) is not None:
        if step.stored is not None:  # a step of this session already in the store: finish it if interrupted
            run_id = step.stored["run_id"]
            if step.stored["status"] != "completed":
                resume_scan(bench, store, run_id, progress=progress)
        else:
            run_id = run_scan(bench, step.plan, store, seed=seed, progress=progress).run_id
        session.add(step, run_id, store.to_record(run_id))
    return session.result()


def _inside(values: Mapping[str, float], spec: ModelSpec) -> dict[str, float]:
    """Estimates kept strictly inside the model's bounds (a design needs derivatives both ways)."""
    out = {}
    for p in spec.free:
        margin = 1e-3 * (p.hi - p.lo)
        out[p.name] = min(max(float(values[p.name]), p.lo + margin), p.hi - margin)
    return out


def _time_of(bench: Bench, settings: ReadingSettings, points: Sequence[Geometry]) -> float:
    from bench.identify.time_model import bench_time_model

    return bench_time_model(bench, settings).seconds(points)["seconds"]

