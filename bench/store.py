"""The run store: one SQLite file (WAL mode), one transaction per measured point.

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

import json
import math
import platform
import secrets
import sqlite3
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from collections.abc import Mapping
from typing import Any, Sequence

import numpy as np

from bench.core.errors import InputError, StoreError
from bench.core.records import BSDF_COLUMNS, BSDFRecord, json_default

__all__ = ["RunStore", "SCHEMA_VERSION", "RUN_KINDS", "RUN_STATUSES", "READING_COLUMNS",
           "package_versions", "new_run_id"]

SCHEMA_VERSION = 1
RUN_KINDS = ("scan", "sweep", "calibration", "import", "virtual", "bluesky")
RUN_STATUSES = ("running", "completed", "interrupted", "failed")
#: allowed status changes (same status again is a no-op that may update the reason)
_TRANSITIONS = {
    "running": {"completed", "interrupted", "failed"},
    "interrupted": {"running", "failed"},
    "failed": {"running"},
    "completed": set(),
}
_GEOMETRY = ("theta_i", "phi_i", "theta_r", "phi_r")
#: value columns of the readings table, in order (``extra`` holds anything else as JSON)
READING_COLUMNS = ("wavelength_nm", "theta_r", "phi_r", "signal", "dark", "white", "value", "std",
                   "ci_lo", "ci_hi", "saturated", "theta_min", "theta_max", "phi_min", "phi_max", "psa",
                   "count", "N", "hemisphere")
_POINT_LEVEL = {"run_id", "idx", "theta_i", "phi_i", "t_start", "t_end", "point_status"}
_INT_COLUMNS = {"saturated", "count", "N"}

_SCHEMA = f"""
CREATE TABLE schema_version (
    version     INTEGER NOT NULL,
    applied_utc TEXT NOT NULL
);
CREATE TABLE runs (
    run_id          TEXT PRIMARY KEY,
    kind            TEXT NOT NULL,
    status          TEXT NOT NULL CHECK (status IN ({", ".join(repr(s) for s in RUN_STATUSES)})),
    reason          TEXT,
    created_utc     TEXT NOT NULL,
    created_epoch   REAL NOT NULL,
    started_utc     TEXT,
    started_epoch   REAL,
    finished_utc    TEXT,
    finished_epoch  REAL,
    plan            TEXT,
    bench           TEXT,
    versions        TEXT,
    seed            INTEGER,
    calibration     TEXT,
    meta            TEXT,
    n_planned       INTEGER
);
CREATE TABLE run_events (
    run_id  TEXT NOT NULL REFERENCES runs(run_id) ON DELETE CASCADE,
    t_utc   TEXT NOT NULL,
    t_epoch REAL NOT NULL,
    status  TEXT NOT NULL,
    reason  TEXT
);
CREATE TABLE points (
    run_id     TEXT NOT NULL REFERENCES runs(run_id) ON DELETE CASCADE,
    idx        INTEGER NOT NULL,
    theta_i    REAL,
    phi_i      REAL,
    theta_r    REAL,
    phi_r      REAL,
    t_start    REAL,
    t_end      REAL,
    status     TEXT NOT NULL DEFAULT 'ok',
    n_readings INTEGER NOT NULL,
    UNIQUE (run_id, idx)
);
CREATE TABLE readings (
    run_id        TEXT NOT NULL,
    idx           INTEGER NOT NULL,
    wavelength_nm REAL,
    theta_r       REAL,
    phi_r         REAL,
    signal        REAL,
    dark          REAL,
    white         REAL,
    value         REAL,
    std           REAL,
    ci_lo         REAL,
    ci_hi         REAL,
    saturated     INTEGER,
    hemisphere    TEXT,
    theta_min     REAL,
    theta_max     REAL,
    phi_min       REAL,
    phi_max       REAL,
    psa           REAL,
    count         INTEGER,
    N             INTEGER,
    extra         TEXT
);
CREATE INDEX readings_point ON readings(run_id, idx);
CREATE TRIGGER points_refuse_completed BEFORE INSERT ON points
WHEN (SELECT status FROM runs WHERE run_id = NEW.run_id) = 'completed'
BEGIN SELECT RAISE(ABORT, 'goniobench: run is completed'); END;
CREATE INDEX events_run ON run_events(run_id);
"""

#: migrations[v] upgrades a store at version v to v + 1 (none yet: version 1 is the first)
_MIGRATIONS: dict[int, str] = {}


# --- small helpers -------------------------------------------------------------------------


def _now() -> tuple[str, float]:
    t = time.time()
    return _iso(t), t


def _iso(t: float) -> str:
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def _dumps(obj: Any) -> str | None:
    if obj is None:
        return None
    return json.dumps(obj, default=json_default, allow_nan=True, sort_keys=False)


def _loads(text: str | None) -> Any:
    return None if text is None else json.loads(text)


def _py(v: Any) -> Any:
    """A value sqlite3 binds: numpy scalars to Python, NaN to NULL, bools to 0/1."""
    if v is None:
        return None
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float):
        return None if math.isnan(v) else v
    if isinstance(v, bool):
        return int(v)
    return v


def new_run_id(t: float | None = None) -> str:
    """A short, readable, sortable run id: ``YYYYMMDD-HHMM-xxxx`` (UTC, 4 random hex digits)."""
    t = time.time() if t is None else t
    return datetime.fromtimestamp(t, tz=timezone.utc).strftime("%Y%m%d-%H%M") + "-" + secrets.token_hex(2)


def package_versions() -> dict[str, str | None]:
    """Versions recorded with every run: python, platform, numpy, numba, pandas, scipy, goniobench.

    Read from package metadata (``importlib.metadata``), so numba is not imported.
    """
    from importlib import metadata

    out: dict[str, str | None] = {"python": platform.python_version(), "platform": platform.platform(),
                                  "sqlite": sqlite3.sqlite_version}
    for name in ("numpy", "numba", "pandas", "scipy", "pyarrow", "goniobench"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


# --- the store -----------------------------------------------------------------------------


class RunStore:
    """A goniobench run store (one SQLite file in WAL mode).

    Parameters
    ----------
    path : str or Path
        The database file; created (with parent folders) unless ``create`` is false.
    timeout : float
        Seconds any connection waits for a lock (``busy_timeout``) before raising
        :class:`bench.core.errors.StoreError`; readers beside a running scan never see
        "database is locked".
    synchronous : {"NORMAL", "FULL"}
        ``NORMAL`` (default): durable against process crashes (SIGKILL), not against power
        loss. ``FULL``: fsync on every commit, durable against power loss too.
    create : bool
        If false, a missing file raises :class:`StoreError` instead of creating a store.

    Examples
    --------
    >>> with RunStore("runs.sqlite") as store:                         # doctest: +SKIP
    ...     rid = store.create_run("scan", plan={...}, n_planned=3)
    ...     store.add_point(rid, 0, {"theta_i": 45, "phi_i": 0, "theta_r": 0, "phi_r": 0},
    ...                     [{"wavelength_nm": 550.0, "signal": 1234.0}])
    ...     store.set_status(rid, "completed")
    """

    def __init__(self, path: str | Path, *, timeout: float = 30.0, synchronous: str = "NORMAL",
                 create: bool = True) -> None:
        self.path = Path(path)
        sync = str(synchronous).upper()
        if sync not in ("NORMAL", "FULL"):
            raise InputError(f"synchronous must be 'NORMAL' or 'FULL', got {synchronous!r}")
        if not (isinstance(timeout, (int, float)) and timeout >= 0):
            raise InputError(f"timeout must be a number of seconds >= 0, got {timeout!r}")
        if not self.path.exists():
            if not create:
                raise StoreError(f"no run store at {self.path}")
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self.timeout = float(timeout)
        self.synchronous = sync
        try:
            self._db = sqlite3.connect(str(self.path), timeout=self.timeout, isolation_level=None)
        except sqlite3.Error as e:
            raise StoreError(f"cannot open run store {self.path}: {e}") from e
        try:
            self._db.execute(f"PRAGMA busy_timeout = {int(self.timeout * 1000)}")
            mode = self._db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{self.path}: could not switch to WAL mode (journal_mode={mode})")
            self._db.execute(f"PRAGMA synchronous = {sync}")
            self._db.execute("PRAGMA foreign_keys = ON")
            self._ensure_schema()
        except sqlite3.DatabaseError as e:
            self._db.close()
            raise StoreError(f"{self.path} is not a usable run store: {e}") from e
        except BaseException:
            self._db.close()
            raise

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Close the connection (committed data is already safe)."""
        self._db.close()

    def __enter__(self) -> "RunStore":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RunStore({str(self.path)!r})"

    # -- schema ------------------------------------------------------------------------------
    def _tables(self) -> set[str]:
        return {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type='table'")}

    def _ensure_schema(self) -> None:
        tables = self._tables()
        if "schema_version" not in tables:
            if tables:
                raise StoreError(f"{self.path} is an SQLite file but not a goniobench run store "
                                 f"(tables: {', '.join(sorted(tables))}; no schema_version)")
            self._db.execute("BEGIN IMMEDIATE")
            try:
                if "schema_version" not in self._tables():  # another process may have won
                    for stmt in _SCHEMA.split(";\n"):
                        if stmt.strip():
                            self._db.execute(stmt)
                    self._db.execute("INSERT INTO schema_version VALUES (?, ?)", (SCHEMA_VERSION, _now()[0]))
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
        row = self._db.execute("SELECT MAX(version) FROM schema_version").fetchone()
        version = row[0] if row else None
        if version is None:
            raise StoreError(f"{self.path}: schema_version table is empty; not a goniobench run store")
        if version > SCHEMA_VERSION:
            raise StoreError(f"{self.path} has store schema version {version}, newer than this goniobench "
                             f"understands ({SCHEMA_VERSION}); upgrade goniobench to read it")
        while version < SCHEMA_VERSION:
            if version not in _MIGRATIONS:
                raise StoreError(f"{self.path} has store schema version {version} and no migration to "
                                 f"{SCHEMA_VERSION} exists")
            with self._transaction():
                for stmt in _MIGRATIONS[version].split(";\n"):
                    if stmt.strip():
                        self._db.execute(stmt)
                version += 1
                self._db.execute("INSERT INTO schema_version VALUES (?, ?)", (version, _now()[0]))

    @property
    def schema_version(self) -> int:
        """The schema version of the open file."""
        return int(self._db.execute("SELECT MAX(version) FROM schema_version").fetchone()[0])

    def pragma(self, name: str) -> Any:
        """Read one PRAGMA (``journal_mode``, ``synchronous``, ``busy_timeout`` ...)."""
        if not name.replace("_", "").isalnum():
            raise InputError(f"bad pragma name {name!r}")
        row = self._db.execute(f"PRAGMA {name}").fetchone()
        return None if row is None else row[0]

    # -- transactions ------------------------------------------------------------------------
    class _Tx:
        def __init__(self, db: sqlite3.Connection, path: Path) -> None:
            self.db, self.path = db, path

        def __enter__(self) -> sqlite3.Connection:
            try:
                self.db.execute("BEGIN IMMEDIATE")
            except sqlite3.OperationalError as e:
                raise StoreError(f"{self.path}: could not start a write transaction ({e}); another "
                                 f"process holds the write lock") from e
            return self.db

        def __exit__(self, et: Any, ev: Any, tb: Any) -> None:
            # an exception (including KeyboardInterrupt mid-point) rolls the whole point back
            if et is None:
                try:
                    self.db.execute("COMMIT")
                    return
                except sqlite3.Error as e:
                    if self.db.in_transaction:
                        self.db.execute("ROLLBACK")
                    raise StoreError(f"{self.path}: commit failed, nothing of it was stored ({e})") from e
            if self.db.in_transaction:  # SQLite may already have rolled back (disk full, I/O error)
                self.db.execute("ROLLBACK")

    def _transaction(self) -> "RunStore._Tx":
        return RunStore._Tx(self._db, self.path)

    # -- runs --------------------------------------------------------------------------------
    def create_run(self, kind: str = "scan", plan: Any = None, bench: Any = None, seed: int | None = None,
                   meta: Mapping[str, Any] | None = None, n_planned: int | None = None, *,
                   calibration: Any = None, run_id: str | None = None) -> str:
        """Create a run with status ``running``; return its id.

        Parameters
        ----------
        kind : one of :data:`RUN_KINDS`
        plan, bench, calibration : JSON-serialisable (numpy values are converted)
            The plan as given, the bench configuration, the calibration used.
        seed : int, optional
            Root seed of any virtual device.
        meta : mapping, optional
            Anything else (specimen, operator, notes); comes back in :meth:`to_record`.
        n_planned : int, optional
            Points the plan holds (for progress and ``summary``).
        run_id : str, optional
            An explicit id (default: :func:`new_run_id`).
        """
        if kind not in RUN_KINDS:
            raise InputError(f"run kind must be one of {', '.join(RUN_KINDS)}, got {kind!r}")
        if n_planned is not None and (not isinstance(n_planned, (int, np.integer)) or n_planned < 0):
            raise InputError(f"n_planned must be an integer >= 0, got {n_planned!r}")
        iso, t = _now()
        fields = (kind, "running", None, iso, t, iso, t, _dumps(plan), _dumps(bench),
                  _dumps(package_versions()), None if seed is None else int(seed), _dumps(calibration),
                  _dumps(dict(meta or {})), None if n_planned is None else int(n_planned))
        for attempt in range(20):
            rid = run_id if run_id is not None else new_run_id(t)
            try:
                with self._transaction() as db:
                    db.execute("INSERT INTO runs (run_id, kind, status, reason, created_utc, created_epoch, "
                               "started_utc, started_epoch, plan, bench, versions, seed, calibration, meta, "
                               "n_planned) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)", (rid, *fields))
                    db.execute("INSERT INTO run_events VALUES (?,?,?,?,?)", (rid, iso, t, "running", "created"))
                return rid
            except sqlite3.IntegrityError:
                if run_id is not None:
                    raise StoreError(f"run id {run_id!r} already exists in {self.path}") from None
        raise StoreError(f"{self.path}: could not find a free run id")  # pragma: no cover

    def _status(self, run_id: str) -> str:
        row = self._db.execute("SELECT status FROM runs WHERE run_id = ?", (run_id,)).fetchone()
        if row is None:
            raise self._unknown(run_id)
        return row[0]

    def _unknown(self, run_id: str) -> StoreError:
        return StoreError(f"unknown run {run_id!r} in {self.path}; list the run ids with "
                          f"`bench runs --store {self.path}` (or RunStore.runs())")

    def set_status(self, run_id: str, status: str, reason: str | None = None) -> None:
        """Change a run's status (``running`` -> ``completed`` | ``interrupted`` | ``failed``;
        ``interrupted``/``failed`` -> ``running`` to resume). ``completed`` is final.

        Sets ``finished_*`` on entering a final or interrupted state and clears it on resume;
        every change is appended to the run's event history.
        """
        if status not in RUN_STATUSES:
            raise InputError(f"status must be one of {', '.join(RUN_STATUSES)}, got {status!r}")
        iso, t = _now()
        with self._transaction() as db:
            old = self._status(run_id)
            if status != old and status not in _TRANSITIONS[old]:
                raise StoreError(f"run {run_id!r}: cannot go from {old!r} to {status!r} "
                                 f"(allowed: {', '.join(sorted(_TRANSITIONS[old])) or 'none'})")
            if status == "running":
                db.execute("UPDATE runs SET status=?, reason=?, finished_utc=NULL, finished_epoch=NULL "
                           "WHERE run_id=?", (status, reason, run_id))
            else:
                db.execute("UPDATE runs SET status=?, reason=?, finished_utc=?, finished_epoch=? WHERE run_id=?",
                           (status, reason, iso, t, run_id))
            db.execute("INSERT INTO run_events VALUES (?,?,?,?,?)", (run_id, iso, t, status, reason))

    def update_meta(self, run_id: str, **fields: Any) -> None:
        """Merge keys into a run's ``meta`` JSON (one transaction)."""
        with self._transaction() as db:
            row = db.execute("SELECT meta FROM runs WHERE run_id=?", (run_id,)).fetchone()
            if row is None:
                raise self._unknown(run_id)
            meta = _loads(row[0]) or {}
            meta.update(fields)
            db.execute("UPDATE runs SET meta=? WHERE run_id=?", (_dumps(meta), run_id))

    def set_calibration(self, run_id: str, calibration: Any) -> None:
        """Store (replace) the calibration JSON of a run."""
        with self._transaction() as db:
            self._status(run_id)
            db.execute("UPDATE runs SET calibration=? WHERE run_id=?", (_dumps(calibration), run_id))

    def delete_run(self, run_id: str) -> None:
        """Remove a run with all its points and readings (one transaction)."""
        with self._transaction() as db:
            self._status(run_id)
            db.execute("DELETE FROM readings WHERE run_id=?", (run_id,))
            db.execute("DELETE FROM points WHERE run_id=?", (run_id,))
            db.execute("DELETE FROM run_events WHERE run_id=?", (run_id,))
            db.execute("DELETE FROM runs WHERE run_id=?", (run_id,))

    # -- points ------------------------------------------------------------------------------
    def add_point(self, run_id: str, idx: int, geometry: Mapping[str, Any] | Any,
                  rows: Sequence[Mapping[str, Any]] | Any, t_start: float | None = None,
                  t_end: float | None = None, status: str = "ok") -> int:
        """Store one measured point and all its readings in ONE transaction; return rows written.

        Parameters
        ----------
        run_id : str
        idx : int
            The point's index in the plan (>= 0). An index already stored raises
            :class:`StoreError` naming the run and index; nothing is written.
        geometry : mapping or Geometry
            ``theta_i, phi_i, theta_r, phi_r`` in degrees (``theta_r/phi_r`` may be None for a
            whole-sphere point whose rows carry their own viewing directions).
        rows : list of dicts or pandas.DataFrame
            One entry per wavelength (and viewing direction): keys of :data:`READING_COLUMNS`;
            any other key (except point-level ones such as ``theta_i``) goes to ``extra`` JSON.
        t_start, t_end : float, optional
            Epoch seconds (default: now).
        status : str
            Point status, e.g. ``"ok"``, ``"saturated"``.

        Raises
        ------
        StoreError
            Unknown run, a completed run, or a duplicate index.
        InputError
            A malformed row (no wavelength, a value that is not a number).
        """
        if not isinstance(idx, (int, np.integer)) or isinstance(idx, bool) or idx < 0:
            raise InputError(f"point index must be an integer >= 0, got {idx!r}")
        idx = int(idx)
        g = geometry.as_dict() if hasattr(geometry, "as_dict") else dict(geometry)
        geo = tuple(_py(g.get(k)) for k in _GEOMETRY)
        tuples = _reading_tuples(run_id, idx, rows)
        now = time.time()
        t0 = now if t_start is None else float(t_start)
        t1 = now if t_end is None else float(t_end)
        db = self._db
        with self._transaction():
            try:
                db.execute("INSERT INTO points (run_id, idx, theta_i, phi_i, theta_r, phi_r, t_start, t_end, "
                           "status, n_readings) VALUES (?,?,?,?,?,?,?,?,?,?)",
                           (run_id, idx, *geo, t0, t1, status, len(tuples)))
            except sqlite3.IntegrityError as e:
                msg = str(e)
                if "UNIQUE" in msg:
                    raise StoreError(f"run {run_id!r} already has point {idx}; refusing a duplicate "
                                     f"(done_indices() says which points are stored)") from None
                if "completed" in msg:
                    raise StoreError(f"run {run_id!r} is completed; refusing to add point {idx}") from None
                if "FOREIGN KEY" in msg:
                    raise self._unknown(run_id) from None
                raise StoreError(f"run {run_id!r} point {idx}: {msg}") from None
            if tuples:
                db.executemany(_INSERT_READING, tuples)
        return len(tuples)

    def done_indices(self, run_id: str) -> set[int]:
        """Indices of the points stored (committed) for a run."""
        self._status(run_id)
        return {r[0] for r in self._db.execute("SELECT idx FROM points WHERE run_id=?", (run_id,))}

    def add_record(self, run_id: str, record: BSDFRecord, *, start_idx: int | None = None,
                   merge_meta: bool = True) -> list[int]:
        """Store a whole :class:`BSDFRecord` as points, one per incidence ``(theta_i, phi_i)``
        (in order of first appearance), each in its own transaction; return the indices used.

        Rows keep their viewing directions (``theta_r, phi_r``) and patch columns. Indices start
        at ``start_idx`` (default: one past the largest stored). With ``merge_meta`` the record's
        meta is merged into the run's meta (keys already in the run's meta win).
        """
        import pandas as pd

        table = record.table
        if not isinstance(table, pd.DataFrame):
            raise InputError(f"record.table must be a pandas DataFrame, got {type(table).__name__}")
        missing = [c for c in ("wavelength_nm", "theta_i", "phi_i") if c not in table.columns]
        if missing:
            raise InputError(f"record has no column(s) {', '.join(missing)}")
        self._status(run_id)
        if start_idx is None:
            row = self._db.execute("SELECT MAX(idx) FROM points WHERE run_id=?", (run_id,)).fetchone()
            start_idx = 0 if row[0] is None else int(row[0]) + 1
        used = []
        groups = table.groupby(["theta_i", "phi_i"], sort=False)
        for k, ((ti, pi_), part) in enumerate(groups):
            idx = start_idx + k
            self.add_point(run_id, idx, {"theta_i": ti, "phi_i": pi_, "theta_r": None, "phi_r": None}, part)
            used.append(idx)
        if merge_meta and record.meta:
            with self._transaction() as db:
                cur = _loads(db.execute("SELECT meta FROM runs WHERE run_id=?", (run_id,)).fetchone()[0]) or {}
                merged = {**record.meta, **cur}
                db.execute("UPDATE runs SET meta=? WHERE run_id=?", (_dumps(merged), run_id))
        return used

    # -- reading back ------------------------------------------------------------------------
    def _run_row(self, run_id: str) -> dict[str, Any]:
        cur = self._db.execute("SELECT * FROM runs WHERE run_id=?", (run_id,))
        row = cur.fetchone()
        if row is None:
            raise self._unknown(run_id)
        d = dict(zip([c[0] for c in cur.description], row))
        for k in ("plan", "bench", "versions", "calibration", "meta"):
            d[k] = _loads(d[k])
        return d

    def runs(self) -> list[dict[str, Any]]:
        """All runs, oldest first: id, kind, status, reason, created/finished (UTC ISO),
        points done and planned (for ``bench runs``)."""
        cur = self._db.execute(
            "SELECT r.run_id, r.kind, r.status, r.reason, r.created_utc, r.finished_utc, r.n_planned, "
            "r.seed, (SELECT COUNT(*) FROM points p WHERE p.run_id = r.run_id) "
            "FROM runs r ORDER BY r.created_epoch, r.run_id")
        keys = ("run_id", "kind", "status", "reason", "created_utc", "finished_utc", "n_planned", "seed",
                "points_done")
        return [dict(zip(keys, r)) for r in cur.fetchall()]

    def run(self, run_id: str) -> dict[str, Any]:
        """A run's metadata (JSON fields decoded), status history and counts
        (``points_done``, ``readings``)."""
        d = self._run_row(run_id)
        d["points_done"] = self._db.execute("SELECT COUNT(*) FROM points WHERE run_id=?", (run_id,)).fetchone()[0]
        d["readings"] = self._db.execute("SELECT COUNT(*) FROM readings WHERE run_id=?", (run_id,)).fetchone()[0]
        d["events"] = [dict(zip(("t_utc", "t_epoch", "status", "reason"), r)) for r in self._db.execute(
            "SELECT t_utc, t_epoch, status, reason FROM run_events WHERE run_id=? ORDER BY rowid", (run_id,))]
        return d

    def points(self, run_id: str) -> Any:
        """The points table of a run (one row per point) as a ``pandas.DataFrame``."""
        import pandas as pd

        self._status(run_id)
        return pd.read_sql_query("SELECT idx, theta_i, phi_i, theta_r, phi_r, t_start, t_end, status, n_readings "
                                 "FROM points WHERE run_id=? ORDER BY idx", self._db, params=(run_id,))

    def readings(self, run_id: str, *, expand_extra: bool = True) -> Any:
        """Tidy ``pandas.DataFrame``: one row per point x wavelength (x viewing direction).

        Columns: ``idx, theta_i, phi_i, theta_r, phi_r`` (a row's own viewing direction when it
        has one, else the point's), ``wavelength_nm``, the value columns, ``t_start, t_end,
        point_status``; ``extra`` keys become columns when ``expand_extra`` (else one JSON column).
        Ordered by point index, then insertion order.
        """
        import pandas as pd

        self._status(run_id)
        value_cols = [c for c in READING_COLUMNS if c not in ("wavelength_nm", "theta_r", "phi_r")]
        sql = ("SELECT r.idx AS idx, p.theta_i AS theta_i, p.phi_i AS phi_i, "
               "COALESCE(r.theta_r, p.theta_r) AS theta_r, COALESCE(r.phi_r, p.phi_r) AS phi_r, "
               "r.wavelength_nm AS wavelength_nm, "
               + ", ".join(f"r.{c} AS {c}" for c in value_cols)
               + ", p.t_start AS t_start, p.t_end AS t_end, p.status AS point_status, r.extra AS extra "
               "FROM readings r JOIN points p ON p.run_id = r.run_id AND p.idx = r.idx "
               "WHERE r.run_id = ? ORDER BY r.idx, r.rowid")
        df = pd.read_sql_query(sql, self._db, params=(run_id,))
        float_cols = [c for c in ("theta_i", "phi_i", "theta_r", "phi_r", "wavelength_nm", "signal", "dark",
                                  "white", "value", "std", "ci_lo", "ci_hi", "theta_min", "theta_max",
                                  "phi_min", "phi_max", "psa", "t_start", "t_end")]
        for c in float_cols:
            df[c] = pd.to_numeric(df[c], errors="coerce").astype(float)
        for c in ("count", "N", "saturated"):
            col = df[c]
            df[c] = col.astype("int64") if len(col) and col.notna().all() else col.astype("Int64")
        if expand_extra:
            extra = df.pop("extra")
            present = extra.notna()
            if present.any():
                parsed = pd.DataFrame([json.loads(x) if isinstance(x, str) else {} for x in extra],
                                      index=df.index)
                for c in parsed.columns:
                    if c not in df.columns:
                        df[c] = parsed[c]
        return df

    def to_record(self, run_id: str) -> BSDFRecord:
        """The run as a :class:`BSDFRecord`: readings mapped onto :data:`BSDF_COLUMNS` (missing
        columns NaN; ``hemisphere`` from ``theta_r`` when not stored) plus the extra columns
        ``idx``, ``signal``, ``dark``, ``white``, ``saturated`` when they hold data. ``meta`` is the
        run's meta with ``run_id, kind, status, seed, plan, bench, calibration, versions`` added."""
        import pandas as pd

        df = self.readings(run_id)
        out = pd.DataFrame(index=df.index)
        for c in BSDF_COLUMNS:
            out[c] = df[c] if c in df.columns else np.nan
        if len(df):
            hemi = np.where(df["theta_r"].to_numpy(float) > 90.0, "T", "R")
            out["hemisphere"] = df["hemisphere"].where(df["hemisphere"].notna(), pd.Series(hemi, index=df.index))
        for c in ("idx", "signal", "dark", "white", "saturated"):
            if c in df.columns and (c == "idx" or df[c].notna().any()):
                out[c] = df[c]
        info = self._run_row(run_id)
        meta = dict(info.get("meta") or {})
        for k in ("run_id", "kind", "status", "reason", "seed", "plan", "bench", "calibration", "versions",
                  "created_utc", "finished_utc"):
            meta.setdefault(k, info.get(k))
        return BSDFRecord(out, meta)

    def summary(self, run_id: str) -> dict[str, Any]:
        """What ``bench show`` prints: status, reason, points done / planned, wavelengths,
        geometry ranges, timings and value range (all JSON-serialisable)."""
        info = self._run_row(run_id)
        db = self._db
        n_pts, n_read = db.execute(
            "SELECT COUNT(*), COALESCE(SUM(n_readings), 0) FROM points WHERE run_id=?", (run_id,)).fetchone()
        first, last, t_sum, t_max = db.execute(
            "SELECT MIN(t_start), MAX(t_end), SUM(t_end - t_start), MAX(t_end - t_start) FROM points "
            "WHERE run_id=?", (run_id,)).fetchone()
        geo = {}
        for k in ("theta_i", "phi_i"):
            lo, hi = db.execute(f"SELECT MIN({k}), MAX({k}) FROM points WHERE run_id=?", (run_id,)).fetchone()
            geo[k] = [lo, hi]
        for k in ("theta_r", "phi_r"):
            lo, hi = db.execute(f"SELECT MIN(COALESCE(r.{k}, p.{k})), MAX(COALESCE(r.{k}, p.{k})) FROM readings r "
                                f"JOIN points p ON p.run_id=r.run_id AND p.idx=r.idx WHERE r.run_id=?",
                                (run_id,)).fetchone()
            geo[k] = [lo, hi]
        wl = [r[0] for r in db.execute("SELECT DISTINCT wavelength_nm FROM readings WHERE run_id=? "
                                       "ORDER BY wavelength_nm", (run_id,))]
        vmin, vmax, n_val, n_sat = db.execute(
            "SELECT MIN(value), MAX(value), COUNT(value), COALESCE(SUM(saturated), 0) FROM readings "
            "WHERE run_id=?", (run_id,)).fetchone()
        missing = None
        if info["n_planned"] is not None:
            done = self.done_indices(run_id)
            missing = sorted(set(range(info["n_planned"])) - done)
        end = info["finished_epoch"] if info["finished_epoch"] is not None else last
        return {
            "run_id": run_id, "kind": info["kind"], "status": info["status"], "reason": info["reason"],
            "points_done": n_pts, "points_planned": info["n_planned"],
            "points_missing": None if missing is None else len(missing),
            "first_missing": None if not missing else missing[0],
            "readings": n_read,
            "wavelengths": {"n": len(wl), "min": wl[0] if wl else None, "max": wl[-1] if wl else None},
            "geometry": geo,
            "timing": {"created_utc": info["created_utc"], "started_utc": info["started_utc"],
                       "finished_utc": info["finished_utc"],
                       "elapsed_s": None if end is None else end - info["started_epoch"],
                       "first_point_epoch": first, "last_point_epoch": last,
                       "mean_point_s": None if not n_pts or t_sum is None else t_sum / n_pts,
                       "max_point_s": t_max},
            "value": {"min": vmin, "max": vmax, "n": n_val, "n_missing": n_read - n_val},
            "saturated": n_sat, "seed": info["seed"],
        }


_INSERT_READING = (f"INSERT INTO readings (run_id, idx, {', '.join(READING_COLUMNS)}, extra) "
                   f"VALUES ({', '.join('?' * (len(READING_COLUMNS) + 3))})")


_FAST_TYPES = frozenset({float, int, bool, type(None), np.float64})
_NUMERIC = READING_COLUMNS[:-1]  # hemisphere (text) is last
_KNOWN_KEYS = frozenset(READING_COLUMNS) | _POINT_LEVEL


def _reading_tuples(run_id: str, idx: int, rows: Any) -> list[tuple]:
    """Rows (list of mappings or a DataFrame) as tuples for ``_INSERT_READING``.

    The common case (plain floats/ints/bools, a string hemisphere, no other keys) takes a fast
    path; anything else (numpy scalars, extra keys) is converted value by value. NaN is bound
    as is: SQLite stores a NaN as NULL.
    """
    pd = sys.modules.get("pandas")  # a DataFrame implies pandas is loaded; a scan loop needn't load it
    if pd is not None and isinstance(rows, pd.DataFrame):
        return _frame_tuples(run_id, idx, rows)
    if isinstance(rows, Mapping):
        raise InputError(f"run {run_id!r} point {idx}: rows must be a list of dicts or a DataFrame, "
                         f"got one mapping")
    out = []
    fast = _FAST_TYPES
    for j, r in enumerate(rows):
        if type(r) is not dict and not isinstance(r, Mapping):
            raise InputError(f"run {run_id!r} point {idx}: reading {j} is {type(r).__name__}, not a mapping")
        nums = tuple(map(r.get, _NUMERIC))
        hem = r.get("hemisphere")
        if (fast.issuperset(map(type, nums)) and (hem is None or type(hem) is str)
                and _KNOWN_KEYS.issuperset(r.keys())):
            if nums[0] is None:
                raise InputError(f"run {run_id!r} point {idx}: reading {j} has no wavelength_nm")
            out.append((run_id, idx, *nums, hem, None))
            continue
        vals: list[Any] = []
        for c, v in zip(_NUMERIC, nums):
            v = _py(v)
            if v is not None:
                v = int(v) if c in _INT_COLUMNS else _num(run_id, idx, c, v)
            vals.append(v)
        if vals[0] is None:
            raise InputError(f"run {run_id!r} point {idx}: reading {j} has no wavelength_nm")
        hem = _py(hem)
        extra = {k: _py(v) for k, v in r.items() if k not in _KNOWN_KEYS}
        out.append((run_id, idx, *vals, None if hem is None else str(hem), _dumps(extra) if extra else None))
    return out


def _frame_tuples(run_id: str, idx: int, rows: Any) -> list[tuple]:
    names = [str(c) for c in rows.columns]
    if "wavelength_nm" not in names:
        raise InputError(f"run {run_id!r} point {idx}: readings have no wavelength_nm column")
    n = len(rows)
    columns = []
    for c in READING_COLUMNS:
        if c not in rows.columns:
            columns.append([None] * n)
            continue
        v = rows[c]
        if c in _INT_COLUMNS:
            columns.append([None if x is None or (isinstance(x, float) and math.isnan(x)) else int(x)
                            for x in v.tolist()])
        elif c == "hemisphere":
            columns.append([None if x is None or (isinstance(x, float) and math.isnan(x)) else str(x)
                            for x in v.tolist()])
        else:
            try:
                vals = v.to_numpy(dtype=float, na_value=np.nan)
            except (TypeError, ValueError):
                vals = np.asarray([_num(run_id, idx, c, x) for x in v.tolist()], dtype=float)
            columns.append(vals.tolist())
    extra_names = [c for c in names if c not in _KNOWN_KEYS]
    if extra_names:
        recs = rows[extra_names].to_dict("records")
        extras = [_dumps({k: _py(v) for k, v in r.items()}) for r in recs]
    else:
        extras = [None] * n
    if any(x is None or x != x for x in columns[0]):
        raise InputError(f"run {run_id!r} point {idx}: a reading has no wavelength_nm")
    return [(run_id, idx, *vals, ex) for *vals, ex in zip(*columns, extras)]


def _num(run_id: str, idx: int, col: str, v: Any) -> float | None:
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise InputError(f"run {run_id!r} point {idx}: {col} must be a number, got {v!r}") from None
    return None if math.isnan(f) else f
