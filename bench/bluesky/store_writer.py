"""``StoreWriter(STORE)``: a RunEngine callback writing Bluesky runs into our SQLite run store.

One Bluesky run becomes one run of kind ``bluesky`` in the same tables as ``bench scan``'s, so
``bench runs / show / export / compare`` read it unchanged:

* start: the run is created (of kind ``bluesky``, or the kind the start document's
  ``goniobench_run`` key names, :data:`RUN_KEY`, with its ``meta`` merged in) with the bench
  config, seed and description from the start document's ``goniobench`` key (set by
  :func:`~bench.bluesky.connect`), the plan from ``goniobench_plan`` (set by
  :func:`~bench.bluesky.plan_from_toml`) or the Bluesky plan name and arguments, and
  the whole start document in ``meta["bluesky_start"]``;
* descriptor (stream ``primary``): the reflectance detector's calibration (its configuration) is
  stored with the run;
* event: one point per event, its rows made by :func:`bench.runner.point_rows` from the event's
  raw signal, dark and geometry: the very function ``bench scan`` stores with, so the values are
  the same (a spectrometer-only run stores signals, values masked "no white reference");
* stop: ``success`` -> ``completed``, ``abort`` -> ``interrupted``, ``fail`` -> ``failed``, with
  the stop document's reason (a completed run with masked readings: ``N of M readings masked (S
  saturated)``, as ``bench scan`` records it); a failed status's repr (``<AsyncStatus, device: X, ...,
  errored: HardwareError('...')>``) is stored as ``HardwareError: ... (device X)`` as ``bench
  scan`` words a fault (the stop document itself is kept verbatim in ``meta["bluesky_stop"]``).

The store is opened at the start document in the thread that delivers the documents and closed at
the stop document (:class:`~bench.store.RunStore` connections belong to one thread).
"""

from __future__ import annotations

import ast
import json
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from event_model import DocumentRouter, unpack_event_page

from bench.bluesky.connect import METADATA_KEY, PLAN_KEY, jsonable
from bench.bluesky.goniometer import AXES, Mover
from bench.core.calibration import Calibration
from bench.core.geometry import Geometry
from bench.core.roles import Reading
from bench.runner import masked_readings, point_budgets, point_rows
from bench.store import RunStore

log = logging.getLogger(__name__)

__all__ = ["StoreWriter", "EXIT_STATUS", "RUN_KEY", "fault_reason"]

#: the start-document key of a plan whose runs are not plain Bluesky runs: ``{"kind": K, "meta":
#: {...}}`` (a :data:`bench.store.RUN_KINDS` kind, and keys merged into the run's meta), e.g. the
#: check runs of :func:`bench.bluesky.assurance.check_standards`
RUN_KEY = "goniobench_run"

#: Bluesky exit_status -> our run status
EXIT_STATUS = {"success": "completed", "abort": "interrupted", "fail": "failed"}
_FAILED_STATUS = re.compile(r"device: (?P<device>[^,]+),.*errored: (?P<type>\w+)\((?P<msg>'.*'|\".*\")\)>\s*$",
                            re.DOTALL)


def fault_reason(reason: str) -> str:
    """``Type: message (device X)`` from a failed status's repr, else ``reason`` unchanged."""
    m = _FAILED_STATUS.search(reason)
    if m is None:
        return reason
    try:
        msg = ast.literal_eval(m["msg"])
    except (ValueError, SyntaxError):
        return reason
    return f"{m['type']}: {msg} (device {m['device']})"


@dataclass
class _Stream:
    """What one primary descriptor says: which objects are our detectors and axes."""

    reflectance: str | None = None
    spectrometer: str | None = None
    goniometer: dict[str, str] = field(default_factory=dict)  # axis -> data key
    config: dict[str, dict[str, Any]] = field(default_factory=dict)  # object -> its configuration data
    calibration: Calibration | None = None  # the reflectance detector's, decoded once
    white_net: np.ndarray | None = None


