"""What every ``bench`` command group shares: the default store, JSON output, argument types,
durations, opening a store and reporting a run.

Imports nothing heavy (the CLI must start fast); the store module loads when a command opens one.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

__all__ = ["DEFAULT_STORE", "emit_json", "positive_int", "number", "hms", "open_store", "report_run"]

#: the run store every command uses when ``--store`` is not given
DEFAULT_STORE = "goniobench-runs.sqlite"


def emit_json(obj: Any) -> None:
    """Print ``obj`` as one line of JSON (the project's one encoder, :func:`bench.core.records.json_default`)."""
    from bench.core.records import json_default

    print(json.dumps(obj, indent=None, sort_keys=False, default=json_default))


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (``1e7`` accepted)."""
    try:
        v = int(float(text)) if "e" in text.lower() else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def number(text: str) -> float:
    """argparse type: a float."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def hms(seconds: float) -> str:
    """``H:MM:SS`` of a duration in seconds."""
    s = int(round(seconds))
    return f"{s // 3600:d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def open_store(path: str, create: bool = True) -> Any:
    """The :class:`bench.store.RunStore` at ``path``."""
    from bench.store import RunStore

    return RunStore(path, create=create)


def report_run(result: Any, as_json: bool) -> int:
    """What scan and resume print: the run id (or the result as JSON)."""
    if as_json:
        emit_json(result.__dict__)
    else:
        print(result.run_id)
    return 0
