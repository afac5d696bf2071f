"""The run store: one SQLite file (WAL mode), one transaction per measured point.

Modules: :mod:`bench.store.schema` (tables, kinds, statuses, helpers), :mod:`bench.store.runstore`
(:class:`RunStore`: opening, runs, points), :mod:`bench.store.reading` (reading back),
:mod:`bench.store.rows` (readings to rows). The public names are re-exported here.

Durability
----------
Every point (its geometry row and all its readings rows) is written by :meth:`RunStore.add_point`
in a single ``BEGIN IMMEDIATE ... COMMIT`` transaction, so a reader or a later process sees a
point either whole or not at all. With ``journal_mode=WAL`` and ``synchronous=NORMAL`` (the
default here) a committed transaction is in the WAL file before ``COMMIT`` returns; the
operating system keeps it when the *process* dies (Ctrl-C, an exception, ``SIGKILL``), so a killed
scan loses no committed point and leaves no half-written one. NORMAL does not fsync on every
commit, so after a *power loss or kernel crash* the last few commits may be rolled back (the
file is never corrupted). Pass ``synchronous="FULL"`` to fsync every commit and survive power
loss too, at a throughput cost (see ``benchmarks/bench_store.py``).

Throughput
----------
Each point is one ``BEGIN IMMEDIATE``, one ``INSERT`` into ``points``, one ``executemany`` of its
readings and ``COMMIT``. ``benchmarks/bench_store.py`` measures points/s with 31 wavelengths per
point (target >= 2,000/s with NORMAL) beside raw sqlite3 issuing the same transactions; the store
costs little over SQLite itself. FULL is bounded by the disk's fsync rate.

Concurrency
-----------
Readers (``bench runs``, ``bench show`` while a scan runs) never block the writer and are never
blocked by it in WAL mode; every connection also sets ``busy_timeout`` (``timeout`` seconds) so the
rare moments that need a lock (a checkpoint, a second writer) wait instead of failing with
"database is locked". A :class:`RunStore` holds one connection: use it from the thread
that opened it (open another :class:`RunStore` per thread or process).

Schema (version :data:`SCHEMA_VERSION`)
---------------------------------------
``schema_version(version, applied_utc)``; ``runs`` (one row per run: ids, kind, status, reason,
timestamps as UTC ISO text and epoch seconds, plan / bench / versions / calibration / meta as JSON
text, seed, n_planned); ``run_events`` (status history); ``points`` (run_id, idx, geometry,
t_start, t_end, status, n_readings; ``UNIQUE(run_id, idx)``); ``readings`` (run_id, idx,
wavelength_nm, optional per-row viewing direction, signal, dark, white, value, std, ci_lo, ci_hi,
saturated, the virtual-patch columns of :data:`bench.core.records.BSDF_COLUMNS` and a JSON ``extra``).
Opening a file whose schema version is unknown (newer, or not a goniobench store) raises
:class:`bench.core.errors.StoreError` rather than guessing.

Note: SQLite stores a float NaN as NULL; NaN values come back as NaN in :meth:`RunStore.readings`.
"""

from __future__ import annotations

from bench.store.runstore import RunStore
from bench.store.schema import (READING_COLUMNS, RUN_KINDS, RUN_STATUSES, SCHEMA_VERSION, new_run_id,
                                package_versions)

__all__ = ["RunStore", "SCHEMA_VERSION", "RUN_KINDS", "RUN_STATUSES", "READING_COLUMNS",
           "package_versions", "new_run_id"]
