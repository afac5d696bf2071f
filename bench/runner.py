"""The runner: per point move, settle, acquire (dark and white as the plan says), calibrate, record.

* The plan is validated whole against the bench's ``check`` before anything moves.
* Each point is committed to the store in one transaction; a killed process loses nothing
  committed, and :func:`resume` finishes a run with exactly the missing points.
* Ctrl-C or a device fault ends the run cleanly: it is stored as ``interrupted`` with the
  reason, and :class:`bench.core.errors.RunInterrupted` is raised.
* The white reference is measured once (or, ``white = "repeated"``, read ``white_repeats`` times
  in sequence after one mounting: the lamp drift's Type A estimate, every point corrected for
  it), before the run is created, and stored with it; a resumed run reuses it, so its values are
  those an uninterrupted run would have recorded.
  A bench whose ``[white]`` names a ``reference_file`` (:mod:`bench.io.white`) is calibrated
  from that stored reading instead: no operator is needed (the run records the file, its date
  and the operator's note). Which white, which darks, refused or taken, is decided once, before
  any motion, by :func:`bench.calibration_chain.decide_calibration`: a white measured on another
  body or detector is refused there.
* Each calibrated reading is stored with its GUM uncertainty budget (:func:`point_budgets`,
  :mod:`bench.core.budget`): the components the bench description declares; its ``std`` is the
  budget's combined standard uncertainty.
* A plan with ``home = true`` returns the turntable to home after validation, before any
  other motion (:mod:`bench.builders.homing`); a bench without one (virtual) skips it.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from bench.store import RunStore
from bench.core.budget import Budget, calibration_budgets, declared
from bench.core.calibration import Calibration
from bench.config import Bench
from bench.core.errors import BenchError, DeviceError, RunInterrupted, StoreError
from bench.core.geometry import Geometry
from bench.core.roles import Reading
from bench.builders.homing import HOME_AXIS, home_axis, homeable_axes
from bench.exposure import check_exposure, resolve_integration
from bench.builders.ownership import note_run
from bench.plans import Plan, order_for_travel, plan_from_dict, validate
from bench.calibration_chain import acquire_dark, decide_calibration, resumed_calibration, stored_white

log = logging.getLogger(__name__)

__all__ = ["run_scan", "resume_scan", "ScanResult", "point_rows", "point_budgets", "acquire_dark", "measure_calibration",
           "stored_white", "masked_readings"]


@dataclass(frozen=True)
class ScanResult:
    run_id: str
    status: str
    points_done: int
    points_planned: int
    seconds: float
    #: readings without a value (a calibrated run's masked ones) and the saturated among them
    masked: int = 0
    saturated: int = 0
    #: why a completed run is not plainly completed: ``N of M readings masked (S saturated)``
    reason: str | None = None


def point_rows(reading: Reading, cal: Calibration | None, geometry: Geometry, dark: Reading | None,
               white_net: np.ndarray | None, budgets: list[Budget | None] | None = None,
               lit_index: int | None = None) -> list[dict[str, Any]]:
    """The store rows of one point: one per wavelength. With ``budgets`` (one per wavelength, see
    :func:`point_budgets`) each row keeps its GUM budget and its ``std`` is the budget's u_c.
    ``lit_index`` (the reading is the k-th lit one since the first white): with repeated whites the
    value is corrected for the estimated lamp drift (:meth:`Calibration.apply`)."""
    rows = []
    if cal is not None:
        c = cal.apply(reading, geometry, dark, lit_index=lit_index)
        value, std, rf, reasons = c.brdf, c.std, c.reflectance_factor, c.mask_reason
        if budgets is not None:
            std = np.array([s if b is None else b.combined for s, b in zip(std, budgets)])
    else:
        value = std = rf = np.full(reading.signal.shape, np.nan)
        reasons = ["no white reference"] * reading.signal.size
    z = 2.5758293035489004  # two-sided 99 % normal quantile for the interval columns
    d = dark.signal if dark is not None else np.zeros_like(reading.signal)
    for i, w in enumerate(reading.wavelengths):
        masked = bool(reasons[i])
        rows.append({
            "wavelength_nm": float(w), "signal": float(reading.signal[i]), "dark": float(d[i]),
            "white": None if white_net is None else float(white_net[i]),
            "value": None if masked else float(value[i]), "std": None if masked else float(std[i]),
            "ci_lo": None if masked else float(value[i] - z * std[i]),
            "ci_hi": None if masked else float(value[i] + z * std[i]),
            "saturated": bool(reading.saturated[i]),
            "extra": {"reflectance_factor": None if masked else float(rf[i]), "mask": reasons[i] or None,
                      "integration_s": reading.integration_s, "averages": reading.averages},
        })
        b = None if budgets is None or masked else budgets[i]
        if b is not None:
            rows[-1]["uncertainty_budget"] = b.as_dict()  # a column of its own in the store's extra JSON
    return rows


def point_budgets(description: Mapping[str, Any], cal: Calibration | None, reading: Reading, geometry: Geometry,
                  dark: Reading | None, lit_index: int, idx: int, dark_key: str = "dark") -> list[Budget | None] | None:
    """The GUM budget of each wavelength of a point (:mod:`bench.core.budget`), from the bench
    description's declared components; positioning sensitivities from its specimen model
    (:mod:`bench.builders.slopes`) when positioning is declared. ``lit_index``: the point is the k-th lit
    reading since the (first) white; ``idx`` keys its Monte Carlo draws; ``dark_key`` names the dark
    reading (readings with the same key share its noise). None without a calibration."""
    if cal is None:
        return None
    slopes = None
    if declared(description)["positioning_deg"] > 0:
        from bench.builders.slopes import model_slopes

        slopes = model_slopes(description, geometry, reading.wavelengths,
                              cal.apply(reading, geometry, dark, lit_index=lit_index).brdf)
    return calibration_budgets(cal, reading, geometry, dark, description, lit_index=lit_index, slopes=slopes,
                               seed_key=(idx,), dark_key=dark_key)


def measure_calibration(bench: Bench, plan: Plan, use_reference_file: bool = True) -> Calibration | None:
    """The plan's calibration (:mod:`bench.calibration_chain`): None for ``white = "none"``; the
    bench's stored white reference file when it names one (and ``use_reference_file``), checked
    against this body and detector; else a dark (light off, when the plan takes darks) and the
    white standard measured now: once, or (``white = "repeated"``) mounted once and read
    ``white_repeats`` times in sequence."""
    return decide_calibration(bench, plan, use_reference_file).take()


def _progress(total: int, initial: int, enabled: bool, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, desc=desc, unit="pt", dynamic_ncols=True,
                leave=True)


def run_scan(bench: Bench, plan: Plan, store: RunStore, seed: int | None = None, progress: bool = False,
             on_point: Callable[[int, int], None] | None = None, kind: str = "scan",
             extra_meta: dict[str, Any] | None = None) -> ScanResult:
    """Validate, then measure every point of ``plan`` on ``bench`` into ``store`` as a run of
    ``kind`` (``scan``, or ``check`` for a check standard) with ``extra_meta`` in its metadata.

    ``on_point(k, idx)`` is called after point number ``k`` (plan index ``idx``) is committed
    (tests use it to inject faults).
    """
    plan = resolve_integration(plan, bench.config)  # integration_s = "auto": the bench's longest unsaturated
    refused = validate(plan, bench.goniometer.check)  # refuse the whole plan before any motion, or skip
    skipped = {r.index for r in refused}
    order = order_for_travel(plan.points) if plan.order == "travel" else list(range(len(plan.points)))
    order = [i for i in order if i not in skipped]
    check_exposure(plan, bench.config)  # a plan whose readings (or white) would saturate the detector
    chain = decide_calibration(bench, plan)  # which white, which darks: refused here, before any motion
    homed = _home(bench, plan)
    cal = chain.take()
    specimen = bench.config.get("specimen") or {}
    meta = {"order": order, "bench_description": bench.describe(), "bench_kind": bench.kind,
            "homed": homed, "white_reference": chain.provenance(),
            "source": "virtual" if bench.kind == "virtual" else "measured",
            "specimen": specimen.get("spec") or specimen.get("name"),  # the key compare aligns on: the model
            "specimen_name": specimen.get("name") or specimen.get("spec"), "plan_name": plan.name,
            "calibration_steps": chain.record(cal),
            "skipped": [r.as_dict() for r in refused]}  # unreachable = "skip": what was not measured, and why
    meta.update(extra_meta or {})  # e.g. the check standard a `check` run measured, the check a scan relied on
    run_id = store.create_run(kind=kind, plan=plan.as_dict(), bench=bench.config, seed=seed, meta=meta,
                              n_planned=len(order), calibration=None if cal is None else cal.as_dict())
    return _execute(bench, plan, store, run_id, order, cal, set(), progress, on_point)


def resume_scan(bench: Bench, store: RunStore, run_id: str, progress: bool = False,
                on_point: Callable[[int, int], None] | None = None) -> ScanResult:
    """Finish an interrupted run: measure exactly the points it lacks, with its calibration."""
    info = store.run(run_id)
    if info["status"] == "completed":
        raise StoreError(f"run {run_id} is already completed")
    plan = plan_from_dict(info["plan"], name=info["plan"].get("name", "plan"))
    meta = info.get("meta") or {}
    order = [int(i) for i in meta.get("order", range(len(plan.points)))]
    validate(plan, bench.goniometer.check)
    cal = resumed_calibration(bench, plan, run_id, info)  # the run's own white, on the body that measured it
    _home(bench, plan)
    done = set(store.done_indices(run_id))
    store.set_status(run_id, "running", None)
    return _execute(bench, plan, store, run_id, order, cal, done, progress, on_point)


def _home(bench: Bench, plan: Plan) -> dict[str, float] | None:
    """Home the turntable when the plan asks and the bench has one; the position read back."""
    if not plan.home:
        return None
    if HOME_AXIS not in homeable_axes(bench):
        log.info("plan %s asks to home; bench %s has no %s with a return-to-home: skipped",
                 plan.name, bench.name, HOME_AXIS)
        return None
    return {HOME_AXIS: home_axis(bench, HOME_AXIS)}


def _execute(bench: Bench, plan: Plan, store: RunStore, run_id: str, order: list[int], cal: Calibration | None,
             done: set[int], progress: bool, on_point: Callable[[int, int], None] | None) -> ScanResult:
    t_run = time.perf_counter()
    note_run(run_id)  # the devices' owner records name the run a second process would disturb
    white_net = cal.reference_rate()[0] if cal is not None else None
    dark: Reading | None = None
    dark_key = "dark once"  # which dark a reading used: readings sharing one share its noise (budgets)
    if plan.dark == "once":
        dark = acquire_dark(bench, plan)
    last_incidence: tuple[float, float] | None = None
    bar = _progress(len(order), len(done), progress, f"run {run_id}")
    k = len(done)
    faults = PointFaults(store, run_id, bench)
    try:
        for idx in order:
            if idx in done:
                continue
            g = plan.points[idx]
            t0 = time.time()
            faults.start()
            reached = bench.goniometer.move_to(g)
            incidence = (g.theta_i, g.phi_i)
            if plan.dark == "per-point" or (plan.dark == "per-incidence" and incidence != last_incidence):
                dark, dark_key = acquire_dark(bench, plan), f"dark before point {idx}"
            last_incidence = incidence
            reading = bench.spectrometer.acquire(plan.integration_s, plan.averages)
            lit = (cal.n_whites if cal is not None else 1) + k  # lit readings before this one since the first white
            rows = point_rows(reading, cal, reached, dark, white_net,
                              point_budgets(bench.config, cal, reading, reached, dark, lit, idx, dark_key), lit)
            store.add_point(run_id, idx, reached.as_dict(), rows, t_start=t0, t_end=time.time())
            faults.record(idx)
            k += 1
            bar.update(1)
            if on_point is not None:
                on_point(k, idx)
    except KeyboardInterrupt:
        store.set_status(run_id, "interrupted", "interrupted by the user (Ctrl-C)")
        raise RunInterrupted.by_the_user(f"run {run_id} interrupted by the user after {k} of {len(order)} points; "
                                         f"finish it with: bench resume {run_id}") from None
    except DeviceError as exc:
        _safe_stop(bench)
        store.set_status(run_id, "interrupted", f"{type(exc).__name__}: {exc}")
        raise RunInterrupted(f"run {run_id} interrupted by a device fault after {k} of {len(order)} points "
                             f"({type(exc).__name__}: {exc}); fix it, then: bench resume {run_id}") from exc
    except BaseException as exc:  # anything else (a store that lost a table, a bug): never left `running`
        store.record_failure(run_id, exc)
        raise
    finally:
        bar.close()
    masked, saturated, reason = masked_readings(store, run_id, calibrated=cal is not None)
    store.set_status(run_id, "completed", reason)  # a run with masked readings says so wherever it is shown
    return ScanResult(run_id, "completed", k, len(order), time.perf_counter() - t_run, masked, saturated, reason)


def masked_readings(store: RunStore, run_id: str, calibrated: bool) -> tuple[int, int, str | None]:
    """How many readings of run ``run_id`` are masked (no value, in a calibrated run; a
    saturated one in any run) and saturated, and the reason a completed run then records
    (``N of M readings masked (S saturated)``; None when every reading holds a value)."""
    s = store.summary(run_id)
    saturated = int(s["saturated"] or 0)
    masked = int(s["value"]["n_missing"]) if calibrated else saturated
    if not masked:
        return 0, 0, None
    return masked, saturated, f"{masked} of {s['readings']} readings masked ({saturated} saturated)"


class PointFaults:
    """The devices' transient faults and recoveries of each point, kept in the run's meta as
    ``device_faults``: ``{"points": {IDX: {"arm.retries": 1, ...}}, "total": {...}}`` (only points
    that had any), written after the point's own commit; a resumed run adds to what it holds."""

    def __init__(self, store: RunStore, run_id: str, bench: Bench) -> None:
        self.store, self.run_id, self.bench = store, run_id, bench
        held = (store.run(run_id).get("meta") or {}).get("device_faults") or {}
        self.points: dict[str, dict[str, int]] = dict(held.get("points") or {})
        self._before: dict[str, int] = {}

    def start(self) -> None:
        self._before = self.bench.fault_counts()

    def record(self, idx: int) -> None:
        after = self.bench.fault_counts()
        delta = {k: n - self._before.get(k, 0) for k, n in after.items() if n != self._before.get(k, 0)}
        if not delta:
            return
        self.points[str(idx)] = delta
        total: dict[str, int] = {}
        for d in self.points.values():
            for key, n in d.items():
                total[key] = total.get(key, 0) + n
        self.store.update_meta(self.run_id, device_faults={"points": self.points, "total": total})


def _safe_stop(bench: Bench) -> None:
    try:
        bench.goniometer.stop()
    except BenchError as exc:  # the device may be gone; the run is being interrupted anyway
        log.warning("stop after fault failed: %s", exc)
    except OSError as exc:
        log.warning("stop after fault failed: %s", exc)
