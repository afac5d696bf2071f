"""Our plans as Bluesky plans: ``plan_from_toml(PLAN_TOML, devices)`` and the sequential design
``sequential_fit(MODEL, devices, seconds=S, store=STORE)``.

:func:`plan_from_toml`: the plan is read and validated whole against the bench's safety rules
*before* the generator is returned (the same :class:`~bench.core.errors.PlanError` as ``bench
plan`` / ``bench scan``, naming every refused point), ordered as our runner orders it
(:func:`bench.plans.order_for_travel` unless ``order = "as-given"``), and run as: set the
reflectance detector's reading settings from the plan, stage (white and dark references, as
``bench scan`` measures them), open the run, then per point a checkpoint, one coalesced move of
the whole geometry and ONE event with the goniometer read-back and the detectors.

:func:`sequential_fit`: ``bench scan --sequential`` on a RunEngine, one run per step, through the same
step function (:class:`bench.identify.design_sequential.SequentialSession`).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp

from bench.bluesky.connect import METADATA_KEY, PLAN_KEY, Devices, jsonable
from bench.bluesky.store_writer import StoreWriter
from bench.core.errors import InputError
from bench.identify.design import CRITERIA
from bench.identify.design_io import design_inputs
from bench.identify.design_sequential import (SequentialSession, NextStep, parse_targets, session_candidates, session_key,
                                              stored_steps)
from bench.identify.time_model import DEFAULT_INTEGRATIONS, DEFAULT_STEP_DEG
from bench.plans import Plan, load_plan, order_for_travel, plan_from_dict, validate
from bench.store import RunStore

__all__ = ["plan_from_toml", "sequential_fit", "PLAN_KEY", "SEQUENTIAL_KEY", "FIT_STREAM"]

#: the start-document key of a :func:`sequential_fit` step (session, step, model, criterion, ...)
SEQUENTIAL_KEY = "goniobench_sequential"
#: the stream of each :func:`sequential_fit` run's last event: the fit of every reading so far
FIT_STREAM = "fit"


def _plan(plan: str | Path | Mapping[str, Any] | Plan) -> Plan:
    if isinstance(plan, Plan):
        return plan
    if isinstance(plan, Mapping):
        return plan_from_dict(plan, name=str(plan.get("name", "plan")))
    return load_plan(plan)


def plan_from_toml(plan: str | Path | Mapping[str, Any] | Plan, devices: Devices, *,
                   detectors: Iterable[Any] | None = None, md: Mapping[str, Any] | None = None) -> Any:
    """A Bluesky plan measuring ``plan`` (a plan TOML, its dict or a :class:`Plan`) on ``devices``.

    Parameters
    ----------
    plan : path, mapping or Plan
    devices : Devices
        From :func:`bench.bluesky.connect`.
    detectors : iterable of devices, optional
        Default ``[devices.reflectance]``; ``devices.spectrometer`` may be added.
    md : mapping, optional
        Extra start-document metadata.

    Raises
    ------
    PlanError
        At once (before the RunEngine sees anything) if any point is refused.
    """
    return _measure(_plan(plan), devices, detectors, md)


def _measure(p: Plan, devices: Devices, detectors: Iterable[Any] | None, md: Mapping[str, Any] | None,
             after: Callable[[], Any] | None = None) -> Any:
    """:func:`plan_from_toml`'s plan; ``after()`` (a plan) runs inside the run after the last point."""
    validate(p, devices.bench.goniometer.check)  # the whole plan, before any motion
    order = order_for_travel(p.points) if p.order == "travel" else list(range(len(p.points)))
    dets = list(detectors) if detectors is not None else [devices.reflectance]
    axes = list(devices.goniometer.axes.values())
    meta = {"plan_name": "goniobench_plan", "num_points": len(order),
            "detectors": [d.name for d in dets], "motors": [a.name for a in axes],
            "plan_args": {"plan": p.name, "kind": p.kind},
            "hints": {"dimensions": [([a.name for a in axes], "primary")]},
            PLAN_KEY: {"name": p.name, "plan": p.as_dict(), "order": order, "n_planned": len(order)},
            **dict(md or {})}
    settings: list[Any] = []
    for det in dets:
        for key in ("integration_s", "averages"):
            if hasattr(det, key):
                settings += [getattr(det, key), getattr(p, key)]
    refl = devices.reflectance
    if refl in dets:
        settings += [refl.dark_mode, p.dark, refl.white_mode, p.white]

    @bpp.stage_decorator(dets)
    @bpp.run_decorator(md=meta)
    def measure() -> Any:
        for idx in order:
            yield from bps.checkpoint()
            yield from bps.mv(devices.goniometer, p.points[idx])
            yield from bps.trigger_and_read([devices.goniometer, *dets])
        if after is not None:
            yield from after()

    def whole() -> Any:
        yield from bps.mv(*settings)
        return (yield from measure())

    return whole()


