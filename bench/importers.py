"""Deprecated: moved to :mod:`bench.io` (readers) -- this module re-exports it for one release.

Import from :mod:`bench.io` instead (``from bench.io import read_record, read_tidy_csv, ...``).
"""

from __future__ import annotations

from bench.io import read_astm, read_parquet, read_record, read_tidy_csv, read_zemax

__all__ = ["read_tidy_csv", "read_parquet", "read_astm", "read_zemax", "read_record"]
