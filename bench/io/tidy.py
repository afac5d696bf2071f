"""The project's own tables: tidy CSV (records and spectra) and Parquet, writers and readers.

tidy CSV (:func:`record_to_csv`)
    One header row of column names, then one row per record row, so plain
    ``pandas.read_csv(path)`` reads it. Floats are written with Python's shortest round-trip repr,
    so values read back exactly. Columns no row fills are left out (an identity key too: a
    spectrophotometer's record has no ``collector``); the record's identity travels in every row
    (``specimen``, ``collector``, ``quantity``, ``geometry`` and, when the metadata knows them,
    ``run_id``, ``bench``, ``body``, ``plan``, ``sample_name``: :func:`bench.core.records.record_provenance`).
    Metadata (instrument settings, calibration, versions ...) and ``column_units`` (column ->
    unit, :func:`column_units`) go by default into a sidecar JSON ``<file>.json`` beside the CSV;
    ``meta="header"`` writes the older commented header instead (``# goniobench-record 1``,
    ``# meta: <JSON>``, ``# units: <JSON>``; ``pandas.read_csv(path, comment="#")``), which
    :func:`read_tidy_csv` still reads.
Parquet (:func:`record_to_parquet`)
    The same table as the tidy CSV (the same columns), via pyarrow; the metadata as JSON under the
    key ``goniobench.meta`` and the column units under ``goniobench.units`` of the schema's
    key-value metadata, and the units with the record's identity under pandas' ``PANDAS_ATTRS``,
    which ``pandas.read_parquet`` (and :func:`read_parquet`) put in ``DataFrame.attrs``
    (:func:`frame_attrs`).

Both carry the identity key columns (``specimen``, ``collector``, ``geometry``, ``quantity``;
:func:`bench.core.records.with_keys`), written from the metadata when the table lacks them; a
reader gets them back as columns and the units as ``meta["column_units"]``.
spectrum CSV (:func:`spectrum_to_csv`)
    One row per wavelength (``bench spectro --csv``), 8 significant digits.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bench.core.errors import InputError
from bench.core.parsing import json_problem
from bench.core.records import (BSDF_COLUMNS, COLUMN_UNITS, IDENTITY_KEYS, BSDFRecord, json_default, record_provenance,
                                 value_unit, with_keys)
from bench.core.roles import Spectrum
from bench.io.files import atomic_write, check_record, check_target, meta_json, write_csv, write_text
from bench.io.reading import bad, complete, read_lines

__all__ = ["tidy_table", "frame_attrs", "PROVENANCE_COLUMNS", "RAW_UNITS", "sidecar_path", "CSV_MAGIC", "PARQUET_META_KEY", "PARQUET_UNITS_KEY", "column_units", "spectrum_table", "spectrum_to_csv", "record_to_csv",
           "record_to_parquet", "read_tidy_csv", "read_parquet", "SPECTRUM_COLUMNS", "read_spectrum_csv"]

PARQUET_META_KEY = b"goniobench.meta"
PARQUET_UNITS_KEY = b"goniobench.units"
CSV_MAGIC = "# goniobench-record 1"


def column_units(record: BSDFRecord) -> dict[str, str]:
    """Unit of every column of ``record`` that has one (:data:`COLUMN_UNITS`; values and their
    uncertainties in 1/sr for a BSDF, ``1`` for a reflectance or transmittance)."""
    unit = value_unit(record.meta)
    out = {}
    for c in record.table.columns:
        if c in COLUMN_UNITS and COLUMN_UNITS[c]:
            out[str(c)] = unit if c in ("value", "std", "ci_lo", "ci_hi", "u_c", "U") else COLUMN_UNITS[c]
        elif c in RAW_UNITS:
            out[str(c)] = RAW_UNITS[c]
    return out


#: units of the raw columns a stored run's record carries besides :data:`COLUMN_UNITS`'
RAW_UNITS = {"signal": "counts", "dark": "counts", "white": "counts", "saturated": "pixels", "idx": "point index"}
#: the provenance columns every tidy export carries when the metadata knows them
PROVENANCE_COLUMNS = ("run_id", "bench", "body", "plan", "sample_name")


def tidy_table(record: BSDFRecord) -> Any:
    """The table a tidy CSV and a Parquet file hold: the record's columns less those no row fills
    (identity keys included), then its provenance columns (:func:`bench.core.records.record_provenance`)."""
    t = with_keys(record).table
    t = t[[c for c in t.columns if c in ("quantity", "hemisphere") or t[c].notna().any()]].copy()
    for k, v in record_provenance(record.meta).items():
        if k not in t.columns or t[k].isna().all():
            t[k] = v
    return t


def frame_attrs(record: BSDFRecord, units: dict[str, str]) -> dict[str, Any]:
    """What ``DataFrame.attrs`` holds when a Parquet export is read back: ``column_units``, the
    record's ``quantity`` and identity (``specimen``, ``collector``, ``geometry`` when one value),
    provenance (``run_id``, ``bench``, ``body``, ``plan``, ``sample_name``). The full metadata stays
    under :data:`PARQUET_META_KEY` (``attrs`` is copied along by pandas operations: kept small)."""
    t = with_keys(record).table
    out: dict[str, Any] = {"column_units": dict(units)}
    for k in (*IDENTITY_KEYS, "quantity"):
        vals = [v for v in dict.fromkeys(t[k]) if v is not None]
        if len(vals) == 1:
            out[k] = str(vals[0])
    out.update(record_provenance(record.meta))
    return out


def spectrum_table(s: Spectrum) -> Any:
    """A tidy ``pandas.DataFrame``: one row per wavelength, intervals as lo/hi columns."""
    import pandas as pd

    return pd.DataFrame({
        "wavelength_nm": s.wavelengths,
        "reflectance": s.reflectance,
        "reflectance_lo": s.reflectance_ci[:, 0],
        "reflectance_hi": s.reflectance_ci[:, 1],
        "transmittance": s.transmittance,
        "transmittance_lo": s.transmittance_ci[:, 0],
        "transmittance_hi": s.transmittance_ci[:, 1],
        "N": s.N,
        "specimen": (s.meta or {}).get("specimen"),
        "geometry": s.geometry,
        "seed": s.seed,
        "confidence": 1.0 - s.delta,
    })



#: the leading columns of a spectrum CSV (what :func:`read_spectrum_csv` recognises)
SPECTRUM_COLUMNS = ("wavelength_nm", "reflectance", "reflectance_lo", "reflectance_hi", "transmittance",
                    "transmittance_lo", "transmittance_hi", "N")


def spectrum_to_csv(s: Spectrum, path: str | Path) -> Path:
    """Write :func:`spectrum_table` as CSV (atomically, :func:`bench.io.files.atomic_write`); return the path."""
    return write_csv(spectrum_table(s), path, float_format="%.8g")


def sidecar_path(path: str | Path) -> Path:
    """The metadata file of a tidy CSV: ``<file>.json`` beside it (``r.csv`` -> ``r.csv.json``)."""
    return Path(str(path) + ".json")


def record_to_csv(record: BSDFRecord, path: str | Path, *, meta: str = "sidecar") -> Path:
    """Write a record as tidy CSV (one header row; floats as shortest round-trip repr).

    Parameters
    ----------
    meta : {"sidecar", "header", "none"}
        ``sidecar``: the metadata and ``column_units`` as JSON in :func:`sidecar_path` (written
        atomically too); ``header``: ``# goniobench-record 1``, ``# meta:`` and ``# units:``
        lines before the column names (the older layout); ``none``: the table only.
    """
    check_record(record, ("wavelength_nm",))
    table = tidy_table(record)
    record = BSDFRecord(table, dict(record.meta))
    if meta not in ("header", "sidecar", "none"):
        raise InputError(f"meta must be 'header', 'sidecar' or 'none', got {meta!r}")
    check_target(path)  # both files refused before either is written
    if meta == "sidecar":
        check_target(sidecar_path(path))
    units = column_units(record)
    header = ([CSV_MAGIC, f"# meta: {meta_json(record.meta)}", f"# units: {json.dumps(units)}"]
              if meta == "header" else [])
    new = not Path(path).exists()
    out = write_csv(table, path, header_lines=header)
    if meta == "sidecar":
        side = {**record.meta, "column_units": units}
        try:
            write_text(sidecar_path(out), json.dumps(side, default=json_default, indent=1) + "\n")
        except BaseException:  # a table without its metadata is half an export: a new one goes too
            if new:
                out.unlink(missing_ok=True)
            raise
    return out


def record_to_parquet(record: BSDFRecord, path: str | Path) -> Path:
    """Write a record as Parquet; ``meta`` as JSON under :data:`PARQUET_META_KEY` in the
    schema's key-value metadata. Needs pyarrow (``pip install goniobench[parquet]``)."""
    check_record(record, ("wavelength_nm",))
    table = tidy_table(record)
    record = BSDFRecord(table, dict(record.meta))
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as e:  # pragma: no cover - pyarrow is installed here
        raise InputError("Parquet export needs pyarrow: pip install 'goniobench[parquet]'") from e
    t = pa.Table.from_pandas(table, preserve_index=False)
    md = dict(t.schema.metadata or {})
    md[PARQUET_META_KEY] = meta_json(record.meta).encode()
    units = column_units(record)
    md[PARQUET_UNITS_KEY] = json.dumps(units).encode()
    md[b"PANDAS_ATTRS"] = json.dumps(frame_attrs(record, units), default=json_default).encode()
    t = t.replace_schema_metadata(md)
    return atomic_write(path, lambda tmp: pq.write_table(t, tmp))


