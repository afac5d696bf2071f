"""``check_standards(BENCH, store=STORE)``: ``bench check`` as a Bluesky plan.

Each of the bench's ``[[check]]`` standards (or those named) is measured as ``bench check``
measures it (:mod:`bench.assurance`): its plan (:func:`~bench.assurance.check_plan`: its
geometries as given, one dark and one white, staged by the reflectance device as every plan of
:func:`~bench.bluesky.plans.plan_from_toml`), on the bench with the standard mounted
(:func:`~bench.assurance.check_description`), on the simulated day ``date`` (a declared
``[drift]``, :func:`bench.builders.drift.on_day`), every check refused before the RunEngine sees
anything. Each check is ONE Bluesky run, written into ``store`` by a
:class:`~bench.bluesky.StoreWriter` the plan subscribes itself as a run of kind ``check`` with
``meta["check"]`` as ``bench check`` stores it (check name, date, then its score: check value,
max |E_n|, agreement, masked readings), so ``bench chart``, the scan gate
(:func:`bench.assurance.gate`) and ``bench serve`` read it like any check run.

Mounting: the virtual and emulated bodies simulate the standard, so the plan connects one bench
per check from the description with the standard as its specimen (and closes it when the plan
ends), in the RunEngine's loop; the devices of the bench being checked only lend their
description, body, seed and loop. A real body cannot swap specimens by itself: it measures the
standard the operator mounted on the devices given, one check per call.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp

from bench.assurance import check_description, check_plan, checks_of, score, today
from bench.bluesky.connect import METADATA_KEY, Devices, connect, jsonable
from bench.bluesky.plans import _measure
from bench.bluesky.store_writer import RUN_KEY, StoreWriter
from bench.builders.drift import on_day
from bench.builders.instrument import declared_aperture
from bench.config import load_description
from bench.core.errors import InputError
from bench.plan_check import refuse_before_opening
from bench.plans import plan_from_dict
from bench.store import RunStore

__all__ = ["check_standards"]


class _Loop:
    """What :func:`~bench.bluesky.connect` needs of a RunEngine: its loop (and an ``md`` to set,
    unused: each check run names its bench in its own start document)."""

    def __init__(self, loop: Any) -> None:
        self.loop, self.md = loop, {}


def _date(date: str | None, body: str) -> str:
    if date is None:
        return today()
    if body == "real":
        raise InputError("check_standards: date simulates a day on the virtual or emulated body; a real bench "
                         "checks today")
    import datetime as dt

    try:
        return dt.date.fromisoformat(str(date)).isoformat()
    except ValueError:
        raise InputError(f"check_standards: date must be YYYY-MM-DD, got {date!r}") from None


def check_standards(bench: str | Path | Mapping[str, Any] | Devices, *, store: str | Path,
                    checks: Sequence[str] = (), seed: int | None = None, body: str | None = None,
                    date: str | None = None, run_engine: Any = None, md: Mapping[str, Any] | None = None) -> Any:
    """A Bluesky plan measuring the check standards of ``bench``, one run of kind ``check`` each.

    Parameters
    ----------
    bench : path, mapping or Devices
        The bench description (TOML or dict) declaring ``[[check]]`` tables, or the devices of
        :func:`~bench.bluesky.connect` (their description, body, seed and loop are used).
    store : path
        The run store the check runs are written into and scored from.
    checks : names, optional
        Measure only these (default: every declared check).
    seed, body : optional
        As ``bench check --seed/--body`` (ignored when ``bench`` is Devices: theirs).
    date : str, optional
        The simulated day (``YYYY-MM-DD``; virtual and emulated bodies); default today.
    run_engine : RunEngine, optional
        Whose loop the per-check benches connect in (default: the RunEngine created last).
    md : mapping, optional
        Extra start-document metadata.

    Returns
    -------
    generator
        The plan; it returns a list of ``bench check --json``'s ``checks`` entries (each
        reading's E_n, the check value, ``run`` and ``date``).

    Raises
    ------
    InputError, PlanError, ConfigError
        At once, before the RunEngine sees anything: no check declared or an unknown name, a
        standard the body cannot simulate (a certified value only), a check plan the bench
        refuses, several checks on a real body. While running: a check run that did not complete.
    """
    given = bench if isinstance(bench, Devices) else None
    if given is not None:
        d, kind, seed = dict(given.bench.config), given.bench.kind, given.seed
        loop = given.loop
    else:
        d, kind = load_description(bench, body)
        loop = None if run_engine is None else run_engine.loop
    on = _date(date, kind)
    source = "bench config" if given is not None or isinstance(bench, Mapping) else f"bench config {bench}"
    declared = checks_of(d, tuple(checks), source)
    d = on_day(d, on)
    plans = [(c, plan_from_dict(check_plan(c), name=f"check {c.name}"), check_description(d, c, kind))
             for c in declared]
    if kind == "real" and len(plans) != 1:
        raise InputError(f"check_standards: a real bench measures the one standard mounted on it; name it with "
                         f"checks=[...] (its checks: {', '.join(c.name for c in declared)})")
    for _, plan, described in plans:  # every check refused before anything is opened
        refuse_before_opening(plan, described, kind)
    opened: list[Devices] = []
    try:
        for _, _, described in plans:
            if kind == "real" and given is not None:
                opened.append(given)
            else:
                opened.append(connect(described, _Loop(loop) if loop is not None else run_engine, seed=seed,
                                      body=kind))
    except BaseException:
        for devs in opened:
            if devs is not given:
                devs.close()
        raise
    writer = StoreWriter(store)

    def measure() -> Any:
        out = []
        try:
            for (check, plan, described), devs in zip(plans, opened):
                meta = {"plan_name": "check_standards", "plan_args": {"check": check.name, "date": on},
                        METADATA_KEY: {**devs.metadata, "bench": described,  # the standard mounted
                                       "specimen": (described.get("specimen") or {}).get("spec")},
                        RUN_KEY: {"kind": "check", "meta": {"check": {"check": check.name, "date": on}}},
                        **dict(md or {})}
                # at the check's first geometry before staging: a fresh emulated arm is parked with
                # its detector in the beam, where no white can be returned from
                yield from bps.mv(devs.goniometer, plan.points[0])
                yield from _measure(plan, devs, [devs.reflectance], jsonable(meta))
                run_id = writer.run_ids[-1]
                with RunStore(store) as st:
                    info = st.run(run_id)
                    if info["status"] != "completed":
                        raise InputError(f"check {check.name!r}: run {run_id} {info['status']} ({info.get('reason')})")
                    scored = score(check, st.readings(run_id), declared_aperture(described) or 0.0)
                    st.update_meta(run_id, check={**{k: v for k, v in scored.items() if k != "readings"},
                                                  "date": on})
                out.append({**scored, "run": run_id, "date": on})
        finally:
            for devs in opened:
                if devs is not given:
                    devs.close()
        return out

    return bpp.subs_wrapper(measure(), {"all": [writer]})
