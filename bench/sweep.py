"""Sweeps: many virtual measurements, in-process or on a Dask cluster, into the run store.

A sweep is the cartesian product (or an explicit list) of virtual measurements::

    specimens x incidences (or CIE geometries) x collectors x wavelengths

described by a ``SWEEP.toml`` (see :func:`sweep_from_dict` for the format; examples in
``fixtures/sweeps/``). It is cut into *tasks*: one series (specimen, incidence, collector) at
``wavelengths_per_task`` wavelengths. A task is a pure function of its own parameters
(:func:`run_task`); it returns the store rows of one point and never touches the store.

Where the work runs
-------------------
* in-process (the default, ``client=None``): tasks run one after another in this process, numba
  using all its threads;
* on Dask: pass a ``distributed.Client`` (:func:`dask_client` makes one for a scheduler address
  or a local cluster of N worker processes). Each task runs numba single-threaded
  (``numba_threads=1``): a worker with ``--nthreads k`` runs k tasks at once on k cores without
  oversubscription. Workers need goniobench installed (same version as the client).

This module lives in ``bench`` (application level: it drives ``virtual`` instruments and the
store) rather than in ``virtual``, whose numba cache is dropped whenever a ``virtual/`` source
changes.

Only the client process writes the SQLite store: one transaction per task, point index = task
index, a sweep run's rows being a goniophotometric record's (or R/T rows per wavelength for the
spectrophotometer). Per-task metadata (specimen, collector or geometry, method, rays, task key,
series seed) is a function of the spec and is stored once, in the run's meta, at creation; who
ran each task and for how long is flushed there every few seconds. :func:`sweep_readings` joins
both onto the tidy readings. A result whose index is already stored (a retried task, a resumed
run) is skipped, never stored twice. A worker that dies mid-task is replaced by the scheduler and its tasks run
elsewhere. A sweep interrupted as a whole (Ctrl-C, a killed client, a failed task) keeps every
committed task; :func:`resume_sweep` runs exactly the missing ones.

Determinism
-----------
Every series has a *task key*: a 64-bit BLAKE2b hash of its canonical parameters (instrument,
specimen text with the whitespace around ``: , =`` removed, incidence rounded to 1e-6 deg or the
CIE geometry, collector, beam, method, rays, cone). Its seed is
``SeedSequence(sweep_seed, spawn_key=(key,))`` reduced to a 63-bit integer (``series_seed`` in
the run's task table); the instrument then draws wavelength ``w`` from
``measurement_seed(series_seed, w in pm, theta_i, phi_i)``. A result therefore depends on the
sweep seed and the measurement's own parameters only -- never on the task index, the order of
the product, how wavelengths are grouped into tasks, which worker ran it, the thread count, or
a retry -- and ``bench gonio --seed SERIES_SEED`` (``bench spectro``) reproduces one series.
Two series with equal parameters would draw the same rays, so a sweep refuses duplicates.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import re
import socket
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from bench.core.errors import BenchError, ConfigError, InputError, RunInterrupted, SimulationError, StoreError

log = logging.getLogger(__name__)

__all__ = [
    "SweepSpec",
    "SweepTask",
    "TaskResult",
    "SweepResult",
    "load_sweep",
    "sweep_from_dict",
    "task_key",
    "series_seed",
    "run_task",
    "run_sweep",
    "resume_sweep",
    "sweep_readings",
    "task_table",
    "dask_client",
    "warm_up",
    "INSTRUMENTS",
]

INSTRUMENTS = ("gonio", "spectro")
_METHODS = ("auto", "rays", "fast")
_BEAMS = ("collimated", "conical")
_SWEEP_KEYS = {"name", "seed", "instrument", "specimens", "incidences", "geometries", "collectors", "wavelengths",
               "wavelengths_per_task", "rays", "uncertainty", "delta", "method", "beam", "cone_deg"}
_TASK_KEYS = {"specimen", "incidence", "geometry", "collector", "wavelengths", "rays", "uncertainty", "delta",
              "method", "beam", "cone_deg"}
#: per-task columns of :func:`sweep_readings` that differ between executions (who ran it, how long)
RUN_COLUMNS = ("worker", "compute_s")
#: per-task columns fixed by the spec (stored once, in the run's meta, at creation)
TASK_COLUMNS = ("specimen", "collector", "geometry", "quantity", "method", "rays", "beam", "task_key", "series_seed")


# --- the spec --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepTask:
    """One unit of work: a series (specimen, incidence or CIE geometry, collector) at some
    wavelengths. Self-contained and small: a worker needs nothing else to run it."""

    idx: int
    instrument: str
    specimen: str
    theta_i: float
    phi_i: float
    geometry: str | None
    collector: str | None
    wavelengths: tuple[float, ...]
    rays: int
    method: str
    beam: str
    delta: float
    cone_deg: float | None
    key: int
    seed: int

    def label(self) -> str:
        where = self.geometry if self.instrument == "spectro" else f"({self.theta_i:g},{self.phi_i:g})"
        col = f" {self.collector}" if self.collector else ""
        wl = self.wavelengths
        span = f"{wl[0]:g}" if len(wl) == 1 else f"{wl[0]:g}..{wl[-1]:g} nm ({len(wl)})"
        return f"#{self.idx} {self.specimen} {where}{col} {span}"


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: its name, root seed, instrument, tasks and the dict it came from
    (``source``, stored as the run's plan so that :func:`resume_sweep` rebuilds the same tasks)."""

    name: str
    seed: int
    instrument: str
    tasks: tuple[SweepTask, ...]
    source: dict[str, Any] = field(repr=False, default_factory=dict)

    def __len__(self) -> int:
        return len(self.tasks)


