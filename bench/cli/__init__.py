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
* :mod:`bench.cli.white` -- ``white`` (save a white reference file).

Starts fast: heavy modules (numba kernels, colour-science, matplotlib, pandas) are imported
inside the commands that use them. Exit status: 0 ok, 2 bad input, 1 a failed run. Every
command that reports numbers has ``--json`` with stable keys.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Callable, Sequence

from bench.cli.common import DEFAULT_STORE
from bench.core.errors import BenchError, InputError

__all__ = ["main", "build_parser", "COMMAND_MODULES", "DEFAULT_STORE"]

log = logging.getLogger("bench")

#: Modules that add subcommands, in ``bench --help`` order: each has ``register(subparsers)`` and
#: imports nothing heavy at module level (the CLI must start fast).
COMMAND_MODULES = ["bench.cli.measure", "bench.cli.scans", "bench.cli.demo", "bench.cli.compare",
                   "bench.cli.tradeoff", "bench.cli.sweep", "bench.cli.emulate",
                   "bench.cli.home", "bench.cli.white"]


def build_parser() -> argparse.ArgumentParser:
    """The ``bench`` parser with every command group's subcommands."""
    p = argparse.ArgumentParser(prog="bench", description="goniobench: real, emulated and virtual "
                                "goniophotometry and spectrophotometry behind one interface.")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run one ``bench`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except InputError as exc:
        print(f"bench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BenchError as exc:
        print(f"bench {args.command}: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bench {args.command}: interrupted", file=sys.stderr)
        return 130
