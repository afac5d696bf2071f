"""Which process owns a running run, and whether it is still alive (survives SIGKILL).

A run in status ``running`` whose process was killed would show ``running`` for ever. The store
records, in a side table ``run_owners`` (created on the first write-open; readers tolerate its
absence), the owner's host, pid and process start time whenever a run starts or resumes. A run
is *gone* when it is on this host and no process with that pid and start time exists (a reused
pid has another start time). On another host nothing can be known: the state is ``unknown``.
"""

from __future__ import annotations

import os
import socket
import sqlite3
from typing import Literal

__all__ = ["claim_run", "owner_state", "process_identity", "process_state"]

_OWNERS_TABLE = ("CREATE TABLE IF NOT EXISTS run_owners (run_id TEXT PRIMARY KEY, host TEXT NOT NULL, "
                 "pid INTEGER NOT NULL, started REAL)")

OwnerState = Literal["alive", "gone", "unknown"]


def _start_time(pid: int) -> float | None:
    """The start time of process ``pid`` (seconds, comparable between calls), or None if none."""
    try:
        import psutil

        try:
            return round(float(psutil.Process(pid).create_time()), 2)
        except (psutil.NoSuchProcess, psutil.ZombieProcess):
            return None
        except psutil.AccessDenied:
            return -1.0  # it exists; we may not look at it
    except ImportError:  # Linux without psutil: /proc/PID/stat field 22 (clock ticks since boot)
        try:
            with open(f"/proc/{pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
            return float(fields[19])
        except (OSError, IndexError, ValueError):
            return None


def process_identity() -> tuple[str, int, float | None]:
    """(host, pid, start time) of this process."""
    return socket.gethostname(), os.getpid(), _start_time(os.getpid())


def claim_run(db: sqlite3.Connection, run_id: str) -> None:
    """Record this process as the owner of ``run_id`` (inside the caller's transaction)."""
    host, pid, started = process_identity()
    db.execute("INSERT OR REPLACE INTO run_owners (run_id, host, pid, started) VALUES (?,?,?,?)",
               (run_id, host, pid, started))


def owner_state(db: sqlite3.Connection, run_id: str) -> OwnerState:
    """``alive``, ``gone`` (the owning process no longer exists) or ``unknown`` (no record, or
    another host)."""
    try:
        row = db.execute("SELECT host, pid, started FROM run_owners WHERE run_id=?", (run_id,)).fetchone()
    except sqlite3.OperationalError:  # a store written before owners were recorded
        return "unknown"
    if row is None:
        return "unknown"
    host, pid, started = row
    return process_state(str(host), int(pid), None if started is None else float(started))


def process_state(host: str, pid: int, started: float | None) -> OwnerState:
    """Whether the process ``(host, pid, started)`` (as :func:`process_identity` gave it) still
    runs: ``alive``, ``gone`` (no such process, or the pid reused by another) or ``unknown``
    (another host)."""
    if host != socket.gethostname():
        return "unknown"
    now = _start_time(int(pid))
    if now is None:
        return "gone"
    if now == -1.0 or started is None or abs(now - float(started)) < 0.05:
        return "alive"
    return "gone"  # the pid was reused by another process
