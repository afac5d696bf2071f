"""``bench sweep``: many virtual measurements in-process, or on a Dask cluster, into a run store.

Imports nothing heavy at module level: the sweep machinery (numba kernels, pandas, Dask) loads
only when the command runs.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import logging
import sys
from typing import Any, Iterator

from bench.cli.argtypes import count, listen_address, run_id, scheduler_address
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, announce_compilation
from bench.core.errors import InputError


def register(subparsers: Any) -> None:
    """Add ``bench sweep`` to the CLI."""
    p = subparsers.add_parser(
        "sweep", help=command_help("sweep"),
        description="Run every task of SWEEP.toml into the run store: in-process by default, on an existing "
                    "Dask cluster with --scheduler, or on a local cluster of N worker processes with --workers. "
                    "Results are identical however the work is split. --resume RUN finishes an interrupted "
                    "sweep (SWEEP.toml is then taken from the store).")
    p.add_argument("sweep", nargs="?", metavar="SWEEP.toml", help="the sweep (see fixtures/sweeps/)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", type=scheduler_address, metavar="tcp://HOST:PORT",
                       help="address of a running Dask scheduler (default: run in-process)")
    where.add_argument("--workers", type=count(1, 1024), metavar="N",
                       help="start a local Dask cluster of N processes, 1..1024 (default: run in-process)")
    p.add_argument("--threads-per-worker", type=count(1, 256), default=1, metavar="K",
                   help="threads of each local worker (default 1; every task runs numba single-threaded)")
    p.add_argument("--dashboard", type=listen_address, metavar="HOST:PORT", default="127.0.0.1:8787",
                   help="where a local cluster's dashboard listens (default %(default)s, loopback only; "
                        "give 0.0.0.0:8787 to expose it)")
    p.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite",
                   help="the run store, an SQLite file (default %(default)s)")
    p.add_argument("--resume", type=run_id, metavar="RUN", help="finish this interrupted sweep run instead of starting one (default: start a new run)")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar (shown only on a terminal)")
    p.add_argument("--json", action="store_true", help="the run result as one JSON object")
    p.set_defaults(func=cmd_sweep)


@contextlib.contextmanager
def _client(args: argparse.Namespace) -> Iterator[Any]:
    if args.scheduler is None and args.workers is None:
        yield None
        return
    from bench.sweep import dask_client

    if not logging.getLogger("bench").isEnabledFor(logging.INFO):  # no -v: Dask's INFO chatter off
        import distributed  # noqa: F401 - creates its loggers (with their own levels) first

        for name in list(logging.root.manager.loggerDict):
            if name.split(".")[0] in ("distributed", "dask"):
                logging.getLogger(name).setLevel(logging.WARNING)
    kw: dict[str, Any] = {}
    if args.workers is not None:
        kw["threads_per_worker"] = args.threads_per_worker
        kw["dashboard_address"] = getattr(args, "dashboard", None) or "127.0.0.1:8787"
    with dask_client(args.scheduler, args.workers, **kw) as client:
        info = client.scheduler_info()
        n = len(info.get("workers", {}))
        hint = ""
        if args.workers is not None and importlib.util.find_spec("bokeh") is None:
            hint = "  (install bokeh>=3.1 for the dashboard's pages)"
        print(f"Dask scheduler {info.get('address')} with {n} workers; dashboard: {client.dashboard_link}{hint}",
              file=sys.stderr)
        yield client


def cmd_sweep(args: argparse.Namespace) -> int:
    """Run (or resume) a sweep; print the run id, or the result as JSON."""
    from bench.store import RunStore
    from bench.sweep import load_sweep, resume_sweep, run_sweep

    if args.resume is None and args.sweep is None:
        raise InputError("give a SWEEP.toml, or --resume RUN")
    if args.resume is not None and args.sweep is not None:
        raise InputError("--resume takes the sweep stored with the run; do not also give SWEEP.toml")
    spec = load_sweep(args.sweep) if args.sweep is not None else None  # bad input: exit 2 before any work
    progress = not args.quiet and sys.stderr.isatty()
    if args.scheduler is None and args.workers is None:
        announce_compilation()  # in-process: the kernels compile here the first time
    with RunStore(args.store, create=args.resume is None) as store, _client(args) as client:
        if spec is not None:
            print(f"sweep {spec.name}: {len(spec)} tasks, seed {spec.seed}", file=sys.stderr)
            result = run_sweep(spec, store, client=client, progress=progress)
        else:
            result = resume_sweep(store, args.resume, client=client, progress=progress)
    if args.json:
        print(json.dumps({"run_id": result.run_id, "status": result.status, "tasks_done": result.tasks_done,
                          "tasks_planned": result.tasks_planned, "tasks_run": result.tasks_run,
                          "duplicates_skipped": result.duplicates_skipped, "seconds": result.seconds,
                          "executor": result.executor, "store": str(args.store)}))
    else:
        print(result.run_id)
    return 0


def resume_run(run_id: str, store: str, *, quiet: bool = False, json: bool = False) -> int:
    """``bench resume RUN`` for a sweep run (in-process): what ``bench sweep --resume RUN`` does."""
    args = argparse.Namespace(sweep=None, resume=run_id, store=store, scheduler=None, workers=None,
                              threads_per_worker=1, dashboard=None, quiet=quiet, json=json)
    return cmd_sweep(args)
