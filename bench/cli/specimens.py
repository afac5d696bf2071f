"""``bench specimens``: every specimen family and its declared parameters (name, range, unit,
default, meaning), from the declarations of :mod:`virtual.specimens` -- the same declarations that
parse and validate ``--specimen`` strings, so this list cannot drift from what is accepted."""

from __future__ import annotations

import argparse
from typing import Any

from bench.cli.commands import command_help
from bench.cli.common import emit_json

__all__ = ["register", "cmd_specimens"]


def cmd_specimens(args: argparse.Namespace) -> int:
    from virtual.specimens import specimen_families, specimen_table_markdown

    if args.json:
        emit_json(specimen_families())
        return 0
    if args.markdown:
        print(specimen_table_markdown(), end="")
        return 0
    for fam in specimen_families():
        print(f"{fam['name']}: {fam['doc']}")
        for p in fam["parameters"]:
            lo, hi = p["range"]
            aliases = f" (or {', '.join(p['aliases'])})" if p["aliases"] else ""
            default = "" if p["default"] is None else f", default {p['default']:g}"
            unit = f" {p['unit']}" if p["unit"] else ""
            print(f"  {p['name']}{aliases}: {lo:.10g} .. {hi:.10g}{unit}{default}  {p['doc']}".rstrip())
    print("e.g. --specimen 'ggx:alpha=0.2,eta=1.5,k=0'")
    return 0


def register(sub: Any) -> None:
    """Add ``specimens`` to the ``bench`` subcommands."""
    p = sub.add_parser("specimens", help=command_help("specimens"))
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true", help="a JSON list of families with their parameters")
    fmt.add_argument("--markdown", action="store_true", help="the README table (markdown)")
    p.set_defaults(func=cmd_specimens)