def _canonical_specimen(text: str) -> str:
    return re.sub(r"\s*([:,=])\s*", r"\1", str(text).strip())


def task_key(params: Mapping[str, Any]) -> int:
    """The 64-bit key of a series: BLAKE2b-64 of its canonical parameters as sorted JSON.

    ``params`` holds what defines the random draw: instrument, specimen, incidence (or
    geometry), collector, beam, method, rays, cone -- not the wavelengths (those key the
    per-wavelength streams inside the instrument) and not the task's index.
    """
    text = json.dumps(dict(params), sort_keys=True, separators=(",", ":"))
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "big")


def series_seed(sweep_seed: int, key: int) -> int:
    """The instrument seed of a series: ``SeedSequence(sweep_seed, spawn_key=(key,))`` as a
    63-bit integer (small enough for ``bench gonio --seed``)."""
    ss = np.random.SeedSequence(int(sweep_seed), spawn_key=(int(key),))
    return int(ss.generate_state(1, dtype=np.uint64)[0] & np.uint64((1 << 63) - 1))


def _incidence(v: Any, where: str) -> tuple[float, float]:
    try:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            parts = [float(v)]
        elif isinstance(v, str):
            parts = [float(p) for p in v.split(",")]
        else:
            parts = [float(p) for p in v]
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: incidence {v!r} must be THETA, [THETA, PHI] or 'THETA,PHI' (deg)") from None
    if len(parts) not in (1, 2) or not all(math.isfinite(p) for p in parts):
        raise ConfigError(f"{where}: incidence {v!r} must be THETA, [THETA, PHI] or 'THETA,PHI' (deg)")
    theta, phi = parts[0], parts[1] if len(parts) == 2 else 0.0
    if not 0.0 <= theta < 90.0:
        raise ConfigError(f"{where}: incidence theta_i = {theta:g} deg must lie in [0, 90)")
    return round(theta, 6), round(phi % 360.0, 6)


def _list(d: Mapping[str, Any], key: str, where: str) -> list[Any]:
    v = d.get(key)
    if v is None:
        return []
    if isinstance(v, (str, int, float)):
        return [v]
    if not isinstance(v, list) or not v:
        raise ConfigError(f"{where}: {key} must be a non-empty list")
    return list(v)


def load_sweep(path: str | Path) -> SweepSpec:
    """Read and validate a ``SWEEP.toml`` (see :func:`sweep_from_dict`)."""
    from bench.config import read_toml

    d = read_toml(path)
    return sweep_from_dict(d, default_name=Path(path).stem)


