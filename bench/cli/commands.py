"""The ``bench`` commands: each one's name, the module that registers it and its one-line help.

``bench --help`` lists every command from this table alone, and a command loads only the module
that registers it (:func:`bench.cli.build_parser`), so no command pays for the others' imports.
A command module's ``register(subparsers)`` takes its help from here (:func:`command_help`);
the table's order is the ``bench --help`` order, and one module's commands are consecutive.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["Command", "COMMANDS", "command_help"]


class Command(NamedTuple):
    module: str
    help: str


COMMANDS: dict[str, Command] = {
    "rays": Command("bench.cli.measure", "ray budget of eq. 3.5 (eq. 3.12 with --patches)"),
    "spectro": Command("bench.cli.measure", "virtual spectrophotometric measurement (one spectrum)"),
    "gonio": Command("bench.cli.measure", "virtual goniophotometric measurement (whole collector sphere)"),
    "plan": Command("bench.cli.scans", "check a plan on a bench and estimate its duration"),
    "scan": Command("bench.cli.scans", "run a plan on a bench into the store; prints the run id"),
    "resume": Command("bench.cli.scans", "finish an interrupted run (scan or sweep)"),
    "runs": Command("bench.cli.scans", "list the runs in a store (read-only)"),
    "show": Command("bench.cli.scans", "summarize one run (read-only)"),
    "export": Command("bench.cli.scans", "export a run: csv, parquet, astm, zemax (read-only on the store)"),
    "serve": Command("bench.cli.serve", "serve every stored run as a Bluesky run in a Tiled catalog (127.0.0.1)"),
    "demo": Command("bench.cli.demo", "end-to-end demo on the embedded default bench"),
    "compare": Command("bench.cli.compare", "compare candidate records (virtual models) with an actual one"),
    "tradeoff": Command("bench.cli.tradeoff", "accuracy versus time of a scene: table and Pareto plot"),
    "sweep": Command("bench.cli.sweep", "run a sweep of virtual measurements (in-process, or on Dask); prints the run id"),
    "emulate": Command("bench.cli.emulate", "start a bench's emulators and print their ports"),
    "home": Command("bench.cli.home", "return the turntable (or another axis) to its home position"),
    "white": Command("bench.cli.white", "save a white reference file (measured now or from a completed run)"),
    "fit": Command("bench.cli.fit", "fit a model's parameters to a record: maximum likelihood, intervals, goodness of fit"),
    "check": Command("bench.cli.assurance", "measure the bench's check standards: E_n of each reading, a run of kind check"),
    "chart": Command("bench.cli.assurance", "control charts of the check standards (Western Electric / Nelson rules)"),
    "specimens": Command("bench.cli.specimens", "list every specimen family and its parameters (range, unit, default)"),
}


def command_help(name: str) -> str:
    """The one-line help of command ``name`` (what ``bench --help`` lists)."""
    return COMMANDS[name].help
