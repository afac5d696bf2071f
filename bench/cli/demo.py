"""``bench demo``: the end-to-end demo of :mod:`bench.demo` on the embedded default bench."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.cli.argtypes import seed, stderr_is_terminal
from bench.cli.commands import command_help
from bench.cli.common import announce_compilation, emit_json, output_dir

__all__ = ["register", "cmd_demo"]


def cmd_demo(args: argparse.Namespace) -> int:
    from bench.demo import run_demo

    announce_compilation()
    summary = run_demo(Path(args.out), seed=args.seed, progress=stderr_is_terminal())
    if args.json:
        emit_json(summary)
    else:
        for line in summary["lines"]:
            print(line)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``bench`` subcommands."""
    d = sub.add_parser("demo", help=command_help("demo"))
    d.add_argument("--out", type=output_dir, default="demo-out", help="output folder (default ./%(default)s)")
    d.add_argument("--seed", type=seed, default=20261122, help="root seed, integer 0..2^63-1 (default %(default)s)")
    d.add_argument("--json", action="store_true", help="the demo summary as one JSON object")
    d.set_defaults(func=cmd_demo)
