"""What every ``bench`` command group shares: the default store, JSON output, argument types,
durations, opening a store and reporting a run.

Imports nothing heavy (the CLI must start fast); the store module loads when a command opens one.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

from bench.cli.argtypes import real, renamed
from bench.core.errors import InputError
from bench.core.outputs import check_target

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading the store or the runner
    from bench.runner import ScanResult
    from bench.store import RunStore

__all__ = ["DEFAULT_STORE", "emit_json", "number", "hms", "open_store", "report_run",
           "output_file", "output_dir", "check_output", "add_force_option", "check_outputs", "PLOT_SUFFIXES",
           "announce_compilation", "stop_announcing", "add_service_time_limit"]

#: image formats matplotlib writes (checked before any work, so a typo does not cost the run)
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".eps", ".ps", ".tif", ".tiff", ".webp",
                 ".pgf", ".raw", ".rgba")

#: the run store every command uses when ``--store`` is not given
DEFAULT_STORE = "goniobench-runs.sqlite"


def emit_json(obj: Any) -> None:
    """Print ``obj`` as one line of JSON (the project's one encoder, :func:`bench.core.records.json_default`)."""
    from bench.core.records import json_default

    print(json.dumps(obj, indent=None, sort_keys=False, default=json_default))


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


def open_store(path: str, create: bool = True, readonly: bool = False) -> RunStore:
    """The :class:`bench.store.RunStore` at ``path`` (``readonly``: a reader that never changes the file)."""
    from bench.store import RunStore

    return RunStore(path, create=create, readonly=readonly)


def check_output(path: str | Path, *, directory: bool = False, suffixes: Sequence[str] | None = None,
                 force: bool | None = None) -> Path:
    """Refuse, before any work, an output path that cannot be written: under a file, a folder
    where a file is expected (or the reverse), a read-only folder, an unknown image format, and
    for a file what every writer refuses (:func:`bench.core.outputs.check_target`: a device,
    FIFO or socket; a file's missing folder; an existing file unless ``force``, when given)."""
    text = str(path)
    p = Path(path)
    what = "output folder" if directory else "output file"
    if not text.strip():
        raise InputError(f"{what}: empty path")
    if any(ord(ch) < 32 or ord(ch) == 127 for ch in text):
        raise InputError(f"{what} {text!r}: control characters in the path")
    if not directory and (text.endswith(("/", os.sep)) or p.name in ("", ".", "..")):
        raise InputError(f"{what} {text!r} names a folder, not a file")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise InputError(f"{what} {p}: unknown format {p.suffix or '(no suffix)'!r}; use one of "
                         f"{', '.join(s.lstrip('.') for s in suffixes)}")
    try:
        if p.exists():
            if directory and not p.is_dir():
                raise InputError(f"{what} {p} is a file, not a folder")
            if not directory and p.is_dir():
                raise InputError(f"{what} {p} is a folder, not a file")
            if not directory:
                check_target(p, force=force)  # a device, FIFO or socket; an existing file without --force
            if not os.access(p, os.W_OK):
                raise InputError(f"{what} {p}: permission denied")
            return p
        if not directory:
            check_target(p, force=force)  # the folder of a file must exist: none is created unasked
        parent = p.parent
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
        if not parent.is_dir():
            raise InputError(f"{what} {p}: {parent} is a file, not a folder")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise InputError(f"{what} {p}: folder {parent} is not writable")
    except OSError as exc:  # a symlink loop, a name too long ...
        raise InputError(f"{what} {p}: {exc.strerror or exc}") from None
    return p


def _output_type(name: str, **check: Any) -> Callable[[str], str]:
    """argparse type: the text unchanged once :func:`check_output` (with ``check``) accepts it."""

    def parse(text: str) -> str:
        try:
            check_output(text, **check)
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        return text

    parse.__name__ = name
    return parse


def output_file(suffixes: Sequence[str] | None = None) -> Callable[[str], str]:
    """argparse type: a file path that can be written (see :func:`check_output`)."""
    return _output_type("output file", suffixes=suffixes)


#: argparse type: a folder that can be created or written (see :func:`check_output`)
output_dir = _output_type("output folder", directory=True)


def add_force_option(parser: argparse.ArgumentParser, *outputs: str, sidecars: Sequence[str] = ()) -> None:
    """``--force``: replace output files that exist. ``outputs`` name the arguments holding the
    command's output files, checked by :func:`check_outputs` before any work; ``sidecars`` those
    of them that also write ``FILE.json`` (a tidy CSV's metadata)."""
    parser.add_argument("--force", action="store_true",
                        help="replace output files that exist (default: refused); a device, FIFO, socket or "
                             "folder is never replaced")
    parser.set_defaults(output_dests=outputs, output_sidecars=tuple(sidecars))


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, the output files of a command with ``--force``
    (:func:`add_force_option`) that exist when ``--force`` is not given, or are not regular files."""
    force = bool(getattr(args, "force", False))
    for dest in getattr(args, "output_dests", ()):
        value = getattr(args, dest, None)
        if value:
            check_output(value, force=force)
            if dest in getattr(args, "output_sidecars", ()):
                check_output(f"{value}.json", force=force)


_ANNOUNCED: list = []  # the command's open compile_progress context, if any


def announce_compilation() -> None:
    """Show the kernels numba compiles from here to the end of the command (a first run only; the
    cache makes later runs quick): on a terminal a line per kernel family with elapsed seconds and
    an estimate, otherwise one plain line per kernel family (:mod:`bench.compilation`)."""
    if _ANNOUNCED:
        return
    from bench.compilation import compile_progress

    context = compile_progress()
    context.__enter__()
    _ANNOUNCED.append(context)


def stop_announcing() -> None:
    """End :func:`announce_compilation`'s notices (at the end of a command)."""
    while _ANNOUNCED:
        _ANNOUNCED.pop().__exit__(None, None, None)


def report_run(result: ScanResult, as_json: bool) -> int:
    """What scan and resume print: the run id (or the result as JSON); a run that completed with
    masked readings says so on stderr (its JSON has ``masked``, ``saturated`` and ``reason``)."""
    if as_json:
        emit_json(result.__dict__)
    else:
        print(result.run_id)
    reason = getattr(result, "reason", None)
    if reason and not as_json:
        print(f"run {result.run_id} {result.status} with {reason}: see `bench show {result.run_id}`", file=sys.stderr)
    return 0


#: what may execute a bench description (``--body``); default: the file's ``kind``
BODIES = ("virtual", "emulated", "real")


def add_bench_options(parser: argparse.ArgumentParser, help: str, required: bool = True) -> None:
    """``--bench FILE`` and ``--body virtual|emulated|real``: one description, three bodies."""
    parser.add_argument("--bench", required=required, metavar="BENCH.toml", help=help)
    parser.add_argument("--body", choices=BODIES, default=None,
                        help="what executes the bench description (default: the file's kind)")


def warn_if_radians(what: str, angles: Sequence[float]) -> None:
    """Warn on stderr when angles taken as degrees all look like radians (``--incidence 1.2``)."""
    from bench.core.parsing import looks_like_radians

    if looks_like_radians(angles):
        import math

        shown = ", ".join(f"{a:g}" for a in list(angles)[:4])
        print(f"warning: {what} {shown} taken as degrees; in radians that would be "
              f"{', '.join(f'{math.degrees(a):.4g}' for a in list(angles)[:4])} deg", file=sys.stderr)


def add_service_time_limit(parser: argparse.ArgumentParser) -> None:
    """``--max-seconds S`` of a command that keeps a service running until Ctrl-C (``bench emulate``,
    ``bench serve``: :func:`wait_until_stopped` reads it), and its retired spelling ``--seconds``
    refused with the one line naming it: the flag means one thing in both."""
    parser.add_argument("--max-seconds", type=real(0.0, 1e7), metavar="S",
                        help="time limit, s: stop after this many seconds (default: until Ctrl-C)")
    renamed(parser, "--seconds", "--max-seconds", "was the time limit; it is --max-seconds, as in every command "
            "(--budget-seconds is a design's bench-time budget)")


def wait_until_stopped(seconds: float | None, tick: Callable[[], object] | None = None, period_s: float = 2.0) -> None:
    """Block for ``seconds`` (None: until Ctrl-C or SIGTERM), for commands that keep a service
    running (``bench emulate``, ``bench serve``), calling ``tick()`` every ``period_s`` when given
    (``bench serve`` adds the runs stored meanwhile); Ctrl-C returns normally."""
    import signal
    import time

    end = None if seconds is None else time.monotonic() + seconds
    try:
        if seconds is None:
            signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
        while end is None or time.monotonic() < end:
            left = 3600.0 if end is None else end - time.monotonic()
            time.sleep(max(0.0, min(left, period_s if tick is not None else left)))
            if tick is not None:
                tick()
    except KeyboardInterrupt:
        pass