def sweep_from_dict(d: Mapping[str, Any], default_name: str = "sweep") -> SweepSpec:
    """Validate a sweep description and cut it into tasks.

    Format (TOML shown; a dict of the same shape works)::

        [sweep]
        name = "ggx-roughness"          # default: the file name
        seed = 20261122                 # default: a fresh seed, stored with the run
        instrument = "gonio"            # "gonio" or "spectro"
        specimens = ["lambert:albedo=0.5", "colorchecker:dark skin"]
        incidences = [0, 30, [60, 90]]  # gonio: THETA or [THETA, PHI] in degrees
        geometries = ["8/d", "45/0"]    # spectro: CIE geometries
        collectors = ["equal-psa:9x36"] # gonio (default equal-psa:9x36)
        wavelengths = "450:650:50"      # START:STOP:STEP, a list, or a number (nm)
        wavelengths_per_task = 1        # 0 = all in one task (default: gonio 1, spectro 0)
        rays = 2_000_000                # per wavelength; or uncertainty = v (eq. 3.5/3.12)
        delta = 0.01
        method = "rays"                 # gonio: auto | rays | fast
        beam = "collimated"             # or "conical"
        cone_deg = 5.0                  # spectro: viewing / gloss-trap cone (optional)

        [[task]]                        # optional: an explicit list instead of the product;
        specimen = "lambert:albedo=0.9" # each entry is one series and may override any
        incidence = [45, 0]             # [sweep] default (wavelengths, rays, collector, ...)

    Raises
    ------
    ConfigError
        Unknown keys, bad values, specimens that lack a wavelength, duplicate series.
    """
    from virtual.spectrophotometer import fresh_seed, parse_wavelengths

    if not isinstance(d, Mapping) or not isinstance(d.get("sweep"), Mapping):
        raise ConfigError("a sweep needs a [sweep] table")
    top_unknown = set(d) - {"sweep", "task"}
    if top_unknown:
        raise ConfigError(f"sweep: unknown top-level key(s) {', '.join(sorted(top_unknown))}; "
                          f"expected [sweep] and optional [[task]]")
    s = dict(d["sweep"])
    unknown = set(s) - _SWEEP_KEYS
    if unknown:
        raise ConfigError(f"[sweep]: unknown key(s) {', '.join(sorted(unknown))}; known: "
                          f"{', '.join(sorted(_SWEEP_KEYS))}")
    instrument = str(s.get("instrument", "gonio"))
    if instrument not in INSTRUMENTS:
        raise ConfigError(f"[sweep]: instrument must be one of {', '.join(INSTRUMENTS)}, got {instrument!r}")
    seed = s.get("seed")
    if seed is None:
        seed = fresh_seed()
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"[sweep]: seed must be an integer >= 0, got {seed!r}")
    s["seed"] = seed
    name = str(s.get("name", default_name))
    per_task = s.get("wavelengths_per_task", 1 if instrument == "gonio" else 0)
    if not isinstance(per_task, int) or isinstance(per_task, bool) or per_task < 0:
        raise ConfigError(f"[sweep]: wavelengths_per_task must be an integer >= 0, got {per_task!r}")

    entries = d.get("task")
    if entries is not None:
        if not isinstance(entries, list) or not entries or not all(isinstance(e, Mapping) for e in entries):
            raise ConfigError("[[task]] must be a non-empty array of tables")
        series = []
        for j, e in enumerate(entries):
            bad = set(e) - _TASK_KEYS
            if bad:
                raise ConfigError(f"[[task]] {j}: unknown key(s) {', '.join(sorted(bad))}; known: "
                                  f"{', '.join(sorted(_TASK_KEYS))}")
            series.append(({**{k: v for k, v in s.items() if k in _TASK_KEYS}, **e}, f"[[task]] {j}"))
        # a [[task]] may leave specimen/incidence to [sweep] singletons
        for e, where in series:
            for one, many in (("specimen", "specimens"), ("incidence", "incidences"), ("geometry", "geometries"),
                              ("collector", "collectors")):
                if one not in e and many in s:
                    vals = _list(s, many, "[sweep]")
                    if len(vals) != 1:
                        raise ConfigError(f"{where}: no {one}, and [sweep] {many} has {len(vals)} values")
                    e[one] = vals[0]
    else:
        specimens = _list(s, "specimens", "[sweep]")
        if not specimens:
            raise ConfigError("[sweep]: specimens is required (or give an explicit [[task]] list)")
        series = []
        if instrument == "gonio":
            if "geometries" in s:
                raise ConfigError("[sweep]: geometries are for instrument = 'spectro'; a goniophotometer "
                                  "sweep takes incidences")
            incidences = _list(s, "incidences", "[sweep]") or [0.0]
            collectors = _list(s, "collectors", "[sweep]") or ["equal-psa:9x36"]
            for sp in specimens:
                for col in collectors:
                    for inc in incidences:
                        series.append(({**s, "specimen": sp, "collector": col, "incidence": inc}, "[sweep]"))
        else:
            if "incidences" in s or "collectors" in s:
                raise ConfigError("[sweep]: a spectrophotometer sweep takes geometries (CIE names), not "
                                  "incidences or collectors")
            geometries = _list(s, "geometries", "[sweep]") or ["8/d"]
            for sp in specimens:
                for g in geometries:
                    series.append(({**s, "specimen": sp, "geometry": g}, "[sweep]"))

    tasks: list[SweepTask] = []
    seen: dict[int, str] = {}
    checked: dict[tuple, Any] = {}
    for e, where in series:
        params, wl = _series(instrument, e, where, parse_wavelengths, checked)
        delta = params.pop("delta")  # intervals only: not part of the random draw
        key = task_key(params)
        label = f"{where}: {params['specimen']} {params.get('incidence') or params.get('geometry')}"
        if key in seen:
            raise ConfigError(f"{label}: the same measurement as {seen[key]} (equal parameters draw the same "
                              f"rays); remove the duplicate or merge their wavelengths")
        seen[key] = label
        seed_i = series_seed(seed, key)
        group = len(wl) if per_task == 0 else per_task
        for start in range(0, len(wl), group):
            theta, phi = params.get("incidence") or (params["theta_i"], 0.0)
            tasks.append(SweepTask(
                idx=len(tasks), instrument=instrument, specimen=params["specimen"], theta_i=float(theta),
                phi_i=float(phi), geometry=params.get("geometry"), collector=params.get("collector"),
                wavelengths=tuple(float(w) for w in wl[start:start + group]), rays=params["rays"],
                method=params.get("method", "rays"), beam=params["beam"], delta=delta,
                cone_deg=params.get("cone_deg"), key=key, seed=seed_i))
    source = {"sweep": s, **({"task": [dict(e) for e in entries]} if entries is not None else {})}
    return SweepSpec(name=name, seed=seed, instrument=instrument, tasks=tuple(tasks), source=source)


