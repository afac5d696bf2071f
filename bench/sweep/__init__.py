"""Sweeps: many virtual measurements, in-process or on a Dask cluster, into the run store.

Modules: :mod:`bench.sweep.spec` (the ``SWEEP.toml`` spec and its tasks),
:mod:`bench.sweep.task` (one task, run anywhere), :mod:`bench.sweep.executor` (running a sweep
into the store, in-process or on Dask). Everything public is re-exported here.

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
``measurement_seed(series_seed, [specimen hash,] w in pm, theta_i, phi_i)`` -- or, counting rays
for a specimen whose wavelengths share the angular part (Lambertian, single-roughness GGX), all
the task's wavelengths from one spectral batch on ``measurement_seed(series_seed, [specimen
hash,] theta_i, phi_i)`` (the specimen hash left out under common random numbers), whose
row for ``w`` is exactly what a task of ``w`` alone gives (see
:mod:`virtual.goniophotometer`). Tasks hold a whole spectrum by default
(``wavelengths_per_task = 0``), so such a series costs one batch. A result therefore depends on the
sweep seed and the measurement's own parameters only -- never on the task index, the order of
the product, how wavelengths are grouped into tasks, which worker ran it, the thread count, or
a retry -- and ``bench gonio --seed SERIES_SEED`` (``bench spectro``) reproduces one series.
Two series with equal parameters would draw the same rays, so a sweep refuses duplicates.
"""

from __future__ import annotations

from bench.sweep.executor import SweepResult, dask_client, resume_sweep, run_sweep, sweep_readings
from bench.sweep.records import sweep_record
from bench.sweep.spec import (INSTRUMENTS, RUN_COLUMNS, TASK_COLUMNS, SweepSpec, SweepTask, load_sweep, series_seed,
                              sweep_from_dict, task_key, task_table)
from bench.sweep.task import TaskResult, run_task, warm_up

__all__ = [
    "SweepSpec", "SweepTask", "TaskResult", "SweepResult", "load_sweep", "sweep_from_dict", "task_key", "series_seed",
    "run_task", "run_sweep", "resume_sweep", "sweep_readings", "task_table", "dask_client", "warm_up", "INSTRUMENTS",
    "TASK_COLUMNS", "RUN_COLUMNS", "sweep_record",
]