class _Readout:
    """A Readable of fixed values, read once as the event of stream :data:`FIT_STREAM`."""

    def __init__(self, name: str, values: Mapping[str, Any]) -> None:
        self.name, self.parent, self._values, self._t = name, None, dict(values), time.time()

    @staticmethod
    def _dtype(v: Any) -> str:
        if isinstance(v, bool):
            return "boolean"
        if isinstance(v, int):
            return "integer"
        return "string" if isinstance(v, str) else "number"

    def describe(self) -> dict[str, dict[str, Any]]:
        return {f"{self.name}-{k}": {"source": "goniobench:sequential_fit", "dtype": self._dtype(v), "shape": []}
                for k, v in self._values.items()}

    def read(self) -> dict[str, dict[str, Any]]:
        return {f"{self.name}-{k}": {"value": v, "timestamp": self._t} for k, v in self._values.items()}


def _fit_values(session: SequentialSession, stopped: str) -> dict[str, Any]:
    """The event of stream ``fit``: bench fit's document of every reading so far, flat."""
    fit = session.fit
    out: dict[str, Any] = {"model": fit.model, "step": session.number - 1, "seconds": session.spent,
                           "stopped": stopped}
    for n, e in fit.parameters.items():
        out.update({n: float(e.value), f"{n}_lo": float(e.ci[0]), f"{n}_hi": float(e.ci[1]),
                    f"{n}_width": float(e.ci[1] - e.ci[0])})
    out.update({"chi2": float(fit.chi2), "dof": int(fit.dof), "p_value": float(fit.p_value),
                "json": json.dumps(jsonable(fit.to_json()))})
    return out


def _text(values: str | Mapping[str, float] | None) -> str | None:
    if values is None or isinstance(values, str):
        return values
    return ",".join(f"{k}={float(v)!r}" for k, v in values.items())