def _series(instrument: str, e: Mapping[str, Any], where: str, parse_wavelengths: Callable,
            checked: dict) -> tuple[dict[str, Any], np.ndarray]:
    """Validate one series (building its instrument once per distinct specimen/collector) and
    return its canonical parameters and wavelengths."""
    from bench.core.geometry import cie_geometry
    from virtual.bounds import hoeffding_rays
    from virtual.collector import parse_collector
    from virtual.specimens import parse_specimen

    if "specimen" not in e:
        raise ConfigError(f"{where}: no specimen")
    specimen = _canonical_specimen(e["specimen"])
    try:
        wl = parse_wavelengths(e.get("wavelengths", "550" if instrument == "gonio" else "400:700:10"))
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if len(set(wl.tolist())) != wl.size:
        raise ConfigError(f"{where}: wavelengths repeat")
    beam = str(e.get("beam", "collimated"))
    if beam not in _BEAMS:
        raise ConfigError(f"{where}: beam must be one of {', '.join(_BEAMS)}, got {beam!r}")
    delta = float(e.get("delta", 0.01))
    if not 0.0 < delta < 1.0:
        raise ConfigError(f"{where}: delta must lie in (0, 1), got {delta}")
    try:
        spec = checked.get(("specimen", specimen))
        if spec is None:
            spec = checked[("specimen", specimen)] = parse_specimen(specimen)
        spec.check_wavelengths(wl)
    except InputError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    rays = e.get("rays")
    params: dict[str, Any] = {"instrument": instrument, "specimen": specimen, "beam": beam}
    if instrument == "gonio":
        if "geometry" in e:
            raise ConfigError(f"{where}: 'geometry' is for spectro sweeps; use incidence")
        params["incidence"] = list(_incidence(e.get("incidence", 0.0), where))
        try:
            col = parse_collector(str(e.get("collector", "equal-psa:9x36")))
        except InputError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        params["collector"] = str(col)
        method = str(e.get("method", "auto"))
        if method not in _METHODS:
            raise ConfigError(f"{where}: method must be one of {', '.join(_METHODS)}, got {method!r}")
        if method == "fast" and not spec.has_density:
            raise ConfigError(f"{where}: method 'fast' needs a specimen with a density; {specimen} has none")
        if method == "auto":  # resolve now: the key and the stored rows name the method really used
            method = "fast" if spec.has_density and beam == "collimated" else "rays"
        params["method"] = method
        if rays is None:
            u = e.get("uncertainty")
            rays = hoeffding_rays(float(u), delta, col.n_patches) if u is not None else 10_000_000
    else:
        if "incidence" in e or "collector" in e:
            raise ConfigError(f"{where}: a spectro series takes a geometry, not an incidence or collector")
        try:
            g = cie_geometry(str(e.get("geometry", "8/d")))
        except InputError as exc:
            raise ConfigError(f"{where}: {exc}") from None
        params["geometry"] = g.name
        params["theta_i"] = float(g.reciprocal_directional.theta_i)
        cone = e.get("cone_deg")
        if cone is not None:
            cone = float(cone)
            if not 0.0 < cone < 90.0:
                raise ConfigError(f"{where}: cone_deg must lie in (0, 90), got {cone}")
        params["cone_deg"] = cone
        if rays is None:
            rays = hoeffding_rays(float(e.get("uncertainty", 0.005)), delta)
    if not isinstance(rays, (int, np.integer)) or isinstance(rays, bool) or rays < 1:
        raise ConfigError(f"{where}: rays must be a positive integer, got {rays!r}")
    params["rays"] = int(rays)
    params["delta"] = delta
    return params, wl


# --- one task (runs anywhere) ----------------------------------------------------------------


@dataclass
class TaskResult:
    """What a task sends back: the point's geometry and store rows, and when/where it ran."""

    idx: int
    geometry: dict[str, Any]
    rows: Any  # pandas.DataFrame
    t_start: float
    t_end: float
    worker: str
    compute_s: float


def _worker_name() -> str:
    distributed = sys.modules.get("distributed")  # not loaded: certainly not in a Dask worker
    if distributed is not None:
        try:
            return str(distributed.get_worker().address)
        except ValueError:
            pass
    return f"in-process:{socket.gethostname()}:{os.getpid()}"


#: numba's "workqueue" threading layer (used when neither OpenMP nor TBB is available) aborts the
#: process if two threads launch parallel kernels at once: a Dask worker with several threads
#: then runs its kernels one at a time (OpenMP and TBB need no lock)
_KERNEL_LOCK = threading.Lock()


def _kernel_guard(numba_threads: int | None) -> Any:
    if numba_threads is None:
        return contextlib.nullcontext()
    import numba

    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run in this process yet: the layer is not chosen
        return _KERNEL_LOCK
    return _KERNEL_LOCK if layer == "workqueue" else contextlib.nullcontext()


