"""Record files in and out: the one format registry (:mod:`bench.io.registry`) and its formats.

* :func:`read_record` / :func:`export_record` -- any registered format, by name or inferred from
  the file (first line, then suffix); :func:`export_run` -- a stored run.
* formats: tidy CSV and Parquet (:mod:`bench.io.tidy`), "ASTM" CSV (:mod:`bench.io.astm`), Zemax
  tabular BSDF (:mod:`bench.io.zemax`, angles of :mod:`bench.io.specular`), the spectrum CSV of
  ``bench spectro --csv``.
* :func:`run_records` -- what an export holds of a stored run (one record per specimen);
  :func:`load_run` -- a stored run as a keyed record (:mod:`bench.io.runs`: sweeps with their
  specimen/collector columns, spectro sweeps and spectral scans as spectra).
* :func:`atomic_write` (refuses devices, FIFOs, folders and, without :func:`replacing`, existing
  files), :func:`save_figure` and the one CSV writer :func:`write_csv` (:mod:`bench.io.files`).

The CLI (``bench export``, ``bench compare``) and the Python API read and write through here;
:mod:`compare` takes records and never reads files itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.core.records import BSDFRecord, record_identity
from bench.io.astm import read_astm, record_to_astm
from bench.io.files import WriteFailed, atomic_write, replacing, save_figure, write_csv
from bench.io.registry import (FORMATS, FileFormat, default_suffix, export_record, formats, infer_format,
                               read_record, register_format)
from bench.io.runs import load_run, spectral_scan_spectra, sweep_record
from bench.sweep.records import sweep_table
from bench.io.specular import from_specular, specular_frame, to_specular
from bench.io.tidy import (CSV_MAGIC, PARQUET_META_KEY, read_parquet, read_spectrum_csv, read_tidy_csv,
                           record_to_csv, record_to_parquet, spectrum_table, spectrum_to_csv, tidy_table)
from bench.io.zemax import ZemaxGrid, read_zemax, record_to_zemax, record_to_zemax_files, zemax_grid
from bench.store import RunStore

__all__ = ["run_records", "tidy_table", "load_run", "sweep_record", "spectral_scan_spectra", "read_record", "export_record", "export_run", "FORMATS", "FileFormat", "register_format", "formats",
           "infer_format", "default_suffix", "atomic_write", "write_csv", "save_figure", "replacing", "WriteFailed", "CSV_MAGIC", "PARQUET_META_KEY",
           "record_to_csv", "record_to_parquet", "record_to_astm", "record_to_zemax", "read_tidy_csv",
           "read_parquet", "read_astm", "read_zemax", "read_spectrum_csv", "spectrum_table", "spectrum_to_csv",
           "ZemaxGrid", "zemax_grid", "record_to_zemax_files", "specular_frame", "to_specular", "from_specular"]


def export_run(store: RunStore | str | Path, run_id: str, path: str | Path, fmt: str | None = None,
               **options: Any) -> Path:
    """Export a stored run (``store`` is a :class:`bench.store.RunStore` or a path to one)."""
    if isinstance(store, RunStore):
        return export_record(_exportable(store, run_id), path, fmt, **options)
    with RunStore(store, create=False) as s:
        return export_record(_exportable(s, run_id), path, fmt, **options)


def run_records(store: RunStore, run_id: str) -> list[tuple[str | None, BSDFRecord]]:
    """What ``bench export`` (and ``bench serve``) write of a stored run: ``[(None, record)]``,
    or for a sweep of several specimens ``[(specimen, its record), ...]`` (a file holds one
    specimen); the record's ``meta["specimen"]`` names it whenever its rows do."""
    record = _exportable(store, run_id)
    t = record.table
    if "quantity" in t.columns and "hemisphere" in t.columns:  # a spectrum's T rows are its transmittance
        is_t = (t["hemisphere"] == "T") & t["quantity"].isin(["reflectance", "reflectance factor"])
        if is_t.any():
            t = t.copy()
            t.loc[is_t, "quantity"] = "transmittance"
            record = BSDFRecord(t, record.meta)
    specimens = [s for s in dict.fromkeys(record.table.get("specimen", [])) if s is not None]
    if len(specimens) <= 1:
        if specimens and not record_identity(record.meta)["specimen"]:
            record = BSDFRecord(record.table, {**record.meta, "specimen": specimens[0]})
        return [(None, record)]
    return [(s, BSDFRecord(record.table[record.table.specimen == s].reset_index(drop=True),
                           {**record.meta, "specimen": s})) for s in specimens]


def _exportable(store: RunStore, run_id: str) -> Any:
    """The keyed record of a run as rows: a sweep with its tasks' keys (a spectrophotometric one
    as reflectance rows with their CIE geometry, :func:`bench.sweep.records.sweep_table`), a
    spectral scan as the store's record of it, any other run as :func:`load_run` gives it."""
    if store.run(run_id)["kind"] == "sweep":
        return sweep_table(store, run_id)
    rec = load_run(store, run_id)
    return rec if not isinstance(rec, tuple) else store.to_record(run_id)