def sequential_fit(model: str, devices: Devices, *, seconds: float, store: str | Path,
                 target: str | Mapping[str, float] | None = None, prior: str | Mapping[str, float] | None = None,
                 criterion: str = "D", integration_s: str | Sequence[float] = DEFAULT_INTEGRATIONS,
                 like: str | Path | None = None, step: float = DEFAULT_STEP_DEG,
                 md: Mapping[str, Any] | None = None) -> Any:
    """``bench scan --sequential`` as a Bluesky plan: measure a design, fit, re-design, repeat.

    The same session as the CLI's (:class:`~bench.identify.design_sequential.SequentialSession`, one
    step function): a first design at the prior spends 40 % of ``seconds`` (bench seconds as ``bench
    plan`` estimates them), each later step fits every reading so far and designs at the estimate,
    until the budget is spent or every ``target`` width is reached. Each step is ONE run of
    :func:`plan_from_toml`'s plan for its points (calibration at stage, one event per point),
    written into ``store`` by a :class:`~bench.bluesky.StoreWriter` the plan subscribes itself (do
    not subscribe another one to the same store). Its start document says under
    :data:`SEQUENTIAL_KEY` the ``session``, ``step``, ``model``, ``criterion``, ``designed_at`` (the
    prior or estimate it was designed at), ``budget_s`` and ``spent_s``; after its last point the
    run fits all readings so far and emits one event of stream ``fit``: ``fit-model``, ``fit-P``,
    ``fit-P_lo``, ``fit-P_hi``, ``fit-P_width`` per free parameter P (95 % Hessian intervals),
    ``fit-chi2``, ``fit-dof``, ``fit-p_value``, ``fit-json`` (``bench fit --json``'s document),
    ``fit-seconds`` spent and ``fit-stopped`` (``""`` while another step follows, else
    ``"budget"`` or ``"target"``). The plan returns the
    :class:`~bench.identify.design_sequential.SequentialResult` (``RE(..)`` with
    ``call_returns_result=True`` gives it as ``plan_result``).

    Resume: the runs are named ``sequential-KEY-STEP`` as the CLI's (``KEY`` digests the bench
    config, body, seed, model and every option here). Run again with the same arguments on the
    same store after a kill or an abort, the plan reuses every completed step from the store
    without measuring it, and measures an interrupted step again as a new run from its stored
    plan (the RunEngine cannot continue a run); the continuation is the one an uninterrupted
    session would have made. The design and fits run in the plan itself, between messages.

    Raises
    ------
    InputError
        At once (before the RunEngine sees anything): a bad model, prior, target, criterion or
        budget, a bench refusing every candidate, or a budget that buys no first design.
    """
    if not seconds > 0:
        raise InputError(f"sequential_fit: seconds must be > 0, got {seconds!r}")
    if criterion not in CRITERIA:
        raise InputError(f"sequential_fit: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    spec, point, settings = design_inputs(model, prior, like, integration_s)
    targets = parse_targets(_text(target), spec.names)
    bench = devices.bench
    key = session_key("bluesky", spec.text, bench.config, bench.kind, devices.seed, seconds, criterion, _text(prior),
                      integration_s, like, step, _text(target))
    session = SequentialSession(bench, spec, point, seconds, settings, session_candidates(bench, step, settings),
                              criterion, targets, key)
    with RunStore(store) as st:
        done = stored_steps(st, session.prefix)
    first = session.next_step(done.get(0))  # the first design, before the RunEngine sees anything
    writer = StoreWriter(store)
    args = {"model": spec.text, "seconds": seconds, "criterion": criterion, "target": targets,
            "prior": {n: point.values[n] for n in point.free}, "step": step}

    def measure(s: NextStep) -> Any:
        state: dict[str, Any] = {}

        def fit() -> Any:  # inside the run, after its last point: fit, decide, say so in one event
            run_id = writer.run_ids[-1]
            with RunStore(store) as st:
                record = st.to_record(run_id)
            session.add(s, run_id, record)
            state["next"] = session.next_step(done.get(session.number))
            readout = _Readout(FIT_STREAM, _fit_values(session, "" if state["next"] is not None else session.stopped))
            yield from bps.create(FIT_STREAM)
            yield from bps.read(readout)
            yield from bps.save()

        meta = {"plan_name": "sequential_fit", "plan_args": args, METADATA_KEY: devices.metadata,
                SEQUENTIAL_KEY: {"session": key, "step": s.number, "model": spec.text, "criterion": criterion,
                               "designed_at": s.designed_at, "budget_s": s.budget_s, "seconds": seconds,
                               "spent_s": session.spent, "targets": targets,
                               "replanned": s.stored is not None},
                **dict(md or {})}
        yield from _measure(s.plan, devices, [devices.reflectance], jsonable(meta), after=fit)
        return state["next"]

    def steps() -> Any:
        s = first
        while s is not None:
            if s.stored is not None and s.stored["status"] == "completed":  # reused from the store
                with RunStore(store) as st:
                    session.add(s, s.stored["run_id"], st.to_record(s.stored["run_id"]))
                s = session.next_step(done.get(session.number))
            else:
                s = yield from measure(s)
        return session.result()

    return bpp.subs_wrapper(steps(), {"all": [writer]})