def run_task(task: SweepTask, numba_threads: int | None = None) -> TaskResult:
    """Run one task: a pure function of ``task`` (its seed included).

    Parameters
    ----------
    task : SweepTask
    numba_threads : int, optional
        Threads numba may use for this task (set for the calling thread only; ``None`` leaves
        the current setting). Results do not depend on it.

    Returns
    -------
    TaskResult
        ``rows``: a DataFrame of store rows (see :meth:`bench.store.RunStore.add_point`), only
        the record's own columns: the per-task metadata (specimen, collector, seed, ...) is a
        function of the spec and is stored once per run, not once per row (which would cost a
        JSON document per row: ~3x the write time of a 648-patch task).
    """
    if numba_threads is not None:
        import numba

        numba.set_num_threads(max(1, min(int(numba_threads), numba.config.NUMBA_NUM_THREADS)))
    with _kernel_guard(numba_threads):
        return _run_task(task)


def _run_task(task: SweepTask) -> TaskResult:
    import pandas as pd

    t0 = time.time()
    c0 = time.perf_counter()
    if task.instrument == "gonio":
        from virtual.goniophotometer import VirtualGoniophotometer

        g = VirtualGoniophotometer(task.specimen, collector=task.collector, rays=task.rays, beam=task.beam,
                                   seed=task.seed, wavelengths=list(task.wavelengths), method=task.method,
                                   delta=task.delta)
        rows = g.measure_bsdf(task.theta_i, task.phi_i, list(task.wavelengths)).table
        rows = rows.drop(columns=["theta_i", "phi_i"])
    else:
        rows = _spectro_rows(task)
    compute_s = time.perf_counter() - c0
    geometry = {"theta_i": task.theta_i, "phi_i": task.phi_i, "theta_r": None, "phi_r": None}
    return TaskResult(task.idx, geometry, pd.DataFrame(rows).reset_index(drop=True), t0, time.time(),
                      _worker_name(), compute_s)


def _spectro_rows(task: SweepTask) -> Any:
    """Store rows of a spectrophotometric task: per wavelength a reflectance ("R") and a
    transmittance ("T") row with interval, standard uncertainty, count and N (rays that reached
    the specimen). The reflectance row holds a reflectance factor for bidirectional geometries
    (45/0, 0/45; ``quantity`` in :func:`sweep_readings`); its ``std`` is scaled like its value."""
    import pandas as pd

    from bench.core.geometry import cie_geometry
    from virtual.spectrophotometer import VirtualSpectrophotometer

    sp = VirtualSpectrophotometer(task.specimen, rays=task.rays, beam=task.beam, seed=task.seed,
                                  delta=task.delta, cone_deg=task.cone_deg)
    s = sp.measure(task.geometry, list(task.wavelengths))
    counts = s.meta["counts"]
    measured = cie_geometry(task.geometry).reciprocal_directional
    n = np.maximum(np.array([c["N"] - c["missed"] for c in counts], dtype=np.int64), 1)
    cone = np.array([c["cone"] for c in counts], dtype=np.int64)
    if measured.viewing == "directional":
        k_r = cone
    else:
        k_r = np.array([c["reflected"] for c in counts], dtype=np.int64) - (0 if measured.specular_included else cone)
    k_t = np.array([c["transmitted"] for c in counts], dtype=np.int64)
    out = []
    for hemi, value, ci, k, q in (("R", s.reflectance, s.reflectance_ci, k_r, s.meta.get("quantity", "reflectance")),
                                  ("T", s.transmittance, s.transmittance_ci, k_t, "transmittance")):
        p = k / n
        # value = scale * p, so std = scale * sqrt(p (1 - p) / n) = value * sqrt((1 - p) / (p n))
        std = np.where(k > 0, value * np.sqrt((1.0 - p) / np.maximum(p * n, 1e-300)), 0.0)
        out.append(pd.DataFrame({
            "wavelength_nm": s.wavelengths.astype(float), "hemisphere": hemi, "value": value.astype(float),
            "std": std, "ci_lo": ci[:, 0], "ci_hi": ci[:, 1], "count": k, "N": n}))
    return pd.concat(out, ignore_index=True)


def warm_up(instrument: str = "gonio") -> float:
    """Import the virtual instruments and load the numba kernels (from the on-disk cache when
    present) with a tiny measurement through the whole task path; return the seconds it took.
    Run once per worker process so the first real task is not charged for it."""
    t0 = time.perf_counter()
    tiny = SweepTask(idx=0, instrument=instrument, specimen="lambert:albedo=0.5", theta_i=30.0, phi_i=0.0,
                     geometry=None if instrument == "gonio" else "8/d",
                     collector="equal-psa:2x4" if instrument == "gonio" else None, wavelengths=(550.0,),
                     rays=64, method="rays", beam="collimated", delta=0.01, cone_deg=None, key=0, seed=0)
    run_task(tiny)
    return time.perf_counter() - t0


