"""Stored runs as Bluesky runs in a Tiled catalog: what ``bench serve`` serves.

:func:`run_documents` turns one stored run into the Bluesky documents of a run -- a start
document whose ``uid`` is the run id (so the catalog is keyed by run id) and which carries the
run's identity (``specimen``, ``bench``, ``body``, ``plan``), its ``column_units`` and the whole
metadata an export's sidecar JSON holds under ``goniobench``; one ``primary`` stream whose event
rows are exactly the rows of ``bench export``'s tidy CSV (:func:`bench.io.tidy_table`, same
columns, same values); a stop document with the run's status. Those documents are written with
``bluesky_tiled_plugins.TiledWriter`` -- the callback a beamline's RunEngine uses -- so the runs
have the structure every Bluesky/Tiled reader expects (``client[run_id]["primary"].read()``).

:class:`CatalogServer` runs a real Tiled server (the ``tiled`` extra) on 127.0.0.1 in a thread:
a SQLite catalog with writable storage (a temporary folder, or ``--catalog DIR`` to keep it),
anonymous read access and one API key for writers, so a RunEngine can subscribe
``TiledWriter(from_uri(uri, api_key=KEY))`` to add its own runs next to the store's.
"""

from __future__ import annotations

import json
import math
import secrets
import socket
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Iterator

from bench.core.errors import DeviceError, InputError
from bench.core.records import json_default, record_identity, record_provenance

__all__ = ["run_documents", "CatalogServer", "STATUS_EXIT"]

#: our run status -> a stop document's exit_status
STATUS_EXIT = {"completed": "success", "interrupted": "abort", "running": "abort", "failed": "fail"}


def _data_key(column: Any, unit: str | None) -> dict[str, Any]:
    kind = column.dtype.kind
    dtype = "boolean" if kind == "b" else "integer" if kind in "iu" else "number" if kind == "f" else "string"
    key: dict[str, Any] = {"dtype": dtype, "shape": [], "source": "goniobench-store"}
    if unit:
        key["units"] = unit
    return key


def _column_values(column: Any) -> list[Any]:
    """A column as JSON-able values: strings for text (an absent key as ""), numbers as floats or ints."""
    kind = column.dtype.kind
    if kind in "biuf":
        return column.to_numpy().tolist()
    return ["" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v) for v in column]


def run_documents(store: Any, run_id: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """The Bluesky documents of stored run ``run_id`` (see the module docstring)."""
    import pandas as pd
    from event_model import compose_run

    from bench.io import run_records, tidy_table
    from bench.io.tidy import column_units

    info = store.run(run_id)
    parts = run_records(store, run_id)
    table = pd.concat([tidy_table(rec) for _, rec in parts], ignore_index=True)
    meta = dict(parts[0][1].meta) if len(parts) == 1 else {**parts[0][1].meta, "specimen": None}
    units = {}
    for _, rec in parts:
        units.update(column_units(rec))
    ident = record_provenance(meta)
    specimens = [s for s in dict.fromkeys(table["specimen"]) if s is not None and s == s]
    t0 = float(info.get("created_epoch") or time.time())
    start_md = {"goniobench": json.loads(json.dumps({**meta, "column_units": units}, default=json_default)),
                "specimen": record_identity(meta)["specimen"] or "; ".join(map(str, specimens)) or None,
                "column_units": units, "kind": info["kind"], "status": info["status"],
                "bench": ident.get("bench"), "body": ident.get("body"), "plan_name": ident.get("plan"),
                "num_points": int(len(table))}
    run = compose_run(uid=run_id, time=t0, metadata={k: v for k, v in start_md.items() if v is not None})
    yield "start", run.start_doc
    desc = run.compose_descriptor(name="primary", data_keys={str(c): _data_key(table[c], units.get(str(c)))
                                                             for c in table.columns})
    yield "descriptor", desc.descriptor_doc
    n = len(table)
    if n:
        t_end = float(info.get("finished_epoch") or t0)
        data = {str(c): _column_values(table[c]) for c in table.columns}
        yield "event_page", desc.compose_event_page(
            data=data, timestamps={k: [t_end] * n for k in data}, seq_num=list(range(1, n + 1)), time=[t_end] * n,
            validate=False)
    yield "stop", run.compose_stop(exit_status=STATUS_EXIT.get(info["status"], "fail"),
                                   reason=info.get("reason") or "", time=float(info.get("finished_epoch") or t0))


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
        self._served: set[str] | None = None  # run ids in the catalog (add_runs), listed on first use
        self.port = int(port) or free_port()
        try:
            with socket.socket() as probe:
                probe.bind(("127.0.0.1", self.port))
        except OSError as exc:
            raise InputError(f"--port {self.port}: cannot listen on 127.0.0.1:{self.port} ({exc.strerror})") from None
        self._tmp = tempfile.TemporaryDirectory(prefix="goniobench-tiled-") if catalog is None else None
        self.directory = Path(self._tmp.name if self._tmp else catalog)
        try:
            (self.directory / "data").mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--catalog {self.directory}: cannot create the catalog folder ({exc.strerror})") from None
        tree = from_uri(f"sqlite:///{self.directory / 'catalog.db'}", init_if_not_exists=True,
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

    def add_runs(self, store: Any, run_ids: list[str] | None = None) -> list[str]:
        """Write stored runs (default: every run not still ``running``: a run is served once it
        has ended, complete) through ``TiledWriter``; runs already in the catalog (a kept
        ``--catalog``, or served earlier) are left as they are. Returns the run ids written."""
        from bluesky_tiled_plugins import TiledWriter

        ids = run_ids if run_ids is not None else [r["run_id"] for r in store.runs() if r["status"] != "running"]
        if self._served is not None and self._served.issuperset(ids):
            return []  # the 2-s poll of `bench serve`: nothing new, no request to the server
        client = self.client(write=True)
        if self._served is None:  # what a kept --catalog already holds, listed once
            self._served = set(client)
        written = []
        for rid in ids:
            if rid in self._served:
                continue
            writer = TiledWriter(client)
            for name, doc in run_documents(store, rid):
                writer(name, doc)
            self._served.add(rid)
            written.append(rid)
        return written

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
