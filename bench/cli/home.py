"""``bench home``: return a bench axis (the turntable) to its home position.

Builds the bench through its builder (:func:`bench.config.load_bench`), homes the axis
(:func:`bench.builders.homing.home_axis`) and prints the position read back. A virtual bench
has nothing to home: exit 2 before anything is built. Device faults (alarm, no HOME-END in time, lost port)
are typed errors: exit 1 (``bench.cli.main``).
"""

from __future__ import annotations

import argparse

from bench.cli.argtypes import real
from bench.cli.commands import command_help
from bench.cli.common import add_bench_options, emit_json
from bench.core.errors import ConfigError

__all__ = ["register", "cmd_home"]


def cmd_home(args: argparse.Namespace) -> int:
    from bench.config import load_bench
    from bench.core.parsing import read_toml
    from bench.builders.homing import home_axis

    config = read_toml(args.bench, "bench config")
    kind = str(args.body or config.get("kind", "virtual"))
    if kind == "virtual":
        raise ConfigError(f"{args.bench}: a virtual bench has no axis to home (nothing to do)")
    if args.timeout is not None and not args.timeout > 0:
        raise ConfigError(f"--timeout must be > 0 s, got {args.timeout:g}")
    with load_bench(config, body=args.body) as bench:
        position = home_axis(bench, args.axis, timeout_s=args.timeout)
        name, kind = bench.name, bench.kind
    if args.json:
        emit_json({"bench": name, "bench_kind": kind, "axis": args.axis, "position_deg": position})
    else:
        print(f"{args.axis} of bench {name} ({kind}) homed: position {position:.3f} deg")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``home`` to the subcommands."""
    h = sub.add_parser("home", help=command_help("home"))
    add_bench_options(h, "the bench config (required)")
    h.add_argument("--axis", default="turntable", help="the axis to home (default: turntable)")
    h.add_argument("--timeout", type=real(0.0, 3600.0, lo_open=True), metavar="S",
                   help="longest wait for HOME-END, seconds in (0, 3600] (default: the axis' home_timeout_s)")
    h.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    h.set_defaults(func=cmd_home)
