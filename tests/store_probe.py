"""Test helper: watch a run store from outside the process that writes it (crash tests)."""

import sqlite3


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
