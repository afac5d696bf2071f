"""Stored runs as Bluesky runs in a Tiled catalog: what ``bench serve`` serves.

:func:`run_documents` turns one stored run into the Bluesky documents of a run -- a start
document whose ``uid`` is a UUID (:func:`run_uid`: the run's own Bluesky uid when a RunEngine
wrote it, so a run a ``TiledWriter`` also wrote live is served once; else a UUID derived from the
run id, the same at every start), with the run id under ``run_id`` and a ``scan_id`` (the
RunEngine's, else the run's rank in the store), and which carries the
run's identity (``specimen``, ``bench``, ``body``, ``plan``), its ``column_units`` and the whole
metadata an export's sidecar JSON holds under ``goniobench``; one ``primary`` stream with one
event per measured point (per spectrum: a point's R and T sides are two), stamped with the time
the point was measured, its geometry and identity as scalars and every other column of ``bench
export``'s tidy CSV (:func:`bench.io.tidy_table`, same values) as an array over the run's
``wavelength_nm`` grid (NaN, False or "" where a point has no reading); rows that are not spectra
(a point holding one wavelength twice) are served one event per row; a stop document with the
run's status. Those documents are written with
``bluesky_tiled_plugins.TiledWriter`` -- the callback a beamline's RunEngine uses -- so the runs
have the structure every Bluesky/Tiled reader expects (``run["primary"].read()``; the arrays are
written as arrays, ``max_array_size=0``, where TiledWriter would keep short ones as text).

:class:`CatalogServer` runs a real Tiled server (the ``tiled`` extra) on 127.0.0.1 in a thread:
a SQLite catalog keyed by start uid (find a run by id with ``search(Key("start.run_id") == RUN)``;
a run without readings has no event stream and is not served, so ``run["primary"]`` reads for
every served run), with writable storage (a temporary folder, or ``--catalog DIR`` to keep it),
anonymous read access and one API key for writers, so a RunEngine can subscribe
``TiledWriter(from_uri(uri, api_key=KEY))`` to add its own runs next to the store's.
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import math
import secrets
import socket
import sqlite3
import tempfile
import threading
import time
import uuid
import warnings
from pathlib import Path
from typing import Any, Iterator

from bench.core.errors import DeviceError, InputError
from bench.core.outputs import atomic_write
from bench.store.check import valid_run_id
from bench.core.records import GEOMETRY_COLUMNS, hardware_name, json_default, record_identity, record_provenance

__all__ = ["run_documents", "run_uid", "scan_ids", "init_catalog", "CatalogServer", "STATUS_EXIT",
           "RUN_UID_NAMESPACE"]

log = logging.getLogger(__name__)

#: our run status -> a stop document's exit_status
STATUS_EXIT = {"completed": "success", "interrupted": "abort", "running": "abort", "failed": "fail"}


#: the namespace of the UUIDs (version 5) derived from run ids of runs no RunEngine wrote
RUN_UID_NAMESPACE = uuid.UUID("6f1c2d52-3b0e-5a8e-9f57-2f1d4c0b9a61")


def run_uid(info: Any) -> str:
    """The start uid a stored run is served with: the Bluesky uid its RunEngine gave it (a
    ``bluesky`` run written by :class:`~bench.bluesky.StoreWriter`), else a UUID derived from
    the run id (stable: a kept catalog recognises the run at the next start)."""
    meta = info.get("meta") or {}
    uid = meta.get("bluesky_uid") if isinstance(meta, dict) else None
    if isinstance(uid, str) and uid:
        return uid
    return str(uuid.uuid5(RUN_UID_NAMESPACE, str(info["run_id"])))


def scan_ids(store: Any) -> dict[str, int]:
    """Each stored run's ``scan_id``: the RunEngine's for a Bluesky run, else its rank (1, 2, ...)
    in the store's creation order."""
    out = {}
    for rank, row in enumerate(store.runs(), start=1):
        out[row["run_id"]] = rank
    return out