# --- running a sweep -------------------------------------------------------------------------


@dataclass(frozen=True)
class SweepResult:
    """How a sweep (or its resumption) ended."""

    run_id: str
    status: str
    tasks_done: int
    tasks_planned: int
    tasks_run: int
    duplicates_skipped: int
    seconds: float
    executor: str


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, *,
                threads_per_worker: int = 1, **cluster_kw: Any) -> Iterator[Any]:
    """A ``distributed.Client`` for a scheduler address, or for a local cluster of ``workers``
    processes (``threads_per_worker`` threads each); closed (and the local cluster shut down)
    on exit. Needs ``dask[distributed]`` (the ``scale`` extra).

    Raises
    ------
    InputError
        Neither or both of ``scheduler`` and ``workers``, or Dask not installed.
    SimulationError
        The scheduler cannot be reached.
    """
    if (scheduler is None) == (workers is None):
        raise InputError("give either a scheduler address or a number of local workers")
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InputError("running a sweep on Dask needs dask[distributed]: pip install 'goniobench[scale]'") from None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=cluster_kw.pop("timeout", "20s"), set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise SimulationError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        with client:
            yield client
        return
    if not isinstance(workers, int) or workers < 1:
        raise InputError(f"workers must be an integer >= 1, got {workers!r}")
    cluster_kw.setdefault("processes", True)
    cluster_kw.setdefault("dashboard_address", ":8787")
    cluster_kw.setdefault("silence_logs", logging.ERROR)
    with LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, **cluster_kw) as cluster, \
            Client(cluster, set_as_default=False) as client:
        yield client


def run_sweep(spec: SweepSpec, store: Any, *, client: Any = None, progress: bool = False,
              numba_threads: int | None = None, window: int | None = None, retries: int = 1,
              on_task: Callable[[int, int], None] | None = None) -> SweepResult:
    """Create a ``sweep`` run in ``store`` and run every task of ``spec``.

    Parameters
    ----------
    spec : SweepSpec
    store : bench.store.RunStore
        Only this process writes it: one transaction per task (point index = task index).
    client : distributed.Client, optional
        Run on this Dask cluster; default: in-process.
    progress : bool
        A tqdm progress bar on stderr.
    numba_threads : int, optional
        numba threads per task: default 1 on Dask (one task per worker thread), all in-process.
    window : int, optional
        Tasks in flight on Dask (default: 4 x the cluster's threads, at least 8): bounds the
        client's and scheduler's memory for sweeps of any size.
    retries : int
        Extra attempts of a task that raised (a worker that died does not count; the scheduler
        reschedules its tasks by itself).
    on_task : callable, optional
        ``on_task(k, idx)`` after task number ``k`` (index ``idx``) is committed (tests use it).

    Raises
    ------
    RunInterrupted
        Ctrl-C, or a task that failed after its retries: the run is stored as interrupted with
        the reason, every committed task kept; :func:`resume_sweep` finishes it.
    """
    executor = _executor(client)
    meta = {"sweep": spec.name, "instrument": spec.instrument, "n_tasks": len(spec),
            "seeding": "series_seed = SeedSequence(seed, spawn_key=(blake2b64(series parameters),)); "
                       "wavelength stream = measurement_seed(series_seed, pm, mdeg theta_i, mdeg phi_i)",
            "tasks": task_table(spec), "task_runs": {"worker": [None] * len(spec), "compute_s": [None] * len(spec)},
            "executions": [executor]}
    run_id = store.create_run(kind="sweep", plan=spec.source, bench={"kind": "virtual", "instrument": spec.instrument},
                              seed=spec.seed, meta=meta, n_planned=len(spec))
    log.info("sweep %s: run %s, %d tasks, %s", spec.name, run_id, len(spec), executor["kind"])
    return _execute(spec, store, run_id, set(), client, progress, numba_threads, window, retries, on_task, executor,
                    meta["task_runs"])


def resume_sweep(store: Any, run_id: str, *, client: Any = None, progress: bool = False,
                 numba_threads: int | None = None, window: int | None = None, retries: int = 1,
                 on_task: Callable[[int, int], None] | None = None) -> SweepResult:
    """Finish an interrupted (or crashed) sweep run: run exactly the tasks it lacks, rebuilt
    from the stored spec, so the stored results equal an uninterrupted run's."""
    info = store.run(run_id)
    if info["kind"] != "sweep":
        raise StoreError(f"run {run_id} is a {info['kind']}, not a sweep; resume it with `bench resume`")
    if info["status"] == "completed":
        raise StoreError(f"run {run_id} is already completed")
    spec = sweep_from_dict(info["plan"])
    stored_keys = ((info.get("meta") or {}).get("tasks") or {}).get("task_key")
    if len(spec) != info["n_planned"] or (stored_keys is not None and stored_keys != task_table(spec)["task_key"]):
        raise StoreError(f"run {run_id}: its stored sweep no longer gives the same tasks ({len(spec)} tasks, "
                         f"{info['n_planned']} planned, or other task keys: a different goniobench version?); "
                         f"refusing to mix results")
    done = set(store.done_indices(run_id))
    executor = _executor(client)
    executions = list((info.get("meta") or {}).get("executions", [])) + [executor]
    store.update_meta(run_id, executions=executions)
    store.set_status(run_id, "running", None)
    return _execute(spec, store, run_id, done, client, progress, numba_threads, window, retries, on_task, executor,
                    (info.get("meta") or {}).get("task_runs"))