def read_tidy_csv(path: str | Path) -> BSDFRecord:
    """Read a tidy CSV written by :func:`bench.io.record_to_csv` (or any CSV with a
    ``wavelength_nm`` column). Metadata from the ``# meta:`` header line, else from a sidecar
    ``<file>.json``, else empty."""
    import pandas as pd

    p, lines = read_lines(path)
    meta: dict[str, Any] = {}
    units: dict[str, str] | None = None
    skip = 0
    while skip < len(lines) and lines[skip].startswith("#"):
        line = lines[skip]
        if line.startswith("# meta:"):
            try:
                meta = json.loads(line[len("# meta:"):])
            except ValueError as e:  # JSONDecodeError, or a number longer than int() takes
                raise bad(p, skip + 1, f"expected JSON after '# meta:' ({e})") from None
        elif line.startswith("# units:"):
            try:
                units = json.loads(line[len("# units:"):])
            except ValueError as e:  # JSONDecodeError, or a number longer than int() takes
                raise bad(p, skip + 1, f"expected JSON after '# units:' ({e})") from None
        skip += 1
    if skip == 0 or not lines or not lines[0].startswith(CSV_MAGIC):
        side = sidecar_path(p)
        if side.exists():
            try:
                meta = json.loads(side.read_text(encoding="utf-8"))
            except ValueError as e:  # JSONDecodeError, or a number longer than int() takes
                raise InputError(f"{side}: not valid JSON ({e})") from None
    if skip >= len(lines):
        raise bad(p, skip + 1, "expected a header line of column names, found the end of the file")
    try:
        df = pd.read_csv(p, skiprows=skip, keep_default_na=True)
    except (pd.errors.ParserError, ValueError) as e:
        raise bad(p, None, f"malformed CSV ({e})") from None
    if "wavelength_nm" not in df.columns:
        raise bad(p, skip + 1, f"expected a column wavelength_nm in the header, got {', '.join(map(str, df.columns))}")
    for c in ("count", "N"):
        if c in df.columns and df[c].notna().all() and len(df):
            df[c] = df[c].astype("int64")
    if units is not None:
        meta["column_units"] = units
    return with_keys(BSDFRecord(complete(df) if set(BSDF_COLUMNS) - set(df.columns) else df, meta))


