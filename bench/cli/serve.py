"""``bench serve --store S [--port P]``: every stored run as a Bluesky run in a Tiled catalog.

A real Tiled server (the ``tiled`` extra) on 127.0.0.1 only (:class:`bench.catalog.CatalogServer`);
each stored run is written through ``bluesky_tiled_plugins.TiledWriter`` keyed by its start uid,
its ``primary`` stream holding the rows ``bench export`` writes. Prints the URI and the API key a
writer (a RunEngine's ``TiledWriter``) needs, then serves until Ctrl-C or SIGTERM.

Writing a run costs the server a second or two, so the catalog is kept between starts: without
``--catalog``, ``bench serve`` serves the catalog it kept for the same store
(:func:`catalog_cache`, under the user's cache folder, one ``bench serve`` at a time), writes
only the runs stored or changed since and deletes any run the store no longer holds
(``--no-cache``, or a second ``bench serve`` of the store: every run written anew into a
temporary catalog).
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import importlib.util
import json
import logging
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from bench.cli.argtypes import count
from bench.cli.commands import command_help
from bench.cli.common import DEFAULT_STORE, add_service_time_limit, open_store, wait_until_stopped

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading Tiled or the store
    from bench.catalog import CatalogServer
    from bench.store import RunStore

__all__ = ["register", "cmd_serve", "catalog_cache"]

log = logging.getLogger(__name__)


def cmd_serve(args: argparse.Namespace) -> int:
    from bench.catalog import CatalogServer
    from bench.core.errors import InputError

    # found, not imported: bluesky_tiled_plugins alone takes seconds to import (its clients pull
    # in xarray and dask); it is imported to write the runs once the server already answers
    if any(importlib.util.find_spec(m) is None for m in ("bluesky_tiled_plugins", "tiled", "uvicorn")):
        raise InputError("bench serve needs the tiled extra: pip install 'goniobench[tiled]'")

    with open_store(args.store, create=False, readonly=True) as store:
        store.runs()  # a missing or foreign store is refused before the server starts
        with _catalog_folder(args) as (folder, kept), CatalogServer(args.port, folder, args.api_key) as server:
            if kept:
                server.keep_only(store)  # runs the store no longer holds (or a RunEngine wrote then)
            _serve(args, store, server)
    return 0


def _serve(args: argparse.Namespace, store: RunStore, server: CatalogServer) -> None:
    """Write the stored runs, print where they are served, and serve until stopped."""
    written = server.add_runs(store)
    info: dict[str, object] = {"uri": server.uri, "api_key": server.api_key, "runs": written,
                               "served": sorted(server.served), "unserved": server.unserved,
                               "catalog": str(server.directory) if args.catalog else None}
    info.update(damaged=server.damaged, replaced=server.replaced)  # damaged runs: never requested
    for rid, why in server.damaged.items():
        print(f"bench serve: warning: run {rid} not served: damaged in the store ({why})", file=sys.stderr)
    if args.json:
        print(json.dumps(info), flush=True)
    else:
        print(f"Tiled catalog at {server.uri}: {len(server.served)} runs of {args.store} ({len(written)} written "
              f"now; keyed by start uid, the run id in start['run_id'])")
        if server.unserved:
            print(f"  not served (no readings): {', '.join(server.unserved)}")
        print(f"  read:  from tiled.client import from_uri; from tiled.queries import Key; c = from_uri("
              f"{server.uri!r}); c.search(Key('start.run_id') == RUN).values().first()['primary'].read()")
        print(f"  write: TiledWriter(from_uri({server.uri!r}, api_key={server.api_key!r}))")
        print("  (runs that end later are added as they end; Ctrl-C stops it)", flush=True)
    # runs that end while the server runs are added as they end (every 2 s)
    wait_until_stopped(args.max_seconds, tick=lambda: server.add_runs(store))


def catalog_cache(store: str | Path) -> Path:
    """The folder where ``bench serve`` keeps the catalog it last served for ``store`` (named
    after the store file's real path): under ``$GONIOBENCH_CACHE_DIR`` if set (the test suite
    sets one of its own), else ``$XDG_CACHE_HOME/goniobench`` (default ``~/.cache/goniobench``)."""
    base = Path(os.environ.get("GONIOBENCH_CACHE_DIR")
                or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "goniobench")
    return base / "catalogs" / hashlib.sha256(str(Path(store).resolve()).encode()).hexdigest()[:24]


@contextlib.contextmanager
def _catalog_folder(args: argparse.Namespace) -> Iterator[tuple[Path | None, bool]]:
    """``(folder, kept)``: ``--catalog`` as given; else the store's kept catalog
    (:func:`catalog_cache`), held with an ``flock`` while served (kept True); else -- with
    ``--no-cache``, while another ``bench serve`` of the store holds it, or where it cannot be
    written -- None, a temporary catalog."""
    if args.catalog:
        yield Path(args.catalog), False
        return
    if args.no_cache:
        yield None, False
        return
    cache = catalog_cache(args.store)
    try:
        cache.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(cache.with_name(cache.name + ".lock"), os.O_RDWR | os.O_CREAT, 0o600)
    except OSError as exc:  # an unwritable cache folder costs time, never the serving
        log.warning("bench serve: not keeping the catalog in %s (%s)", cache, exc)
        yield None, False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"bench serve: note: another bench serve holds the kept catalog of {args.store}; "
                  "serving a temporary one", file=sys.stderr)
            yield None, False
        else:
            yield cache, True
    finally:
        os.close(fd)  # closing the descriptor drops the lock


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
                   help="keep the Tiled catalog (and runs written into it) in DIR (default: the catalog kept for "
                        "this store in the user's cache folder)")
    p.add_argument("--no-cache", action="store_true",
                   help="write every run anew into a temporary catalog, neither using nor keeping the kept one")
    p.add_argument("--api-key", type=api_key, default=None, metavar="KEY",
                   help="the API key writers pass, 1 to 256 ASCII letters and digits (default: a random one, printed)")
    add_service_time_limit(p)
    p.add_argument("--json", action="store_true", help="uri, api_key and the runs served as one JSON object")
    p.set_defaults(func=cmd_serve)