#: the file of a catalog folder that says from which state of its run each served run was written
#: (recorded after the run's stop document), so a kept ``--catalog`` follows the store
LEDGER = "goniobench-served.json"


#: the layout of the documents :func:`run_documents` writes; a kept copy written in another
#: layout (by an older goniobench: events in plan-index order, ``num_points`` counting rows) is
#: written again, as a copy of an older state of the run is
DOCUMENTS_LAYOUT = 2


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


#: the source of a stored column no instrument gave (the record's identity, a patch's bounds)
STORE_SOURCE = "goniobench-store"


def column_sources(meta: dict[str, Any]) -> Any:
    """``column -> source`` of a stored run: the goniometer for the geometry columns and the
    spectrometer for the readings, named as the live devices name them
    (:func:`bench.core.records.hardware_name`, from the run's stored bench description); the
    store for the record's identity and for a run no bench measured (a virtual record)."""
    desc = meta.get("bench_description") if isinstance(meta.get("bench_description"), dict) else None
    if not desc:
        return lambda column: f"{STORE_SOURCE}#{column}"

    def role(name: str) -> str:
        info = desc.get(name) if isinstance(desc.get(name), dict) else {}
        return hardware_name(desc.get("kind", "bench"), desc.get("name", "bench"), name, info.get("model"),
                             info.get("serial"))

    gonio, spectro = role("goniometer"), role("spectrometer")

    def source(column: str) -> str:
        if column in GEOMETRY_COLUMNS:
            return f"{gonio}#{column}"
        if column in _SPECTRUM_KEYS:  # the record's identity and a patch's bounds
            return f"{STORE_SOURCE}#{column}"
        return f"{spectro}#{column}"

    return source


def _data_key(column: Any, unit: str | None, source: str = STORE_SOURCE) -> dict[str, Any]:
    kind = column.dtype.kind
    dtype = "boolean" if kind == "b" else "integer" if kind in "iu" else "number" if kind == "f" else "string"
    key: dict[str, Any] = {"dtype": dtype, "shape": [], "source": source}
    if unit:
        key["units"] = unit
    return key


#: columns that say which spectrum a row belongs to (the point, its geometry and side, the
#: record's identity); every other column becomes an array over ``wavelength_nm``, one event per
#: spectrum
_SPECTRUM_KEYS = ("idx", "theta_i", "phi_i", "theta_r", "phi_r", "theta_min", "theta_max", "phi_min", "phi_max",
                  "psa", "hemisphere", "quantity", "specimen", "sample_name", "geometry", "collector", "run_id",
                  "bench", "body", "plan", "task")


def _spectra(table: Any) -> tuple[list[str], list[str], Any, Any, Any] | None:
    """``(key columns, array columns, wavelength grid, spectrum of each row, grid index of each
    row)``: the rows of each measured point (its geometry, side, quantity, specimen) as one
    spectrum over the run's wavelength grid, spectra numbered in the order of their first row;
    None when a point holds one wavelength twice (then one event per row)."""
    import numpy as np

    if "wavelength_nm" not in table.columns:
        return None
    keys = [str(c) for c in table.columns if c in _SPECTRUM_KEYS]
    arrays = [str(c) for c in table.columns if c not in keys and c != "wavelength_nm"]
    wavelengths = table["wavelength_nm"].to_numpy(float)
    grid = np.unique(wavelengths)
    spectrum = (table.groupby(keys, sort=False, dropna=False).ngroup().to_numpy() if keys
                else np.zeros(len(table), dtype=np.int64))
    at = np.searchsorted(grid, wavelengths)
    if np.unique(spectrum * grid.size + at).size < len(table):
        return None
    return keys, arrays, grid, spectrum, at


def _array_key(column: Any, unit: str | None, n: int, source: str = STORE_SOURCE) -> dict[str, Any]:
    kind = column.dtype.kind
    key: dict[str, Any] = {"dtype": "array", "shape": [n], "dims": ["wavelength_nm"], "source": source}
    if kind in "biuf":
        key["dtype_numpy"] = "|b1" if kind == "b" else "<f8"
    else:  # text (a mask reason, a budget): fixed-width unicode, as TiledWriter stores it
        key["dtype_numpy"] = f"<U{max([1, *(len(v) for v in _column_values(column))])}"
    if unit:
        key["units"] = unit
    return key


