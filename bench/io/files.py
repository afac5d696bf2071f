"""Writing files safely: the one writer every output goes through, the one CSV writer and the
JSON of metadata.

Every file goniobench writes on a user's behalf -- exports, the sidecar, ``bench spectro --csv``,
white reference files, plots (:func:`save_figure`) -- goes through :func:`atomic_write` (which
lives in :mod:`bench.core.outputs`, so the layers below ``bench.io`` write through it too):

* a path that exists and is not a regular file (a device node such as ``/dev/full``, a FIFO, a
  socket, a folder) is refused in one line (:class:`~bench.core.errors.InputError`, exit 2): a
  device is never replaced by a file, nor written into;
* an existing file is replaced only when replacing is allowed (:func:`replacing`: the CLI's
  ``--force``; the Python API replaces by default); otherwise one line naming the file (exit 2);
* the folder must exist: no folder is created unasked;
* the bytes go to a temporary file in the same folder, flushed and fsynced, then moved over the
  target with :func:`os.replace`, so a reader (or a crash) never sees a half-written file;
* a full disk or an I/O error (ENOSPC, EDQUOT, EFBIG, EIO, EROFS) is one line,
  :class:`WriteFailed` (exit 1), with the temporary file removed and the target as it was.

CSV tables (tidy records, spectra, white references) are all written by :func:`write_csv`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from bench.core.errors import InputError
from bench.core.outputs import WriteFailed, atomic_write, check_target, replacing, save_figure, write_text
from bench.core.records import BSDFRecord, json_default

__all__ = ["atomic_write", "write_text", "write_csv", "save_figure", "meta_json", "check_record", "check_target",
           "replacing", "WriteFailed", "require_bsdf", "BSDF_QUANTITIES"]


def write_csv(table: Any, path: str | Path, *, header_lines: Sequence[str] = (),
              float_format: str | None = None) -> Path:
    """The one CSV writer: a ``pandas.DataFrame`` without its index, after ``header_lines``
    (each written as given, e.g. ``# goniobench-record 1``), atomically.

    ``float_format=None`` writes floats as Python's shortest round-trip repr (values read back
    exactly); ``"%.8g"`` is what the human-facing ``--csv`` options use.
    """
    # pandas formats floats through numpy's str(), which numpy's print options change (colour-science
    # sets legacy="1.13": 12 significant digits), so the round-trip repr is asked for explicitly
    body = table.to_csv(index=False, lineterminator="\n", float_format=float_format or _repr)
    return write_text(path, "".join(f"{h}\n" for h in header_lines) + body)


def _repr(x: float) -> str:
    return repr(float(x))


def meta_json(meta: dict[str, Any]) -> str:
    """Metadata as one line of JSON (the project's one encoder)."""
    return json.dumps(meta, default=json_default)


def check_record(record: Any, need: Sequence[str] = ("wavelength_nm", "theta_i", "phi_i", "theta_r",
                                                       "phi_r", "value")) -> Any:
    import pandas as pd

    if not isinstance(record, BSDFRecord) or not isinstance(record.table, pd.DataFrame):
        raise InputError(f"expected a BSDFRecord with a pandas table, got {type(record).__name__}")
    missing = [c for c in need if c not in record.table.columns]
    if missing:
        raise InputError(f"record has no column(s) {', '.join(missing)}")
    return record.table



#: what ``quantity`` says of a BSDF (values in 1/sr, per viewing direction)
BSDF_QUANTITIES = frozenset({"bsdf", "brdf", "btdf", "1/sr"})


def require_bsdf(record: Any, fmt: str) -> Any:
    """Refuse (one line naming the record's kind) a record that is not a BSDF for a format that
    can only say BSDF (ASTM, Zemax): a spectrophotometer's reflectance or transmittance (8/d,
    d/8, 45/0: unitless, with no viewing direction) is never written as a BRDF. Returns the table."""
    import numpy as np
    import pandas as pd

    if not isinstance(record, BSDFRecord) or not isinstance(record.table, pd.DataFrame):
        raise InputError(f"expected a BSDFRecord with a pandas table, got {type(record).__name__}")
    t, meta = record.table, record.meta
    qs = ([str(q) for q in dict.fromkeys(t["quantity"]) if q is not None and q == q] if "quantity" in t.columns
          else [])
    qs = qs or [str(meta.get("quantity") or "BSDF")]
    other = [q for q in qs if q.strip().lower() not in BSDF_QUANTITIES]
    geometries = ([str(g) for g in dict.fromkeys(t["geometry"]) if g is not None and g == g]
                  if "geometry" in t.columns else [])
    if not geometries and isinstance(meta.get("geometry"), str):
        geometries = [meta["geometry"]]
    where = f"{', '.join(geometries)} geometry: " if geometries else ""
    if other:
        spectro = all(q.strip().lower() in ("reflectance", "reflectance factor", "transmittance") for q in other)
        what = f" ({where}unitless, no viewing direction)" if spectro else (f" ({where.rstrip(': ')})" if where else "")
        raise InputError(f"this record holds a {' and '.join(dict.fromkeys(other))}{what}, not a BSDF: {fmt} "
                         f"holds BSDF values in 1/sr; export it as csv or parquet")
    if not {"theta_r", "phi_r"} <= set(t.columns) or not np.isfinite(t[["theta_r", "phi_r"]].to_numpy(float)).any():
        raise InputError(f"this record has no viewing direction (theta_r, phi_r): {fmt} holds a BSDF per viewing "
                         f"direction; export it as csv or parquet")
    return t
