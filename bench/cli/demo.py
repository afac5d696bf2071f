"""``bench demo``: the end-to-end demo of :mod:`bench.demo` on the embedded default bench."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.cli.common import emit_json

__all__ = ["register", "cmd_demo"]


def cmd_demo(args: argparse.Namespace) -> int:
    from bench.demo import run_demo

    summary = run_demo(Path(args.out), seed=args.seed)
    if args.json:
        emit_json(summary)
    else:
        for line in summary["lines"]:
            print(line)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``bench`` subcommands."""
    d = sub.add_parser("demo", help="end-to-end demo on the embedded default bench")
    d.add_argument("--out", default="demo-out", help="output folder (default ./demo-out)")
    d.add_argument("--seed", type=int, default=20261122)
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=cmd_demo)