def _spectrum_arrays(column: Any, spectrum: Any, at: Any, shape: tuple[int, int]) -> list[Any]:
    """A column spread over ``shape`` = (spectra, wavelengths): row r at ``(spectrum[r], at[r])``;
    NaN, False or "" where a spectrum has no reading."""
    import numpy as np

    kind = column.dtype.kind
    if kind == "b":
        out = np.zeros(shape, dtype=bool)
        out[spectrum, at] = column.to_numpy(bool)
    elif kind not in "iuf":
        out = np.full(shape, "", dtype=object)
        out[spectrum, at] = _column_values(column)
    else:
        out = np.full(shape, np.nan)
        out[spectrum, at] = column.to_numpy(float)
    return out.tolist()


def _point_events(table: Any, units: dict[str, str], times: dict[int, float], t_end: float,
                  source: Any = lambda c: STORE_SOURCE) -> Any:
    """``(data_keys, [(data, time), ...])``: one event per measured point, its spectra as arrays
    over ``wavelength_nm`` stamped with the point's end time (``times`` by point index; the run's
    end without one); None when the rows are not spectra (see :func:`_spectra`)."""
    import numpy as np

    found = _spectra(table)
    if found is None:
        return None
    keys, arrays, grid, spectrum, at = found
    data_keys = {c: _data_key(table[c], units.get(c), source(c)) for c in keys}
    data_keys.update({c: _array_key(table[c], units.get(c), grid.size, source(c)) for c in arrays})
    data_keys["wavelength_nm"] = _array_key(table["wavelength_nm"], units.get("wavelength_nm"), grid.size,
                                            source("wavelength_nm"))
    first = np.unique(spectrum, return_index=True)[1]  # each spectrum's first row, in spectrum order
    shape = (first.size, grid.size)
    scalars = {c: _column_values(table[c].iloc[first]) for c in keys}
    spread = {c: _spectrum_arrays(table[c], spectrum, at, shape) for c in arrays}
    wavelengths = grid.tolist()
    idx = table["idx"].iloc[first].tolist() if "idx" in table.columns else [None] * first.size
    events = []
    for k in range(first.size):
        data = {c: v[k] for c, v in scalars.items()}
        data.update({c: v[k] for c, v in spread.items()})
        data["wavelength_nm"] = wavelengths
        i = idx[k]
        t = times.get(int(i), t_end) if i is not None and i == i else t_end
        events.append((data, float(t)))
    # in the order measured, as a RunEngine emits them (seq_num and time rise together): a runner
    # may measure the plan's points in another order than their index (stable for equal times)
    events.sort(key=lambda e: e[1])
    return data_keys, events


def _column_values(column: Any) -> list[Any]:
    """A column as JSON-able values: strings for text (an absent key as ""), numbers as floats or ints."""
    kind = column.dtype.kind
    if kind in "biuf":
        return column.to_numpy().tolist()
    return ["" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v) for v in column]


def _point_times(store: Any, run_id: str) -> dict[int, float]:
    """When each point of the run was measured (its ``t_end``), by point index."""
    try:
        pts = store.points(run_id)
    except (AttributeError, KeyError):
        return {}
    return {int(i): float(t) for i, t in zip(pts["idx"], pts["t_end"]) if t == t and t is not None}