def read_parquet(path: str | Path) -> BSDFRecord:
    """Read a Parquet file written by :func:`bench.io.record_to_parquet`."""
    try:
        import pyarrow.parquet as pq
    except ImportError as e:  # pragma: no cover
        raise InputError("Parquet import needs pyarrow: pip install 'goniobench[parquet]'") from e
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    try:
        t = pq.read_table(p)
    except Exception as e:  # pyarrow raises several types for a bad file
        raise InputError(f"{p}: not a readable Parquet file ({e})") from None
    md = t.schema.metadata or {}
    meta = _parquet_json(p, md, PARQUET_META_KEY) or {}
    units = _parquet_json(p, md, PARQUET_UNITS_KEY)
    if units:
        meta["column_units"] = units
    attrs = _parquet_json(p, md, b"PANDAS_ATTRS")
    try:
        table = t.to_pandas()
    except Exception as e:  # pyarrow's own metadata (b"pandas") read back: several types for a bad one
        raise InputError(f"{p}: not a readable Parquet file ({type(e).__name__}: {e})") from None
    rec = with_keys(BSDFRecord(table, meta))
    rec.table.attrs = attrs if attrs else {"column_units": meta.get("column_units", {})}
    return rec


def _parquet_json(p: Path, md: dict[bytes, bytes], key: bytes) -> dict[str, Any] | None:
    """The JSON object the Parquet file ``p`` holds under the schema metadata ``key`` (None when
    absent); anything else there is one line naming the file and the key."""
    raw = md.get(key)
    if not raw:
        return None
    try:
        value = json.loads(raw.decode("utf-8"))
    except ValueError as e:  # JSONDecodeError, an integer longer than int() takes, or not UTF-8
        raise InputError(f"{p}: metadata {key.decode(errors='replace')} is not valid JSON "
                         f"({json_problem(e, at=True)})") from None
    if not isinstance(value, dict):
        raise InputError(f"{p}: metadata {key.decode(errors='replace')} holds a JSON {type(value).__name__}, "
                         f"not an object")
    return value