class StoreWriter(DocumentRouter):
    """RunEngine callback: ``RE.subscribe(StoreWriter("runs.sqlite"))``.

    Attributes
    ----------
    run_ids : list of str
        Our run ids, one per Bluesky run written (in order).
    """

    def __init__(self, store: str | Path) -> None:
        super().__init__()
        self.path = Path(store)
        self.run_ids: list[str] = []
        self._store: RunStore | None = None
        self._run: str | None = None
        self._order: list[int] | None = None
        self._streams: dict[str, _Stream] = {}
        self._last_t: float | None = None
        self._description: dict[str, Any] = {}

    # -- documents ---------------------------------------------------------------------------
    def start(self, doc: dict[str, Any]) -> None:
        bench = dict(doc.get(METADATA_KEY) or {})
        ours = doc.get(PLAN_KEY) or {}
        self._order = [int(i) for i in ours["order"]] if ours.get("order") is not None else None
        plan = ours.get("plan") or {"bluesky_plan": doc.get("plan_name"), "plan_args": doc.get("plan_args")}
        meta = {"bluesky_start": jsonable(doc), "bluesky_uid": doc["uid"], "order": self._order,
                "bench_description": bench.get("bench_description"), "bench_kind": bench.get("bench_kind"),
                "source": bench.get("source"), "specimen": bench.get("specimen"),
                "plan_name": ours.get("name") or doc.get("plan_name")}
        run = dict(doc.get(RUN_KEY) or {})
        meta.update(run.get("meta") or {})
        n_planned = ours.get("n_planned", doc.get("num_points"))
        self._store = RunStore(self.path)
        self._description = dict(bench.get("bench") or {})  # its declared uncertainty components
        self._run = self._store.create_run(kind=str(run.get("kind", "bluesky")), plan=jsonable(plan),
                                           bench=bench.get("bench"), seed=bench.get("seed"), meta=meta,
                                           n_planned=None if n_planned is None else int(n_planned))
        self.run_ids.append(self._run)
        self._streams.clear()
        self._last_t = float(doc["time"])

    def descriptor(self, doc: dict[str, Any]) -> None:
        if doc.get("name") != "primary" or self._store is None:
            return
        s = _Stream()
        for obj, keys in (doc.get("object_keys") or {}).items():
            names = set(keys)
            if f"{obj}-brdf" in names and f"{obj}-signal" in names:
                s.reflectance = obj
            elif f"{obj}-spectrum" in names and f"{obj}-saturated" in names:
                s.spectrometer = obj
        for key in doc["data_keys"]:
            for axis in AXES:
                if key.endswith(f"-{axis}") and not (s.reflectance and key.startswith(f"{s.reflectance}-")):
                    s.goniometer.setdefault(axis, key)
        s.config = {obj: dict(c.get("data", {})) for obj, c in (doc.get("configuration") or {}).items()}
        self._streams[doc["uid"]] = s
        if s.reflectance is not None:
            cal = json.loads(s.config.get(s.reflectance, {}).get(f"{s.reflectance}-calibration") or "null")
            if cal is not None:
                s.calibration = Calibration.from_dict(cal)
                s.white_net = s.calibration.reference_rate()[0]
                self._store.set_calibration(self._run, cal)

    def event_page(self, doc: dict[str, Any]) -> None:
        for event in unpack_event_page(doc):
            self.event(event)

    def event(self, doc: dict[str, Any]) -> None:
        s = self._streams.get(doc["descriptor"])
        if s is None or self._store is None:
            return
        data = doc["data"]
        k = int(doc["seq_num"]) - 1
        idx = self._order[k] if self._order is not None and k < len(self._order) else k
        geometry = self._geometry(s, data)
        rows = self._rows(s, data, geometry, k, idx)
        t_end = float(doc["time"])
        self._store.add_point(self._run, idx, geometry.as_dict() if geometry is not None else dict.fromkeys(AXES),
                              rows, t_start=self._last_t, t_end=t_end)
        self._last_t = t_end

    def stop(self, doc: dict[str, Any]) -> None:
        if self._store is None:
            return
        try:
            status = EXIT_STATUS.get(doc.get("exit_status", ""), "failed")
            reason = fault_reason(doc["reason"]) if doc.get("reason") else None
            if status != "completed" and not reason:
                reason = f"bluesky run ended with exit_status {doc.get('exit_status')!r}"
            elif status == "completed" and not reason:  # masked readings say so, as the runner's run does
                calibrated = any(s.calibration is not None for s in self._streams.values())
                reason = masked_readings(self._store, self._run, calibrated)[2]
            self._store.update_meta(self._run, bluesky_stop=jsonable(doc))
            self._store.set_status(self._run, status, reason)
        finally:
            self._store.close()
            self._store = None

    # -- rows ----------------------------------------------------------------------------------
    @staticmethod
    def _geometry(s: _Stream, data: dict[str, Any]) -> Geometry | None:
        if s.reflectance is not None:  # signed as the goniometer axes are
            return Mover.geometry_of({a: float(data[f"{s.reflectance}-{a}"]) for a in AXES})
        if len(s.goniometer) == len(AXES):
            return Mover.geometry_of({a: float(data[s.goniometer[a]]) for a in AXES})
        return None

    @staticmethod
    def _reading(data: dict[str, Any], cfg: dict[str, Any], obj: str, signal: str, std: str,
                 saturated: str | None) -> Reading:
        sig = np.asarray(data[f"{obj}-{signal}"], dtype=float)
        sd = np.asarray(data[f"{obj}-{std}"], dtype=float)
        sat = np.asarray(data[f"{obj}-{saturated}"], dtype=bool) if saturated else np.zeros(sig.size, bool)
        return Reading(wavelengths=np.asarray(cfg[f"{obj}-wavelength_nm"], dtype=float), signal=sig,
                       saturated=sat, integration_s=float(cfg[f"{obj}-integration_s"]),
                       averages=int(cfg[f"{obj}-averages"]), std=None if np.all(np.isnan(sd)) else sd)

    def _rows(self, s: _Stream, data: dict[str, Any], geometry: Geometry | None, k: int,
              idx: int) -> list[dict[str, Any]]:
        if s.reflectance is not None:
            obj = s.reflectance
            cfg = s.config[obj]
            reading = self._reading(data, cfg, obj, "signal", "signal_std", "saturated")
            dark = self._reading(data, cfg, obj, "dark", "dark_std", None) if data[f"{obj}-has_dark"] else None
            g = geometry if geometry is not None else Geometry(0, 0, 0, 0)
            return point_rows(reading, s.calibration, g, dark, s.white_net,
                              point_budgets(self._description, s.calibration, reading, g, dark, k + 1, idx,
                                            f"dark at point {idx}"))
        if s.spectrometer is not None:
            obj = s.spectrometer
            reading = self._reading(data, s.config[obj], obj, "spectrum", "spectrum_std", "saturated")
            return point_rows(reading, None, geometry if geometry is not None else Geometry(0, 0, 0, 0), None, None)
        return []
