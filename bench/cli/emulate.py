"""``bench emulate BENCH.toml``: start the wire-level emulators of a bench and print their ports,
then a ``kind = "real"`` bench config for them as TOML (comments above it name the ports), so the
output saved to a file is a bench file; ``--json`` prints both as one JSON object."""

from __future__ import annotations

import argparse
import json

import tomli_w

from bench.cli.argtypes import seed
from bench.cli.commands import command_help
from bench.cli.common import add_service_time_limit, wait_until_stopped


def cmd_emulate(args: argparse.Namespace) -> int:
    from bench.builders.emulated import Emulators
    from bench.builders.tables import validate_driver_tables
    from bench.core.parsing import read_toml
    from bench.core.schemas import BenchFile, validate_document

    config = read_toml(args.bench, "bench config")
    validate_document(BenchFile, config, f"bench config {args.bench}")
    validate_driver_tables(config, f"bench config {args.bench}")
    emu = Emulators(config, seed=args.seed)
    try:
        if args.json:
            print(json.dumps({"ports": emu.ports(), "real_bench": emu.real_bench_config()}), flush=True)
        else:
            print("# emulators running (Ctrl-C stops them):")
            for name, port in emu.ports().items():
                print(f"#   {name:18s} {port}")
            print("# a bench config for the real drivers on these ports: save it as a .toml file")
            print(tomli_w.dumps(emu.real_bench_config()), flush=True)
        wait_until_stopped(args.max_seconds)
    except KeyboardInterrupt:  # Ctrl-C while starting
        pass
    finally:
        emu.close()
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("emulate", help=command_help("emulate"))
    p.add_argument("bench", metavar="BENCH.toml", help="an emulated bench config (see fixtures/benches/)")
    p.add_argument("--seed", type=seed, help="emulator seed, integer 0..2^63-1 (default: the config's, else 7)")
    add_service_time_limit(p)
    p.add_argument("--json", action="store_true", help="ports and the real-bench config as one JSON object (default: TOML)")
    p.set_defaults(func=cmd_emulate)