def _executor(client: Any) -> dict[str, Any]:
    t = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    if client is None:
        return {"kind": "in-process", "host": socket.gethostname(), "pid": os.getpid(), "started_utc": t}
    info = client.scheduler_info()
    workers = info.get("workers", {})
    return {"kind": "dask", "scheduler": info.get("address"), "workers": len(workers),
            "threads": sum(int(w.get("nthreads", 1)) for w in workers.values()), "started_utc": t}


def _progress(total: int, initial: int, enabled: bool, desc: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, disable=not enabled, desc=desc, unit="task", dynamic_ncols=True,
                leave=True)


def task_table(spec: SweepSpec) -> dict[str, list[Any]]:
    """The per-task metadata fixed by the spec, column-wise (lists aligned with the task index):
    :data:`TASK_COLUMNS`. Stored in the run's meta as ``tasks``; :func:`sweep_readings` joins it."""
    from bench.core.geometry import cie_geometry

    def quantity(t: SweepTask) -> str | None:
        if t.geometry is None:
            return None
        directional = cie_geometry(t.geometry).reciprocal_directional.viewing == "directional"
        return "reflectance factor" if directional else "reflectance"

    cols: dict[str, list[Any]] = {c: [] for c in TASK_COLUMNS}
    for t in spec.tasks:
        for c, v in (("specimen", t.specimen), ("collector", t.collector), ("geometry", t.geometry),
                     ("quantity", quantity(t)), ("method", t.method), ("rays", t.rays), ("beam", t.beam),
                     ("task_key", f"{t.key:016x}"), ("series_seed", t.seed)):
            cols[c].append(v)
    return cols


def sweep_readings(store: Any, run_id: str) -> Any:
    """The tidy readings of a sweep run (:meth:`bench.store.RunStore.readings`) with the per-task
    metadata joined on ``idx``: :data:`TASK_COLUMNS` (``quantity`` of a spectro "T" row is
    ``transmittance``) and :data:`RUN_COLUMNS` (the worker that stored it and its compute
    seconds; None for tasks whose run info was not flushed before a crash)."""
    import pandas as pd

    info = store.run(run_id)
    meta = info.get("meta") or {}
    if info["kind"] != "sweep" or "tasks" not in meta:
        raise StoreError(f"run {run_id} is a {info['kind']} run, not a sweep")
    df = store.readings(run_id)
    tasks = pd.DataFrame({**meta["tasks"], **meta.get("task_runs", {})})
    tasks.insert(0, "idx", range(len(tasks)))
    out = df.merge(tasks.dropna(axis=1, how="all"), on="idx", how="left", validate="many_to_one")
    if "quantity" in out.columns:
        out.loc[out["hemisphere"] == "T", "quantity"] = "transmittance"
    return out


class _Sink:
    """The client side: stores each result once, counts, reports progress, and keeps who ran
    each task (flushed to the run's meta every ``flush_s`` seconds and at the end: diagnostic
    metadata, not results, so it does not cost a second transaction per task)."""

    def __init__(self, store: Any, run_id: str, done: set[int], bar: Any,
                 on_task: Callable[[int, int], None] | None, n_tasks: int | None = None,
                 task_runs: Mapping[str, list[Any]] | None = None, flush_s: float = 10.0) -> None:
        self.store, self.run_id, self.done, self.bar, self.on_task = store, run_id, done, bar, on_task
        self.run = 0
        self.duplicates = 0
        n = n_tasks if n_tasks is not None else 0
        runs = dict(task_runs or {})
        self.workers = list(runs.get("worker") or [None] * n)
        self.compute = list(runs.get("compute_s") or [None] * n)
        self.flush_s = flush_s
        self._dirty = False
        self._last_flush = time.monotonic()

    def flush(self) -> None:
        if self._dirty and self.workers:
            self.store.update_meta(self.run_id, task_runs={"worker": self.workers, "compute_s": self.compute})
            self._dirty = False
        self._last_flush = time.monotonic()

    def put(self, r: TaskResult) -> None:
        if r.idx in self.done:
            self.duplicates += 1
            log.info("run %s: task %d already stored; duplicate result skipped", self.run_id, r.idx)
            return
        try:
            self.store.add_point(self.run_id, r.idx, r.geometry, r.rows, t_start=r.t_start, t_end=r.t_end)
        except StoreError:
            if r.idx not in self.store.done_indices(self.run_id):  # not a duplicate: a real refusal
                raise
            self.duplicates += 1
            self.done.add(r.idx)
            log.info("run %s: task %d stored meanwhile by another process; skipped", self.run_id, r.idx)
            return
        self.done.add(r.idx)
        self.run += 1
        if r.idx < len(self.workers):
            self.workers[r.idx], self.compute[r.idx] = r.worker, round(r.compute_s, 6)
            self._dirty = True
            if time.monotonic() - self._last_flush > self.flush_s:
                self.flush()
        self.bar.update(1)
        if self.on_task is not None:
            self.on_task(len(self.done), r.idx)