def read_spectrum_csv(path: str | Path) -> Spectrum:
    """Read a spectrum CSV written by :func:`spectrum_to_csv` (``bench spectro --csv``) back into
    a :class:`~bench.core.roles.Spectrum` (geometry, seed and confidence from its columns)."""
    import numpy as np
    import pandas as pd

    p, lines = read_lines(path)
    try:
        df = pd.read_csv(p)
    except (pd.errors.ParserError, ValueError) as e:
        raise bad(p, None, f"malformed CSV ({e})") from None
    missing = [c for c in SPECTRUM_COLUMNS if c not in df.columns]
    if missing or df.empty:
        raise bad(p, 1, f"expected a spectrum table with columns {', '.join(SPECTRUM_COLUMNS)}"
                        + (f"; missing {', '.join(missing)}" if missing else "; it has no rows"))

    def first(col: str, default: Any) -> Any:
        return df[col].iloc[0] if col in df.columns and df[col].notna().any() else default

    seed = first("seed", None)
    conf = float(first("confidence", float("nan")))
    specimen = first("specimen", None)
    return Spectrum(geometry=str(first("geometry", "")), wavelengths=df.wavelength_nm.to_numpy(float),
                    reflectance=df.reflectance.to_numpy(float), transmittance=df.transmittance.to_numpy(float),
                    reflectance_ci=df[["reflectance_lo", "reflectance_hi"]].to_numpy(float),
                    transmittance_ci=df[["transmittance_lo", "transmittance_hi"]].to_numpy(float),
                    N=df.N.to_numpy(np.int64), seed=None if seed is None else int(seed),
                    delta=1.0 - conf if np.isfinite(conf) else float("nan"),
                    meta={"format": "spectrum-csv", "source_file": str(p),
                          **({"specimen": str(specimen)} if specimen is not None else {})})
