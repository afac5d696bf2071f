"""``plan_from_toml(PLAN_TOML, devices)``: one of our scan plans as a Bluesky plan.

The plan is read and validated whole against the bench's safety rules *before* the generator
is returned (the same :class:`~bench.core.errors.PlanError` as ``bench plan`` / ``bench scan``,
naming every refused point), ordered as our runner orders it (:func:`bench.plans.order_for_travel`
unless ``order = "as-given"``), and run as: set the reflectance detector's reading settings from
the plan, stage (white and dark references, as ``bench scan`` measures them), open the run, then
per point a checkpoint, one coalesced move of the whole geometry and ONE event with the
goniometer read-back and the detectors.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp

from bench.bluesky.connect import Devices
from bench.plans import Plan, load_plan, order_for_travel, plan_from_dict, validate

__all__ = ["plan_from_toml", "PLAN_KEY"]

#: the start-document key describing our plan (its table, the order, points planned)
PLAN_KEY = "goniobench_plan"


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
    p = _plan(plan)
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

    def whole() -> Any:
        yield from bps.mv(*settings)
        return (yield from measure())

    return whole()