def _execute(spec: SweepSpec, store: Any, run_id: str, done: set[int], client: Any, progress: bool,
             numba_threads: int | None, window: int | None, retries: int,
             on_task: Callable[[int, int], None] | None, executor: dict[str, Any],
             task_runs: Mapping[str, list[Any]] | None) -> SweepResult:
    t_run = time.perf_counter()
    todo = [t for t in spec.tasks if t.idx not in done]
    bar = _progress(len(spec), len(done), progress, f"sweep {run_id}")
    sink = _Sink(store, run_id, done, bar, on_task, len(spec), task_runs)
    try:
        if client is None:
            for t in todo:
                sink.put(run_task(t, numba_threads))
        else:
            _on_dask(spec, todo, client, sink, run_id, 1 if numba_threads is None else numba_threads, window,
                     retries)
    except KeyboardInterrupt:
        store.set_status(run_id, "interrupted", "interrupted by the user (Ctrl-C)")
        raise RunInterrupted(f"sweep run {run_id} interrupted by the user after {len(done)} of {len(spec)} tasks; "
                             f"finish it with: bench sweep --resume {run_id}") from None
    except _TaskFailed as exc:
        store.set_status(run_id, "interrupted", str(exc))
        raise RunInterrupted(f"sweep run {run_id} interrupted after {len(done)} of {len(spec)} tasks: {exc}; "
                             f"fix it, then: bench sweep --resume {run_id}") from exc.__cause__
    except BenchError as exc:
        store.set_status(run_id, "interrupted", f"{type(exc).__name__}: {exc}")
        raise
    finally:
        bar.close()
        sink.flush()
    store.set_status(run_id, "completed", None)
    return SweepResult(run_id, "completed", len(done), len(spec), sink.run, sink.duplicates,
                       time.perf_counter() - t_run, executor["kind"])


class _TaskFailed(Exception):
    pass


def _warm_workers(client: Any, instrument: str) -> None:
    """Run :func:`warm_up` once on every worker, as an ordinary task pinned to it (so a slow
    numba compile after a source change never blocks a worker's event loop), and fail early
    with a clear message if the workers cannot import goniobench. A worker that joins later
    warms up on its first task."""
    addrs = list(client.scheduler_info().get("workers", {}))
    futs = {a: client.submit(warm_up, instrument, workers=[a], allow_other_workers=False, pure=False,
                             key=f"goniobench-warm-up-{a}-{time.time_ns()}") for a in addrs}
    took = {}
    for a, f in futs.items():
        try:
            took[a] = round(f.result(), 2)
        except ModuleNotFoundError as exc:
            raise SimulationError(f"Dask worker {a} cannot import {exc.name!r}: install goniobench (the same "
                                  f"version) in every worker's environment") from None
        except Exception as exc:  # noqa: BLE001 - a worker lost during warm-up: its tasks go elsewhere
            log.warning("warm-up on worker %s failed: %s: %s", a, type(exc).__name__, exc)
        finally:
            f.release()
    log.info("workers warmed up (s): %s", took)


def _on_dask(spec: SweepSpec, todo: list[SweepTask], client: Any, sink: _Sink, run_id: str, numba_threads: int,
             window: int | None, retries: int) -> None:
    from distributed import as_completed

    log.info("Dask scheduler %s, dashboard %s", client.scheduler_info().get("address"), client.dashboard_link)
    _warm_workers(client, spec.instrument)
    threads = sum(int(w.get("nthreads", 1)) for w in client.scheduler_info().get("workers", {}).values())
    limit = window if window is not None else max(8, 4 * max(threads, 1))
    queue = list(reversed(todo))
    tag = f"goniobench-sweep-{run_id}"

    def submit() -> Any:
        t = queue.pop()
        return client.submit(run_task, t, numba_threads, key=f"{tag}-{t.idx}", pure=False, retries=retries)

    ac = as_completed(loop=client.loop, with_results=True, raise_errors=False)
    try:
        ac.update([submit() for _ in range(min(limit, len(queue)))])
        for fut, res in ac:
            if fut.status == "error" or isinstance(res, BaseException):
                exc = fut.exception() if fut.status == "error" else res
                idx = fut.key.rsplit("-", 1)[-1]
                raise _TaskFailed(f"task {idx} failed: {type(exc).__name__}: {exc}") from exc
            sink.put(res)
            fut.release()
            if queue:
                ac.add(submit())
    finally:
        remaining = list(ac.futures)
        if remaining:
            client.cancel(remaining)
