"""``bench serve --store S [--port P]``: every stored run as a Bluesky run in a Tiled catalog.

A real Tiled server (the ``tiled`` extra) on 127.0.0.1 only (:class:`bench.catalog.CatalogServer`);
each stored run is written through ``bluesky_tiled_plugins.TiledWriter`` keyed by its start uid,
its ``primary`` stream holding the rows ``bench export`` writes. Prints the URI and the API key a
writer (a RunEngine's ``TiledWriter``) needs, then serves until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys

from bench.cli.argtypes import count, real, renamed
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, open_store, wait_until_stopped

__all__ = ["register", "cmd_serve"]


def cmd_serve(args: argparse.Namespace) -> int:
    from bench.catalog import CatalogServer
    from bench.core.errors import InputError

    # found, not imported: bluesky_tiled_plugins alone takes seconds to import (its clients pull
    # in xarray and dask); it is imported to write the runs once the server already answers
    if any(importlib.util.find_spec(m) is None for m in ("bluesky_tiled_plugins", "tiled", "uvicorn")):
        raise InputError("bench serve needs the tiled extra: pip install 'goniobench[tiled]'")

    with open_store(args.store, create=False, readonly=True) as store:
        store.runs()  # a missing or foreign store is refused before the server starts
        with CatalogServer(args.port, args.catalog, args.api_key) as server:
            written = server.add_runs(store)
            info = {"uri": server.uri, "api_key": server.api_key, "runs": written, "unserved": server.unserved,
                    "catalog": str(server.directory) if args.catalog else None}
            info.update(damaged=server.damaged, replaced=server.replaced)  # damaged runs: never requested
            for rid, why in server.damaged.items():
                print(f"bench serve: warning: run {rid} not served: damaged in the store ({why})", file=sys.stderr)
            if args.json:
                print(json.dumps(info), flush=True)
            else:
                print(f"Tiled catalog at {server.uri}: {len(written)} runs of {args.store} (keyed by start uid, "
                      f"the run id in start['run_id'])")
                if server.unserved:
                    print(f"  not served (no readings): {', '.join(server.unserved)}")
                print(f"  read:  from tiled.client import from_uri; from tiled.queries import Key; c = from_uri("
                      f"{server.uri!r}); c.search(Key('start.run_id') == RUN).values().first()['primary'].read()")
                print(f"  write: TiledWriter(from_uri({server.uri!r}, api_key={server.api_key!r}))")
                print("  (runs that end later are added as they end; Ctrl-C stops it)", flush=True)
            # runs that end while the server runs are added as they end (every 2 s)
            wait_until_stopped(args.max_seconds, tick=lambda: server.add_runs(store))
    return 0


#: what Tiled accepts as its single-user API key (ASCII letters and digits; it refuses anything else
#: only once the server starts, with a page of traceback), and a bound on its length
API_KEY_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789")
API_KEY_LENGTH = (1, 256)


def api_key(text: str) -> str:
    """``--api-key``: 1 to 256 ASCII letters and digits, checked before anything starts (an empty
    key is refused, never replaced by a random one)."""
    lo, hi = API_KEY_LENGTH
    if not text:
        raise argparse.ArgumentTypeError("an empty key would let no writer in; give 1 to 256 letters and digits, "
                                         "or leave --api-key out for a random key (printed)")
    bad = sorted(set(text) - API_KEY_CHARS)
    if bad:
        shown = "".join(bad[:8]).encode("ascii", "backslashreplace").decode("ascii")
        raise argparse.ArgumentTypeError(f"a key holds ASCII letters and digits only (Tiled refuses others); "
                                         f"this one has {shown!r}")
    if not lo <= len(text) <= hi:
        raise argparse.ArgumentTypeError(f"a key has {lo} to {hi} letters and digits, this one {len(text)}")
    return text


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help=command_help("serve"))
    p.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite",
                   help="the run store to serve, read-only (default %(default)s)")
    p.add_argument("--port", type=count(0, 65535), default=8000,
                   help="TCP port on 127.0.0.1, 0 = any free one (default %(default)s)")
    p.add_argument("--catalog", metavar="DIR", default=None,
                   help="keep the Tiled catalog (and runs written into it) in DIR (default: a temporary folder)")
    p.add_argument("--api-key", type=api_key, default=None, metavar="KEY",
                   help="the API key writers pass, 1 to 256 ASCII letters and digits (default: a random one, printed)")
    p.add_argument("--max-seconds", type=real(0.0, 1e7), metavar="S",
                   help="time limit, s: stop after this many seconds (default: until Ctrl-C)")
    renamed(p, "--seconds", "--max-seconds", "was the time limit; it is --max-seconds, as in every command "
            "(--budget-seconds is a design's bench-time budget)")
    p.add_argument("--json", action="store_true", help="uri, api_key and the runs served as one JSON object")
    p.set_defaults(func=cmd_serve)
