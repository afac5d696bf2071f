"""``bench white``: save a white reference file (:mod:`bench.io.white`).

Either measure the white standard now (``--bench B``: on a real bench the operator mounts it and
confirms at a terminal, or beforehand with ``--yes``; a dark is taken with it unless ``--dark
none``, and a bench that cannot switch its light off refuses a dark rather than skip it), or take the
white reference a completed run was calibrated with (``--from-run RUN --store S``). A bench
config then names the file (``[white] reference_file = "..."``) and its runs need no operator.
``--repeats N`` (N >= 3) reads the mounted standard N times in sequence and keeps every reading
(the file of a plan with ``white = "repeated"``, ``white_repeats = N``); ``--json`` then gives
the lamp drift's Type A estimate.

The file records the white's origin (body, bench, detector: :mod:`bench.calibration_chain`);
runs on another body or detector refuse it. A white that does not look like the standard is
refused and nothing is written: a white predicted to saturate the detector (before any motion, as
``bench scan`` predicts a plan's white) or found saturated in a band, and against the declared detector's response to the certificate,
and against the last accepted white of the same body and detector (the file ``--out`` replaces,
else the bench's ``[white] reference_file``): its level and spectral shape.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from bench.cli.argtypes import count, real, run_id
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, add_bench_options, add_force_option, emit_json, open_store, output_file
from bench.core.errors import InputError

if TYPE_CHECKING:
    from bench.core.calibration import Calibration

#: bench.core.schemas.MAX_WHITE_REPEATS (not imported: the CLI starts without pydantic)
MAX_WHITE_REPEATS = 1000

__all__ = ["register", "cmd_white"]


def _measure(args: argparse.Namespace) -> tuple[Calibration, str]:
    from pathlib import Path

    from bench.calibration_chain import check_white_level, check_white_unsaturated, previous_white
    from bench.config import load_bench
    from bench.exposure import check_exposure, starting_integration
    from bench.plans import Plan
    from bench.runner import measure_calibration

    if args.integration_s is not None and not args.integration_s > 0:
        raise InputError(f"--integration-s must be > 0 s, got {args.integration_s:g}")
    if args.repeats == 2:
        raise InputError("--repeats must be 1 (one white) or >= 3 (a lamp drift estimate needs 3), got 2")
    with load_bench(args.bench, body=args.body) as bench:
        # the default: the detector device's own starting time, below the white's saturation
        integration_s = args.integration_s if args.integration_s is not None else starting_integration(bench.config)
        plan = Plan(name="white", kind="list", points=(), integration_s=integration_s, averages=args.averages,
                    dark=args.dark, white="repeated" if args.repeats > 1 else "once",
                    white_repeats=max(args.repeats, 3))
        bench.operator_confirmed = args.yes
        check_exposure(plan, bench.config, white=True)  # as bench scan predicts a plan's white: before motion
        cal = measure_calibration(bench, plan, use_reference_file=False)  # checked against the declared level
        assert cal is not None, "a plan with white 'once' or 'repeated' always measures one"
        check_white_unsaturated(f"the white measured on bench {bench.name!r}", cal)
        previous = previous_white(bench, args.out if Path(args.out).is_file() else None)
        if previous is not None:  # and against the last accepted white of this body and detector
            check_white_level(f"the white measured on bench {bench.name!r}", cal, bench, *previous)
        return cal, bench.name


def _from_run(args: argparse.Namespace) -> tuple[Calibration, str]:
    from bench.calibration_chain import check_white_unsaturated
    from bench.core.calibration import Calibration

    with open_store(args.store, create=False) as store:
        info = store.run(args.from_run)
    if info["status"] != "completed":
        raise InputError(f"run {args.from_run} is {info['status']}: take the white reference of a completed run")
    if not info.get("calibration"):
        raise InputError(f"run {args.from_run} has no white reference (its plan had white = \"none\")")
    cal = Calibration.from_dict(info["calibration"])
    check_white_unsaturated(f"the white of run {args.from_run}", cal)
    return cal, str((info.get("bench") or {}).get("name", ""))


def cmd_white(args: argparse.Namespace) -> int:
    from bench.io.white import WhiteReference, write_white_reference

    if (args.bench is None) == (args.from_run is None):
        raise InputError("give either --bench BENCH.toml (measure now) or --from-run RUN (a completed run's)")
    cal, bench_name = _measure(args) if args.bench is not None else _from_run(args)
    ref = WhiteReference.from_calibration(cal, operator_note=args.note, bench=bench_name)
    drift = getattr(cal, "lamp_drift", None)  # repeated whites: the Type A estimate
    path = write_white_reference(args.out, ref)
    if args.json:
        emit_json({"file": str(path), "date": ref.date, "operator_note": ref.operator_note, "bench": bench_name,
                   "wavelengths": int(ref.white.signal.size), "dark": ref.dark is not None,
                   "integration_s": ref.white.integration_s, "averages": ref.white.averages,
                   "repeats": len(ref.repeats) or 1,
                   "lamp_drift": None if drift is None else drift.as_dict()})
    else:
        print(path)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``white`` to the subcommands."""
    w = sub.add_parser("white", help=command_help("white"))
    add_bench_options(w, "measure the white standard on this bench now (default: none)", required=False)
    w.add_argument("--from-run", type=run_id, metavar="RUN",
                   help="take the white reference of this completed run (default: none)")
    w.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite",
                   help="the run store holding --from-run (default %(default)s)")
    w.add_argument("--out", required=True, type=output_file(), metavar="FILE.csv",
                   help="the white reference file to write (required)")
    w.add_argument("--note", default="", help="the operator's note (standard, cleaning, lamp warm-up...; default: none)")
    w.add_argument("--integration-s", type=real(0.0, 3600.0, lo_open=True), default=None, metavar="S",
                   help="integration time, seconds (default: 0.1, or the longest below it at which the bench's "
                        "white stays below full scale, as its Bluesky detector starts)")
    w.add_argument("--averages", type=count(1, 100_000), default=1, help="scans averaged, 1..100000 (default %(default)s)")
    w.add_argument("--dark", choices=("once", "none"), default="once",
                   help="take a dark with the light off (once), or none (the file records it; runs whose plan "
                        "takes darks then refuse it) (default %(default)s)")
    w.add_argument("--repeats", type=count(1, MAX_WHITE_REPEATS), default=1, metavar="N",
                   help="times the white standard is read, in sequence with it mounted once: 1, or N >= 3 to estimate "
                        "the lamp's drift (runs whose plan has white = \"repeated\", white_repeats = N) "
                        "(default %(default)s)")
    w.add_argument("--yes", action="store_true",
                   help="the white standard is mounted (the operator confirms it): measure without asking at a "
                        "terminal (default: ask)")
    w.add_argument("--json", action="store_true", help="one JSON object with stable keys")
    add_force_option(w, "out")
    w.set_defaults(func=cmd_white)
