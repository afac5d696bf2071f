"""Test helper: watch a run store from outside the process that writes it (crash tests)."""

import os
import signal
import sqlite3
import subprocess
import time


def committed_points(db_path) -> int:
    """Points committed so far, read through a read-only connection (0 before the store exists)."""
    try:
        con = sqlite3.connect(f"file:{db_path}?mode=ro", uri=True, timeout=5)
        try:
            return con.execute("SELECT COUNT(*) FROM points").fetchone()[0]
        finally:
            con.close()
    except sqlite3.Error:
        return 0


def kill_once_committed(proc: subprocess.Popen, db_path, n_points: int, poll_s: float = 0.005,
                        give_up_s: float = 60.0) -> None:
    """SIGKILL ``proc`` (a scan or sweep writing ``db_path``) once ``n_points`` points are
    committed; sooner if it ended by itself or ``give_up_s`` passed (a guard, not a speed bound)."""
    deadline = time.monotonic() + give_up_s
    while committed_points(db_path) < n_points and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(poll_s)
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
