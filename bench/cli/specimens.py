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
    from virtual.specimens.strings import RESERVED_FORMS

    for fam in specimen_families():  # the fields of the README table, one family a block
        print(f"{fam['name']}: {fam['convention']}")
        for p in fam["parameters"]:
            aliases = f" (or {', '.join(p['aliases'])})" if p["aliases"] else ""
            lo, hi = p["range"]
            rng = " | ".join(p["choices"]) if p["choices"] else f"{lo:.10g} .. {hi:.10g}"
            default = p["choices"][int(p["default"])] if p["choices"] else f"{p['default']:g}"
            unit = f" {p['unit']}" if p["unit"] else ""
            print(f"  {p['name']}{aliases}: {rng}{unit}, default {default}  {p['doc']}".rstrip())
    for name, (form, doc) in RESERVED_FORMS.items():
        print(f"{name}: {form}\n  {doc}")
    print("e.g. --specimen 'ggx:alpha=0.2,eta=1.5,k=0,masking=separable'")
    return 0


def register(sub: Any) -> None:
    """Add ``specimens`` to the ``bench`` subcommands."""
    p = sub.add_parser("specimens", help=command_help("specimens"))
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true", help="a JSON list of families with their parameters")
    fmt.add_argument("--markdown", action="store_true", help="the README table (markdown)")
    p.set_defaults(func=cmd_specimens)
