"""A stored run as the Bluesky documents of a run: what ``bench serve`` writes to its catalog.

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
written as arrays, ``max_array_size=0``, where TiledWriter would keep short ones as text) by
:class:`bench.catalog.sync.CatalogServer`.
"""

from __future__ import annotations

import json
import math
import time
import uuid
from typing import TYPE_CHECKING, Any, Iterator, Literal

from bench.store import RunStore
from bench.core.records import GEOMETRY_COLUMNS, hardware_name, json_default, record_identity, record_provenance

if TYPE_CHECKING:  # annotations only: event_model is imported where documents are composed
    from event_model.documents import Document

__all__ = ["run_documents", "run_uid", "scan_ids", "STATUS_EXIT", "RUN_UID_NAMESPACE",
           "DOCUMENTS_LAYOUT", "STORE_SOURCE", "column_sources"]

#: a stop document's exit_status
ExitStatus = Literal["success", "abort", "fail"]
#: our run status -> a stop document's exit_status
STATUS_EXIT: dict[str, ExitStatus] = {"completed": "success", "interrupted": "abort", "running": "abort", "failed": "fail"}


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


def scan_ids(store: RunStore) -> dict[str, int]:
    """Each stored run's ``scan_id``: the RunEngine's for a Bluesky run, else its rank (1, 2, ...)
    in the store's creation order."""
    out = {}
    for rank, row in enumerate(store.runs(), start=1):
        out[row["run_id"]] = rank
    return out



#: the layout of the documents :func:`run_documents` writes; a kept copy written in another
#: layout (by an older goniobench: events in plan-index order, ``num_points`` counting rows) is
#: written again, as a copy of an older state of the run is
DOCUMENTS_LAYOUT = 2


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


def _point_times(store: RunStore, run_id: str) -> dict[int, float]:
    """When each point of the run was measured (its ``t_end``), by point index."""
    try:
        pts = store.points(run_id)
    except (AttributeError, KeyError):
        return {}
    return {int(i): float(t) for i, t in zip(pts["idx"], pts["t_end"]) if t == t and t is not None}


def run_documents(store: RunStore, run_id: str, scan_id: int | None = None) -> Iterator[tuple[str, Document]]:
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
    given = meta.get("bluesky_start")
    bluesky_start = given if isinstance(given, dict) else {}
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