def run_documents(store: Any, run_id: str, scan_id: int | None = None) -> Iterator[tuple[str, dict[str, Any]]]:
    """The Bluesky documents of stored run ``run_id`` (see the module docstring); a run without
    readings gives a start and a stop document only (no empty ``primary`` stream)."""
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
    specimens = [s for s in dict.fromkeys(table.get("specimen", [])) if s is not None and s == s]
    t0 = float(info.get("created_epoch") or time.time())
    n = len(table)
    t_end = float(info.get("finished_epoch") or t0)
    source = column_sources(meta)
    points = _point_events(table, units, _point_times(store, run_id), t_end, source) if n else None
    start_md = {"goniobench": json.loads(json.dumps({**meta, "column_units": units}, default=json_default)),
                "specimen": record_identity(meta)["specimen"] or "; ".join(map(str, specimens)) or None,
                "column_units": units, "kind": info["kind"], "status": info["status"],
                "bench": ident.get("bench"), "body": ident.get("body"), "plan_name": ident.get("plan"),
                "num_points": len(points[1]) if points is not None else n, "run_id": run_id}  # events, as Bluesky counts
    bluesky_start = meta.get("bluesky_start") if isinstance(meta.get("bluesky_start"), dict) else {}
    if isinstance(bluesky_start.get("scan_id"), int):
        start_md["scan_id"] = bluesky_start["scan_id"]
    elif scan_id is not None:
        start_md["scan_id"] = int(scan_id)
    else:
        start_md["scan_id"] = scan_ids(store).get(run_id)
    run = compose_run(uid=run_uid(info), time=t0, metadata={k: v for k, v in start_md.items() if v is not None})
    yield "start", run.start_doc
    if points is not None:  # one event per point, stamped when it was measured
        data_keys, events = points
        desc = run.compose_descriptor(name="primary", data_keys=data_keys)
        yield "descriptor", desc.descriptor_doc
        for data, t in events:
            yield "event", desc.compose_event(data=data, timestamps=dict.fromkeys(data, t), time=t, validate=False)
    elif n:  # rows that are not spectra (no wavelength, or one twice at a point): one event per row
        desc = run.compose_descriptor(name="primary", data_keys={str(c): _data_key(table[c], units.get(str(c)),
                                                                                   source(str(c)))
                                                                 for c in table.columns})
        yield "descriptor", desc.descriptor_doc
        data = {str(c): _column_values(table[c]) for c in table.columns}
        yield "event_page", desc.compose_event_page(
            data=data, timestamps={k: [t_end] * n for k in data}, seq_num=list(range(1, n + 1)), time=[t_end] * n,
            validate=False)
    yield "stop", run.compose_stop(exit_status=STATUS_EXIT.get(info["status"], "fail"),
                                   reason=info.get("reason") or "", time=float(info.get("finished_epoch") or t0))


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
        self._tmp = tempfile.TemporaryDirectory(prefix="goniobench-tiled-") if catalog is None else None
        self.directory = Path(self._tmp.name if self._tmp else catalog)
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

    def add_runs(self, store: Any, run_ids: list[str] | None = None) -> list[str]:
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
            if self._in_step(rid, uid, states.get(rid)):  # already there as the store has it
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

    def _in_step(self, run_id: str, uid: str, state: list[Any] | None) -> bool:
        """Whether the catalog holds run ``uid`` whole and as the store has it now. A copy written
        from another state of the run (served, then resumed and completed) or cut short (no stop
        document: the writer was killed) is deleted, to be written again whole."""
        if self._ledger.get(uid) == state and uid in self._served:
            return True  # written whole from this very state (recorded after its stop document)
        client = self._writer_client
        if uid not in self._served and uid not in client:  # not even written live by a RunEngine since
            return False
        stop = client[uid].metadata.get("stop")
        recorded = self._ledger.get(uid)
        if stop and (recorded == state or (recorded is None and state is not None
                                           and stop.get("exit_status") == STATUS_EXIT.get(state[0]))):
            self._served.add(uid)  # whole, and as the store has it (or written live by a RunEngine)
            self._record(uid, state)
            return True
        log.info("catalog: run %s is %s; writing it again whole", run_id,
                 "cut short (no stop document)" if not stop else "from an older state of the run")
        client.delete_contents(uid, recursive=True, external_only=False)
        self._served.discard(uid)
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

    def keep_only(self, store: Any) -> list[str]:
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
