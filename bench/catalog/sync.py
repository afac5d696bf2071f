"""The Tiled server of ``bench serve`` and its catalog kept in step with the run store.

:class:`CatalogServer` runs a real Tiled server (the ``tiled`` extra) on 127.0.0.1 in a thread:
a SQLite catalog keyed by start uid (find a run by id with ``search(Key("start.run_id") == RUN)``;
a run without readings has no event stream and is not served, so ``run["primary"]`` reads for
every served run), with writable storage (a temporary folder, or ``--catalog DIR`` to keep it),
anonymous read access and one API key for writers, so a RunEngine can subscribe
``TiledWriter(from_uri(uri, api_key=KEY))`` to add its own runs next to the store's.
A kept catalog follows the store: :meth:`CatalogServer.add_runs` writes what is new or changed
since (:func:`served_state`, recorded in the folder's :data:`LEDGER`), deletes a copy cut short
and writes it again; the documents themselves are :func:`bench.catalog.documents.run_documents`'s.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import secrets
import socket
import sqlite3
import tempfile
import threading
import time
import uuid
import warnings
from pathlib import Path
from typing import Any

from bench.store import RunStore
from bench.core.errors import DeviceError, InputError
from bench.core.outputs import atomic_write
from bench.store.check import valid_run_id
from bench.catalog.documents import DOCUMENTS_LAYOUT, STATUS_EXIT, run_documents, run_uid, scan_ids

__all__ = ["CatalogServer", "init_catalog", "served_state", "free_port", "LEDGER"]

log = logging.getLogger(__name__)


#: the file of a catalog folder that says from which state of its run each served run was written
#: (recorded after the run's stop document), so a kept ``--catalog`` follows the store
LEDGER = "goniobench-served.json"


def served_state(row: dict[str, Any]) -> list[Any]:
    """What a served copy of a run must match (a row of ``RunStore.runs()``): status, reason,
    points done and finish time -- a resumed run that ended again differs -- and the layout of
    its documents (:data:`DOCUMENTS_LAYOUT`)."""
    return [row.get("status"), row.get("reason"), row.get("points_done"), row.get("finished_utc"),
            DOCUMENTS_LAYOUT]


def _catalog_key(uid: Any) -> bool:
    """Whether ``uid`` may name a node of the catalog (a URL path segment): a UUID."""
    try:
        return isinstance(uid, str) and str(uuid.UUID(uid)) == uid.lower()
    except ValueError:
        return False


def init_catalog(uri: str) -> None:
    """Create and stamp a Tiled SQLite catalog at ``uri`` unless it exists: what
    ``tiled.catalog.from_uri(..., init_if_not_exists=True)`` does, in this process. Tiled runs it
    as ``python -m tiled catalog init``, a second interpreter that imports tiled again: about
    20 s of a 40-s ``bench serve`` start on a loaded 2-core machine. Called before the server's
    thread starts (SQLite and its async engine stay in one thread here)."""
    import asyncio

    from sqlalchemy.ext.asyncio import create_async_engine
    from tiled.alembic_utils import UninitializedDatabase, check_database, stamp_head
    from tiled.catalog.alembic_constants import ALEMBIC_DIR, ALEMBIC_INI_TEMPLATE_PATH
    from tiled.catalog.core import ALL_REVISIONS, REQUIRED_REVISION, initialize_database
    from tiled.utils import ensure_specified_sql_driver

    uri = ensure_specified_sql_driver(uri)

    async def create() -> bool:
        engine = create_async_engine(uri)
        try:
            await check_database(engine, REQUIRED_REVISION, ALL_REVISIONS)
            return False
        except UninitializedDatabase:
            await initialize_database(engine)
            return True
        finally:
            await engine.dispose()

    if asyncio.run(create()):
        stamp_head(ALEMBIC_INI_TEMPLATE_PATH, ALEMBIC_DIR, uri)


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class CatalogServer:
    """A Tiled server on 127.0.0.1 serving a writable catalog, in a thread of this process.

    Parameters
    ----------
    port : int
        TCP port (0: a free one).
    catalog : path, optional
        Folder of the catalog (``catalog.db``, ``data/``); a temporary one when omitted.
    api_key : str, optional
        The key writers pass (``from_uri(uri, api_key=...)``); a random one when omitted.
        Reading needs none (the server listens on loopback only).
    """

    def __init__(self, port: int = 0, catalog: str | Path | None = None, api_key: str | None = None,
                 start_timeout: float = 60.0) -> None:
        import uvicorn
        from tiled.catalog import from_uri
        from tiled.config import Authentication
        from tiled.server.app import build_app

        self.api_key = api_key or secrets.token_hex(16)
        # a budget's or mask reason's text spectrum is stored as fixed-width unicode, which zarr
        # stores and reads back but warns has no Zarr V3 specification yet: once per array
        warnings.filterwarnings("ignore", message=".*does not have a Zarr V3 specification")
        self._served: set[str] | None = None  # start uids in the catalog (add_runs), listed on first use
        self._handled: set[str] = set()  # run ids add_runs has served or passed over
        self.unserved: list[str] = []  # run ids without readings (not served)
        self.damaged: dict[str, str] = {}  # run ids not served: why (damaged in the store)
        self.replaced: list[str] = []  # run ids written again whole (their copy stale or cut short)
        self.served: set[str] = set()  # run ids of the store in the catalog, written now or before
        self._states: dict[str, Any] = {}  # run id -> its served_state when last handled
        self.port = int(port) or free_port()
        try:
            with socket.socket() as probe:
                probe.bind(("127.0.0.1", self.port))
        except OSError as exc:
            raise InputError(f"--port {self.port}: cannot listen on 127.0.0.1:{self.port} ({exc.strerror})") from None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if catalog is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="goniobench-tiled-")
            catalog = self._tmp.name
        self.directory = Path(catalog)
        try:
            (self.directory / "data").mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--catalog {self.directory}: cannot create the catalog folder ({exc.strerror})") from None
        self._ledger = self._load_ledger()  # start uid -> the run's served_state it was written from
        uri = f"sqlite:///{self.directory / 'catalog.db'}"
        init_catalog(uri)
        tree = from_uri(uri,
                        writable_storage=[self.directory / "data", f"duckdb:///{self.directory / 'tables.duckdb'}"])
        app = build_app(tree, Authentication(allow_anonymous_access=True, single_user_api_key=self.api_key))
        self._server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self._thread = threading.Thread(target=self._server.run, name="goniobench-tiled", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + start_timeout
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                self.close()
                raise DeviceError(f"the Tiled server did not start on 127.0.0.1:{self.port} (port taken?)")
            time.sleep(0.05)

    @property
    def uri(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def client(self, *, write: bool = False) -> Any:
        """A ``tiled.client`` of the catalog (with the API key when ``write``)."""
        from tiled.client import from_uri

        return from_uri(self.uri, api_key=self.api_key) if write else from_uri(self.uri)

    @functools.cached_property
    def _writer_client(self) -> Any:
        """The writing client, made on first use: a start that writes nothing makes none."""
        return self.client(write=True)

    def _top_keys(self) -> set[str]:
        """The start uids at the catalog's top level, read from its SQLite file (a request-free
        read); through a client where the file's tables are not the ones this reads."""
        try:
            with contextlib.closing(sqlite3.connect(f"file:{self.directory / 'catalog.db'}?mode=ro", uri=True)) as db:
                return {str(k) for (k,) in db.execute(
                    "SELECT key FROM nodes WHERE parent = (SELECT id FROM nodes WHERE parent IS NULL)")}
        except sqlite3.Error as exc:
            log.info("catalog: listing its runs through the server (%s)", exc)
            return set(self._writer_client)

    def add_runs(self, store: RunStore, run_ids: list[str] | None = None) -> list[str]:
        """Write stored runs (default: every run not still ``running``: a run is served once it
        has ended, complete) through ``TiledWriter``; runs already in the catalog under their
        start uid (a kept ``--catalog``, served earlier, or written live by a RunEngine's
        ``TiledWriter``) are left as they are, and runs without readings are not served (listed
        in :attr:`unserved`). Returns the run ids written."""
        rows = {r["run_id"]: r for r in store.runs()}
        ids = run_ids if run_ids is not None else [rid for rid, r in rows.items() if r["status"] != "running"]
        ids = [rid for rid in ids if not self._damaged(rid, rows.get(rid))]  # never a URL from a damaged run
        states = {rid: served_state(rows[rid]) for rid in ids if rid in rows}
        # new runs, and runs served before that changed since (resumed and ended again): served whole
        new = [rid for rid in ids if rid not in self._handled or self._states.get(rid) != states.get(rid)]
        if not new:
            return []  # the 2-s poll of `bench serve`: nothing new, no request to the server
        if self._served is None:  # what a kept --catalog already holds, listed once
            self._served = self._top_keys()
        ranks = scan_ids(store)
        written = []
        for rid in new:
            self._handled.add(rid)
            self._states[rid] = states.get(rid)
            uid = run_uid(store.run(rid))
            if not _catalog_key(uid):
                self.damaged[rid] = f"start uid {uid[:60]!r} is not a UUID"
                continue
            if self._in_step(rid, uid, states.get(rid), self._served):  # already there as the store has it
                self.served.add(rid)
                continue
            docs = list(run_documents(store, rid, ranks.get(rid)))
            if not any(name in ("event", "event_page") for name, _ in docs):
                self.unserved.append(rid)  # nothing measured: no event stream to read
                continue
            from bluesky_tiled_plugins import TiledWriter  # seconds to import: only when a run is written

            writer = TiledWriter(self._writer_client, max_array_size=0)  # spectra as arrays (zarr), not text in the table
            for name, doc in docs:
                writer(name, doc)
            self._served.add(uid)
            self._record(uid, states.get(rid))  # after the stop document: a kill before it is redone
            written.append(rid)
            self.served.add(rid)
        return written

    # -- keeping a kept catalog in step with the store -------------------------------------------
    def _damaged(self, run_id: Any, row: dict[str, Any] | None) -> bool:
        """Whether a run is damaged (its id not the store's format, a field that does not parse):
        such a run is never turned into a request; listed in :attr:`damaged`."""
        why = None if row is None else row.get("damaged")
        if why is None and not valid_run_id(run_id):
            why = "run id is not of the store's format"
        if why:
            self.damaged[str(run_id)] = str(why)
        return bool(why)

    def _in_step(self, run_id: str, uid: str, state: list[Any] | None, served: set[str]) -> bool:
        """Whether the catalog holds run ``uid`` whole and as the store has it now (``served``: the
        start uids known in it, kept up to date here). A copy written from another state of the run
        (served, then resumed and completed) or cut short (no stop document: the writer was killed)
        is deleted, to be written again whole."""
        if self._ledger.get(uid) == state and uid in served:
            return True  # written whole from this very state (recorded after its stop document)
        client = self._writer_client
        if uid not in served and uid not in client:  # not even written live by a RunEngine since
            return False
        stop = client[uid].metadata.get("stop")
        recorded = self._ledger.get(uid)
        if stop and (recorded == state or (recorded is None and state is not None
                                           and stop.get("exit_status") == STATUS_EXIT.get(state[0]))):
            served.add(uid)  # whole, and as the store has it (or written live by a RunEngine)
            self._record(uid, state)
            return True
        log.info("catalog: run %s is %s; writing it again whole", run_id,
                 "cut short (no stop document)" if not stop else "from an older state of the run")
        client.delete_contents(uid, recursive=True, external_only=False)
        served.discard(uid)
        self.replaced.append(run_id)
        return False

    def _record(self, uid: str, state: list[Any] | None) -> None:
        """Note in the ledger that ``uid`` is in the catalog whole, written from ``state``."""
        if self._ledger.get(uid) == state:
            return
        self._ledger[uid] = state
        text = json.dumps(self._ledger, sort_keys=True, default=str)
        atomic_write(self.directory / LEDGER, lambda tmp: tmp.write_text(text, encoding="utf-8"), force=True)

    def _load_ledger(self) -> dict[str, Any]:
        try:
            ledger = json.loads((self.directory / LEDGER).read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except (OSError, ValueError) as exc:  # every served run is then checked against its stop document
            log.warning("catalog: ignoring %s (%s)", self.directory / LEDGER, exc)
            return {}
        return ledger if isinstance(ledger, dict) else {}

    def keep_only(self, store: RunStore) -> list[str]:
        """Delete every run of the catalog that is not a run of ``store`` (a copy of a catalog
        served before, holding runs since deleted from the store or written live then by a
        RunEngine alone); returns their start uids."""
        wanted = {run_uid(store.run(row["run_id"])) for row in store.runs()}
        gone = sorted(uid for uid in self._top_keys() if uid not in wanted)
        for uid in gone:
            self._writer_client.delete_contents(uid, recursive=True, external_only=False)
            self._ledger.pop(uid, None)
        return gone

    @property
    def running(self) -> bool:
        """Whether the server's thread still runs (after :meth:`close`: it did not stop in time)."""
        return self._thread.is_alive()

    def close(self) -> None:
        """Stop the server and remove a temporary catalog. Idempotent."""
        self._server.should_exit = True
        if self._thread.is_alive():
            self._thread.join(10)
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> "CatalogServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
