"""Measurement assurance: check standards measured on a schedule, their control charts, and the
gate a scan passes when the bench says how much it trusts itself (``assurance``).

A bench description declares its check standards (``[[check]]``,
:class:`bench.core.schemas.CheckTable`). :func:`measure_check` measures one with the plan
machinery (refusals, darks, white, budgets as every run) into a run of kind ``check``, and scores
each reading against the standard's reference as an E_n number (:func:`compare.control.en_numbers`);
the run's *check value* -- the mean of reading / reference over its unmasked readings -- is one
point of the chart :func:`check_chart` draws from the store (:func:`compare.control.chart`, the
Western Electric / Nelson rules). :func:`gate` is what ``bench scan`` asks first: the latest
check of each standard, whether it is overdue or out of control, and what the bench declared to
do about it (``warn`` or ``refuse``).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from bench.store import RunStore
from bench.core.errors import InputError
from bench.core.geometry import Geometry
from bench.core.schemas import BenchFile, CheckTable
from bench.core.validation import validate_document
from compare.control import Chart, chart, en_numbers

__all__ = ["checks_of", "check_plan", "check_description", "reference_values", "score", "check_history",
           "check_chart", "relied_charts", "Gate", "gate", "today"]


def today() -> str:
    """Today's date (UTC), ISO."""
    return dt.datetime.now(dt.timezone.utc).date().isoformat()


def checks_of(description: Mapping[str, Any], names: Sequence[str] = (), source: str = "bench config") -> list[CheckTable]:
    """The description's check standards (those named, in the bench file's order); one line when
    it declares none or a name is not among them."""
    bench = validate_document(BenchFile, dict(description), source)
    declared = list(bench.check)
    if not declared:
        raise InputError(f"{source} declares no check standard: add a [[check]] table (name, specimen or "
                         f"reference, geometries, every)")
    known = [c.name for c in declared]
    missing = [n for n in names if n not in known]
    if missing:
        raise InputError(f"{source} has no check named {missing[0]!r}; its checks: {', '.join(known)}")
    return [c for c in declared if not names or c.name in names]


def check_plan(check: CheckTable) -> dict[str, Any]:
    """The plan that measures ``check``: its geometries as given, one dark and one white."""
    return {"name": f"check {check.name}", "kind": "list", "points": [list(g) for g in check.geometries],
            "integration_s": check.integration_s, "averages": check.averages, "dark": "once", "white": "once",
            "order": "as-given"}


def check_description(description: Mapping[str, Any], check: CheckTable, body: str) -> dict[str, Any]:
    """The bench with the check standard mounted: its model as the specimen (what the virtual and
    emulated bodies simulate; on the real body the operator mounts it). A standard known only by
    its certified value cannot be simulated: refused in one line on those bodies."""
    d = dict(description)
    if check.specimen:
        d["specimen"] = {"spec": check.specimen, "name": check.name}
    elif body != "real":
        raise InputError(f"check {check.name!r} gives only a certified reference: the {body} body simulates a "
                         f"specimen model, so give the standard's model as specimen = \"...\"")
    return d


def reference_values(check: CheckTable, geometries: Sequence[Geometry], wavelengths: np.ndarray,
                     aperture_deg: float = 0.0) -> np.ndarray:
    """The standard's BRDF (1/sr) at each geometry and wavelength, ``(points, wavelengths)``: its
    model's calibrated prediction, or its certified value everywhere."""
    if check.reference is not None:
        return np.full((len(geometries), len(wavelengths)), float(check.reference))
    from bench.identify.prediction import predicted_brdf
    from virtual.specimens import parse_specimen

    return predicted_brdf(parse_specimen(check.specimen), list(geometries), np.asarray(wavelengths, float),
                          aperture_deg=aperture_deg)


def score(check: CheckTable, readings: Any, aperture_deg: float = 0.0) -> dict[str, Any]:
    """Each unmasked reading's E_n against the standard, and the run's check value (the mean of
    reading / reference): the JSON a check run stores and prints."""
    ok = np.isfinite(readings["value"].to_numpy(float)) & np.isfinite(readings["std"].to_numpy(float))
    if "saturated" in readings:
        ok &= readings["saturated"].fillna(0).to_numpy(float) == 0
    rows = readings[ok]
    if rows.empty:
        raise InputError(f"check {check.name!r}: every reading is masked, so nothing was checked")
    geoms = [Geometry(*(float(r[k]) for k in ("theta_i", "phi_i", "theta_r", "phi_r"))) for _, r in rows.iterrows()]
    wl = rows["wavelength_nm"].to_numpy(float)
    ref = np.array([reference_values(check, [g], np.array([w]), aperture_deg)[0, 0] for g, w in zip(geoms, wl)])
    value, u = rows["value"].to_numpy(float), rows["std"].to_numpy(float)
    en = en_numbers(value, u, ref, check.reference_uncertainty * ref)
    ratio = value / ref
    return {"check": check.name, "readings": [
        {"point": int(r["idx"]), "wavelength_nm": float(w), "value": float(v), "reference": float(x), "E_n": float(e)}
        for (_, r), w, v, x, e in zip(rows.iterrows(), wl, value, ref, en)],
        "value": float(ratio.mean()), "max_abs_E_n": float(np.abs(en).max()),
        "agree": bool((np.abs(en) <= 1).all()), "masked": int((~ok).sum())}


