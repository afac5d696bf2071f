"""The run store's schema and the small helpers around it: table definitions, run kinds and
statuses and their transitions, reading columns, JSON and time stamps, run ids, package versions.
"""

from __future__ import annotations

import json
import math
import platform
import secrets
import sqlite3
import time
from datetime import datetime, timezone
from typing import Any

import numpy as np

from bench.core.records import json_default


__all__ = ["SCHEMA_VERSION", "RUN_KINDS", "RUN_STATUSES", "READING_COLUMNS", "new_run_id", "package_versions"]

SCHEMA_VERSION = 1
RUN_KINDS = ("scan", "sweep", "calibration", "import", "virtual", "bluesky", "fit", "check")
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
