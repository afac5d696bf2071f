"""One sweep task, run anywhere (in-process or on a Dask worker): a pure function of its
:class:`~bench.sweep.spec.SweepTask` returning the store rows of one point (:func:`run_task`).
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import pandas as pd

from bench.core.geometry import cie_geometry
from bench.sweep.spec import SweepTask
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.spectrophotometer import VirtualSpectrophotometer

__all__ = ["TaskResult", "run_task", "warm_up", "spectrum_rows"]


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
        # numba's ceiling, set in numba.config from the environment at import (invisible to a type checker)
        ceiling = int(vars(numba.config)["NUMBA_NUM_THREADS"])
        numba.set_num_threads(max(1, min(int(numba_threads), ceiling)))
    with _kernel_guard(numba_threads):
        return _run_task(task)


def _run_task(task: SweepTask) -> TaskResult:
    t0 = time.time()
    c0 = time.perf_counter()
    if task.instrument == "gonio":
        if task.collector is None:  # the spec gives every gonio task its collector
            raise ValueError(f"sweep task {task.idx}: a gonio task without a collector")
        g = VirtualGoniophotometer(task.specimen, collector=task.collector, rays=task.rays, beam=task.beam,
                                   seed=task.seed, wavelengths=list(task.wavelengths), method=task.method,
                                   delta=task.delta, common_random_numbers=task.common_random_numbers)
        rows = g.measure_bsdf(task.theta_i, task.phi_i, list(task.wavelengths)).table
        rows = rows.drop(columns=["theta_i", "phi_i"])
    else:
        rows = _spectro_rows(task)
    compute_s = time.perf_counter() - c0
    geometry = {"theta_i": task.theta_i, "phi_i": task.phi_i, "theta_r": None, "phi_r": None}
    return TaskResult(task.idx, geometry, pd.DataFrame(rows).reset_index(drop=True), t0, time.time(),
                      _worker_name(), compute_s)


def _spectro_rows(task: SweepTask) -> Any:
    """Store rows of a spectrophotometric task (:func:`spectrum_rows` of its measurement)."""
    if task.geometry is None:  # the spec gives every spectro task its CIE geometry
        raise ValueError(f"sweep task {task.idx}: a spectro task without a geometry")
    sp = VirtualSpectrophotometer(task.specimen, rays=task.rays, beam=task.beam, seed=task.seed,
                                  delta=task.delta, cone_deg=task.cone_deg,
                                  common_random_numbers=task.common_random_numbers)
    return spectrum_rows(sp.measure(task.geometry, list(task.wavelengths)), task.geometry)


def spectrum_rows(s: Any, geometry: str) -> Any:
    """Store rows of a virtual spectrum measured at CIE ``geometry``: per wavelength a reflectance
    ("R") and a transmittance ("T") row with interval, standard uncertainty, count and N (rays
    that reached the specimen). The reflectance row holds a reflectance factor for bidirectional
    geometries (45/0, 0/45; ``quantity`` in :func:`sweep_readings`); its ``std`` is scaled like
    its value."""
    counts = s.meta["counts"]
    measured = cie_geometry(geometry).reciprocal_directional
    n = np.maximum(np.array([c["N"] - c["missed"] for c in counts], dtype=np.int64), 1)
    cone = np.array([c["cone"] for c in counts], dtype=np.int64)
    if measured.viewing == "directional":
        k_r = cone
    else:
        k_r = np.array([c["reflected"] for c in counts], dtype=np.int64) - (0 if measured.specular_included else cone)
    k_t = np.array([c["transmitted"] for c in counts], dtype=np.int64)
    out = []
    for hemi, value, ci, k in (("R", s.reflectance, s.reflectance_ci, k_r),
                               ("T", s.transmittance, s.transmittance_ci, k_t)):
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


