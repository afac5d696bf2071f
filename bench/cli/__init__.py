"""The ``bench`` command line: the parser, the command groups it loads and ``main``.

One module per command group, each with ``register(subparsers)``:

* :mod:`bench.cli.measure` -- ``rays``, ``spectro``, ``gonio`` (one virtual measurement);
* :mod:`bench.cli.scans` -- ``plan``, ``scan``, ``resume``, ``runs``, ``show``, ``export``;
* :mod:`bench.cli.demo` -- ``demo``;
* :mod:`bench.cli.compare` -- ``compare``;
* :mod:`bench.cli.tradeoff` -- ``tradeoff``;
* :mod:`bench.cli.sweep` -- ``sweep``;
* :mod:`bench.cli.emulate` -- ``emulate``;
* :mod:`bench.cli.home` -- ``home`` (return the turntable to home);
* :mod:`bench.cli.white` -- ``white`` (save a white reference file);
* :mod:`bench.cli.fit` -- ``fit`` (model parameters from a record);
* :mod:`bench.cli.specimens` -- ``specimens``.

Starts fast: a command imports only the module that registers it (the table of
:mod:`bench.cli.commands` names every command and its help, for ``bench --help``), and heavy
modules (numba kernels, scipy, colour-science, matplotlib, pandas) are imported inside the
commands that use them. Exit status (one policy, :data:`EXIT_STATUS_HELP`): 0 ok,
2 bad input the user can fix, 1 a run that failed on its own, 130 Ctrl-C, 70 an internal error
(one line naming a saved traceback). Every command that reports numbers has ``--json`` with
stable keys. Argument types are declared in :mod:`bench.cli.argtypes`.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sqlite3
import sys
import tempfile
import traceback
from typing import Callable, Collection, Sequence

from bench.cli.argtypes import BenchArgumentParser, one_line as _one_line
from bench.cli.commands import COMMANDS
from bench.cli.common import DEFAULT_STORE, check_outputs, stop_announcing
from bench.core.errors import BenchError, InputError, StoreError
from bench.core.outputs import replacing

__all__ = ["main", "build_parser", "COMMAND_MODULES", "DEFAULT_STORE"]

log = logging.getLogger("bench")

#: Modules that add subcommands, in ``bench --help`` order: each has ``register(subparsers)`` and
#: imports nothing heavy at module level (the CLI must start fast).
COMMAND_MODULES = list(dict.fromkeys(c.module for c in COMMANDS.values()))


def _version() -> str:
    try:
        from importlib.metadata import version  # ~30 ms: only when --version is asked for

        return version("goniobench")
    except Exception:  # not installed (a source checkout on PYTHONPATH)
        return "0.1.0 (source)"


class _VersionAction(argparse._VersionAction):
    """``--version``, looking the installed version up only when asked (argparse's own action
    needs the string when the parser is built, i.e. on every command)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: str | Sequence[object] | None, option_string: str | None = None) -> None:
        self.version = f"bench (goniobench) {_version()}"
        super().__call__(parser, namespace, values, option_string)


def build_parser(load: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The ``bench`` parser with every command group's subcommands.

    ``load`` names the commands whose modules are imported and registered in full (default:
    all); every other command is listed by its name and help only (enough for ``bench --help``
    and for refusing an unknown command), so a command does not import the others' modules.
    """
    p = BenchArgumentParser(prog="bench", description="goniobench: real, emulated and virtual "
                            "goniophotometry and spectrophotometry behind one interface.",
                            epilog=EXIT_STATUS_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr (default: warnings only)")
    p.add_argument("--version", action=_VersionAction)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    modules = COMMAND_MODULES if load is None else {COMMANDS[c].module for c in load if c in COMMANDS}
    registered: set[str] = set()
    for name, command in COMMANDS.items():
        if command.module not in modules:
            sub.add_parser(name, help=command.help)
        elif command.module not in registered:  # adds all of the module's commands, consecutive in COMMANDS
            importlib.import_module(command.module).register(sub)
            registered.add(command.module)
    return p


def _command_of(argv: Sequence[str]) -> str | None:
    """The command ``argv`` names: its first argument that is not an option (``bench``'s own
    options take no value), or None (``bench --help``, no command)."""
    return next((a for a in argv if not a.startswith("-")), None)


#: the exit-status policy, shown by ``bench --help`` (and tabled in README)
EXIT_STATUS_HELP = """exit status:
  0    success
  1    a run failed on its own (device fault, communication lost, run interrupted)
  2    bad input you can fix: an argument, a file, a missing/foreign/corrupt store, an unknown run
  70   internal error (a bug): one line, and the traceback saved to a file named in it
  130  interrupted by Ctrl-C"""


def _save_traceback(command: str) -> str:
    """Write the current exception's traceback to a file; return its path (or a reason)."""
    try:
        fd, path = tempfile.mkstemp(prefix=f"bench-{command}-", suffix=".traceback.txt")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(f"bench {command} {' '.join(sys.argv[1:])}\n")
            traceback.print_exc(file=f)
        return path
    except OSError as exc:  # nowhere to write: say so, still one line
        return f"(could not be saved: {exc.strerror or exc})"


def _quiet_broken_pipe() -> int:
    """The reader of our stdout went away (``bench runs | head``): stop quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run one ``bench`` command; returns the exit status (see :data:`EXIT_STATUS_HELP`).

    Every failure is one line on stderr: bad input (:class:`InputError`, :class:`StoreError`, an
    unreadable path) exits 2, a run that failed on its own (any other :class:`BenchError`) exits 1,
    Ctrl-C exits 130, and anything unexpected exits 70 naming a file that holds the traceback.
    """
    command = "?"
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        named = _command_of(argv)
        parser = build_parser(load=[named] if named is not None else [])
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # --help, --version, or a usage error (already one line)
            return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        command = args.command
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(levelname)s %(name)s: %(message)s")
        func: Callable[[argparse.Namespace], int] = args.func
        try:
            if hasattr(args, "force"):  # a command that writes files: --force alone replaces them
                check_outputs(args)
                with replacing(args.force):
                    code = func(args)
            else:
                code = func(args)
        finally:
            stop_announcing()
        sys.stdout.flush()  # a closed pipe shows here, inside the handlers, not at interpreter exit
        return code
    except (InputError, StoreError) as exc:
        print(f"bench {command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except BenchError as exc:
        if getattr(exc, "by_user", False):  # a run stopped by Ctrl-C, stored as interrupted
            print(f"bench {command}: interrupted: {_one_line(exc)}", file=sys.stderr)
            return 130
        print(f"bench {command}: failed: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bench {command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return _quiet_broken_pipe()
    except (sqlite3.OperationalError, sqlite3.IntegrityError, sqlite3.DataError, sqlite3.NotSupportedError) as exc:
        # a store error that escaped the store's own typing (ProgrammingError is a bug: below)
        print(f"bench {command}: error: run store: {_one_line(exc)}", file=sys.stderr)
        return 2
    except (OSError, UnicodeError) as exc:  # a path the user gave that cannot be read or written
        name = getattr(exc, "filename", None)
        why = getattr(exc, "strerror", None) or _one_line(exc)
        print(f"bench {command}: error: {_one_line(f'{name}: {why}' if name else why)}", file=sys.stderr)
        return 2
    except Exception as exc:  # the last resort: never a raw traceback
        path = _save_traceback(command)
        print(f"bench {command}: internal error: {type(exc).__name__}: {_one_line(exc, 300)} "
              f"(traceback saved to {path}; please report it)", file=sys.stderr)
        return 70
