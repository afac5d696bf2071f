"""Deprecated: moved to :mod:`bench.io` (writers) -- this module re-exports it for one release.

Import from :mod:`bench.io` instead (``from bench.io import export_record, record_to_csv, ...``).
"""

from __future__ import annotations

from bench.core.records import json_default
from bench.io import (CSV_MAGIC, FORMATS, PARQUET_META_KEY, ZemaxGrid, atomic_write, export_record, export_run,
                      from_specular, record_to_astm, record_to_csv, record_to_parquet, record_to_zemax,
                      spectrum_table, spectrum_to_csv, specular_frame, to_specular, zemax_grid)
from bench.io.registry import infer_format as _infer_format  # noqa: F401 - old private name

__all__ = [
    "spectrum_table", "spectrum_to_csv", "atomic_write", "json_default",
    "record_to_csv", "record_to_parquet", "record_to_astm", "record_to_zemax", "ZemaxGrid", "zemax_grid",
    "specular_frame", "to_specular", "from_specular", "export_record", "export_run", "FORMATS",
    "PARQUET_META_KEY", "CSV_MAGIC",
]