def check_history(store: RunStore, bench_name: str, check_name: str) -> list[dict[str, Any]]:
    """Completed check runs of ``check_name`` on bench ``bench_name``, by date then creation:
    each ``{run, date, value, max_abs_E_n}``."""
    out = []
    for r in store.runs():
        if r.get("kind") != "check" or r.get("status") != "completed":
            continue
        info = store.run(r["run_id"])
        c = (info.get("meta") or {}).get("check") or {}
        if c.get("check") != check_name or (info.get("bench") or {}).get("name", "bench") != bench_name:
            continue
        out.append({"run": r["run_id"], "date": c.get("date"), "value": c.get("value"),
                    "max_abs_E_n": c.get("max_abs_E_n"), "created": r.get("created")})
    out.sort(key=lambda h: (h["date"] or "", h["created"] or ""))
    return out


def check_chart(check: CheckTable, history: Sequence[Mapping[str, Any]]) -> Chart:
    """The control chart of the check values in ``history`` (limits from the first
    ``check.baseline`` points, or the declared centre and sigma)."""
    values = [float(h["value"]) for h in history]
    if check.centre is None and len(values) < 2:
        raise InputError(f"check {check.name!r} has {len(values)} completed check run(s): a chart needs at least 2 "
                         f"(or a declared centre and sigma)")
    n = min(int(check.baseline), len(values))
    if check.sigma is None and not np.ptp(values[:n]) > 0:  # sigma from the baseline's moving ranges: 0
        raise InputError(f"check {check.name!r}: its first {n} check values are all {values[0]:.6g}, so its "
                         f"chart has no spread to set limits with (the same seed and day twice?): declare its sigma "
                         f"or measure it on other days")
    return chart(values, baseline=check.baseline, centre=check.centre, sigma=check.sigma)


def relied_charts(store: RunStore, meta: Mapping[str, Any]) -> list[tuple[CheckTable, list[dict[str, Any]], Chart]]:
    """The control charts of the check standards a run relied on (its meta's ``assurance``, as
    ``bench scan`` records it; its bench config in ``meta["bench"]``): each check's history up to
    the check run the scan relied on, as the scan saw it. Checks without a run or a chart yet
    are left out; [] for a run that relied on none."""
    relied = ((meta.get("assurance") or {}).get("checks") or {}) if isinstance(meta.get("assurance"), Mapping) else {}
    bench = meta.get("bench")
    if not relied or not isinstance(bench, Mapping):
        return []
    out = []
    for check in checks_of(bench, (), "the run's bench config"):
        last = (relied.get(check.name) or {}).get("run")
        history = check_history(store, str(bench.get("name", "bench")), check.name)
        runs = [h["run"] for h in history]
        if last not in runs:
            continue
        history = history[:runs.index(last) + 1]
        try:
            out.append((check, history, check_chart(check, history)))
        except InputError:  # too few runs, or no spread yet: no chart to show
            continue
    return out


@dataclass(frozen=True)
class Gate:
    """What ``bench scan`` learns before it opens anything: per check, its state, and the one
    line to warn or refuse with (empty when every check is current and in control)."""

    policy: str
    states: dict[str, dict[str, Any]]
    problems: tuple[str, ...]

    @property
    def refuses(self) -> bool:
        return self.policy == "refuse" and bool(self.problems)

    def message(self, bench_name: str) -> str:
        return f"bench {bench_name} is not vouched for by its checks: " + "; ".join(self.problems)


def _scans_since(store: RunStore, bench_name: str, created: str) -> int:
    n = 0
    for r in store.runs():
        if r.get("kind") == "scan" and (r.get("created") or "") > created:
            n += (store.run(r["run_id"]).get("bench") or {}).get("name", "bench") == bench_name
    return n


def gate(description: Mapping[str, Any], store: RunStore | None, on: str | None = None) -> Gate | None:
    """The assurance state of a bench before a scan on date ``on`` (default today): None when it
    declares ``assurance = "off"`` or no check; else each check's latest run, whether it is
    overdue (``every``) and whether its chart's latest point broke a rule."""
    bench = validate_document(BenchFile, dict(description), "bench config")
    if bench.assurance == "off" or not bench.check:
        return None
    on = on or today()
    states, problems = {}, []
    for check in bench.check:
        history = [] if store is None else check_history(store, bench.name, check.name)
        if not history:
            states[check.name] = {"state": "never measured"}
            problems.append(f"check {check.name!r} was never measured (bench check --check {check.name!r})")
            continue
        last = history[-1]
        state: dict[str, Any] = {"run": last["run"], "date": last["date"], "value": last["value"], "state": "in control"}
        if check.every == "day" and (last["date"] or "") < on:
            state["state"] = "overdue"
            problems.append(f"check {check.name!r} is due daily and was last measured on {last['date']} (run {last['run']})")
        elif check.every != "day" and store is not None:  # always, with a history (read from it)
            limit = 0 if check.every == "run" else int(check.every)
            since = _scans_since(store, bench.name, last["created"] or "")
            if since >= max(limit, 1):
                state["state"] = "overdue"
                problems.append(f"check {check.name!r} is due every {check.every} scan(s) and {since} ran since "
                                f"run {last['run']} of {last['date']}")
        if len(history) >= 2 or check.centre is not None:
            c = check_chart(check, history)
            fired = [v for v in c.violations if v.index == len(history) - 1]
            if fired:
                state["state"] = "out of control"
                state["rules"] = [v.rule for v in fired]
                problems.append(f"check {check.name!r} of {last['date']} (run {last['run']}) broke the rule "
                                f"'{fired[0].text}' (value {last['value']:.4g}, centre {c.centre:.4g}, "
                                f"sigma {c.sigma:.3g})")
        states[check.name] = state
    return Gate(bench.assurance, states, tuple(problems))
