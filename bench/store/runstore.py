"""The run store's write side: :class:`RunStore` opens or creates the SQLite file, checks and
migrates its schema, creates runs, moves their status, and stores each point in one transaction.
Reading back is :class:`bench.store.reading.RunReader`.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import sqlite3
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bench.core.errors import BenchError, InputError, StoreError
from bench.core.records import BSDFRecord
from bench.core.roles import Closing
from bench.store.check import valid_run_id
from bench.store.reading import RunReader
from bench.store.rows import _INSERT_READING, _reading_tuples
from bench.store.owner import _OWNERS_TABLE, claim_run, owner_state
from bench.store.schema import (_GEOMETRY, _MIGRATIONS, _SCHEMA, _TRANSITIONS, RUN_KINDS, RUN_STATUSES, SCHEMA_VERSION,
                                _dumps, _loads, _now, _py, new_run_id, package_versions)

__all__ = ["RunStore"]

log = logging.getLogger(__name__)


def _typed_errors(cls: type) -> type:
    """Wrap every public method so an SQLite failure that escapes it (a corrupted page, a dropped
    table, an I/O error) is a :class:`StoreError` naming the file, never a raw ``sqlite3`` error."""

    def wrap(fn: Any) -> Any:
        @functools.wraps(fn)
        def method(self: Any, *a: Any, **kw: Any) -> Any:
            try:
                return fn(self, *a, **kw)
            except (sqlite3.ProgrammingError, sqlite3.InterfaceError):
                raise  # a bug in the caller or in goniobench, not a problem of the file
            except sqlite3.Error as e:
                raise StoreError(f"run store {self.path}: {e}") from e
            except (UnicodeEncodeError, UnicodeDecodeError) as e:  # a run id that is not text (a non-UTF-8 argument)
                raise InputError(f"run store {self.path}: not valid text: {e.reason}") from None

        return method

    # each public name's definition as the class resolves it (its own over its bases'), collected
    # before any is replaced: wrapping a base's method first would hide the class's own
    methods = {}
    for klass in reversed(cls.__mro__[:-1]):
        for name, fn in vars(klass).items():
            if not name.startswith("_") and callable(fn) and not isinstance(fn, (staticmethod, classmethod, type)):
                methods[name] = fn
    for name, fn in methods.items():
        setattr(cls, name, wrap(fn))
    return cls


@_typed_errors
class RunStore(RunReader, Closing):
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
                 create: bool = True, readonly: bool = False) -> None:
        self.path = Path(path)
        self.readonly = bool(readonly)
        sync = str(synchronous).upper()
        if sync not in ("NORMAL", "FULL"):
            raise InputError(f"synchronous must be 'NORMAL' or 'FULL', got {synchronous!r}")
        if not (isinstance(timeout, (int, float)) and timeout >= 0 and math.isfinite(timeout)):
            raise InputError(f"timeout must be a number of seconds >= 0, got {timeout!r}")
        try:
            exists = self.path.exists()
            if exists and self.path.is_dir():
                raise StoreError(f"run store {self.path} is a folder, not a file")
            if not exists:
                if not create or self.readonly:
                    raise StoreError(f"no run store at {self.path}")
                self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a parent that is a file, a symlink loop, no permission
            raise StoreError(f"run store {self.path}: {exc.strerror or exc}") from None
        self.timeout = float(timeout)
        self.synchronous = sync
        self._db = self._connect()
        try:
            self._db.execute(f"PRAGMA busy_timeout = {int(self.timeout * 1000)}")
            self._refuse_foreign()  # before anything is written (no WAL switch on a foreign file)
            if not create and not self._tables():  # an empty file is no store to resume from: write nothing
                raise StoreError(f"{self.path} is not a goniobench run store (an empty file)")
            if self.readonly:
                self._check_schema_readonly()
                return
            mode = self._db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{self.path}: could not switch to WAL mode (journal_mode={mode})")
            self._db.execute(f"PRAGMA synchronous = {sync}")
            self._db.execute("PRAGMA foreign_keys = ON")
            self._ensure_schema()
            self._require_tables()
            self._db.execute(_OWNERS_TABLE)
        except sqlite3.DatabaseError as e:
            self._db.close()
            if not self.readonly and not (os.access(self.path, os.W_OK) and os.access(self.path.parent, os.W_OK)):
                raise StoreError(f"run store {self.path} cannot be written here (a read-only file, folder or "
                                 f"file system); readers such as `bench runs` still work on it") from e
            raise StoreError(f"{self.path} is not a usable run store: {e}") from e
        except BaseException:
            self._db.close()
            raise

    def _connect(self) -> sqlite3.Connection:
        """A connection: read-write, or (``readonly``) a ``mode=ro`` URI that can never change the
        file; a store in a read-only folder whose WAL index cannot be created is opened immutable."""
        try:
            if not self.readonly:
                return sqlite3.connect(str(self.path), timeout=self.timeout, isolation_level=None)
            uri = self.path.resolve().as_uri()
            db = sqlite3.connect(f"{uri}?mode=ro", uri=True, timeout=self.timeout, isolation_level=None)
            try:
                db.execute("SELECT 1 FROM sqlite_master LIMIT 1").fetchall()
            except sqlite3.OperationalError:
                db.close()
                wal = self.path.with_name(self.path.name + "-wal")
                if wal.exists():  # a writer may be active: immutable would miss its commits
                    raise
                db = sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, timeout=self.timeout,
                                     isolation_level=None)
            return db
        except sqlite3.Error as e:
            raise StoreError(f"cannot open run store {self.path}: {e}") from e

    def _refuse_foreign(self) -> None:
        tables = self._tables()
        if tables and "schema_version" not in tables:
            raise StoreError(f"{self.path} is an SQLite file but not a goniobench run store "
                             f"(tables: {', '.join(sorted(tables))}; no schema_version)")

    def _require_tables(self) -> None:
        """Refuse a store that lost a table, before a run is created in it."""
        missing = {"schema_version", "runs", "points", "readings", "run_events"} - self._tables()
        if missing:
            raise StoreError(f"{self.path} is not a complete goniobench run store (missing table(s) "
                             f"{', '.join(sorted(missing))})")

    def _check_schema_readonly(self) -> None:
        self._require_tables()
        version = self._db.execute("SELECT MAX(version) FROM schema_version").fetchone()[0]
        if version is None or version != SCHEMA_VERSION:
            raise StoreError(f"{self.path} has store schema version {version}; this goniobench reads "
                             f"version {SCHEMA_VERSION} (open it once for writing to migrate an older one)")

    # -- lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Close the connection (committed data is already safe)."""
        self._db.close()

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
        if run_id is not None and not valid_run_id(run_id):  # an id may become a file name or a URL
            raise InputError(f"run id {run_id!r} is not of the store's format (letters, digits, '._:-', starting "
                             f"with a letter or digit, at most 128 characters)")
        if n_planned is not None and (not isinstance(n_planned, (int, np.integer)) or n_planned < 0):
            raise InputError(f"n_planned must be an integer >= 0, got {n_planned!r}")
        iso, t = _now()
        fields = (kind, "running", None, iso, t, iso, t, _dumps(plan), _dumps(bench),
                  _dumps(package_versions()), None if seed is None else int(seed), _dumps(calibration),
                  _dumps(dict(meta or {})), None if n_planned is None else int(n_planned))
        for _attempt in range(20):
            rid = run_id if run_id is not None else new_run_id(t)
            try:
                with self._transaction() as db:
                    db.execute("INSERT INTO runs (run_id, kind, status, reason, created_utc, created_epoch, "
                               "started_utc, started_epoch, plan, bench, versions, seed, calibration, meta, "
                               "n_planned) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)", (rid, *fields))
                    db.execute("INSERT INTO run_events VALUES (?,?,?,?,?)", (rid, iso, t, "running", "created"))
                    claim_run(db, rid)
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

    def _owned_here(self, run_id: str) -> bool:
        row = self._db.execute("SELECT pid FROM run_owners WHERE run_id=?", (run_id,)).fetchone()
        return row is not None and int(row[0]) == os.getpid()

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
            if status == "running" and old == "running" and owner_state(db, run_id) == "alive" \
                    and not self._owned_here(run_id):
                raise StoreError(f"run {run_id!r} is still being measured by another process; wait for it, "
                                 f"or stop it first")
            if status == "running":
                claim_run(db, run_id)
                db.execute("UPDATE runs SET status=?, reason=?, finished_utc=NULL, finished_epoch=NULL "
                           "WHERE run_id=?", (status, reason, run_id))
            else:
                db.execute("UPDATE runs SET status=?, reason=?, finished_utc=?, finished_epoch=? WHERE run_id=?",
                           (status, reason, iso, t, run_id))
            db.execute("INSERT INTO run_events VALUES (?,?,?,?,?)", (run_id, iso, t, status, reason))

    def record_failure(self, run_id: str, exc: BaseException) -> None:
        """Mark ``run_id`` failed (resumable) with ``exc`` as the reason, after an error the run's
        own handling did not expect, so that no run stays ``running``; a store too broken to
        take it is only logged (the error being raised matters more)."""
        try:
            self.set_status(run_id, "failed", f"{type(exc).__name__}: {exc}"[:500])
        except (BenchError, sqlite3.Error, OSError) as err:
            log.warning("run %s: could not record the failure (%s)", run_id, err)

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
        import pandas as pd  # lazily: neither a scan loop nor `bench runs` needs pandas

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

