"""Writing files safely: the one atomic writer, the one CSV writer and the JSON of metadata.

Every export of :mod:`bench.io` goes through :func:`atomic_write`: the file is written to a
temporary file in the same folder, flushed and fsynced, then moved over the target with
:func:`os.replace`, so a reader (or a crash) never sees a half-written export. CSV tables (tidy
records, spectra, ``bench gonio --csv``) are all written by :func:`write_csv`.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Sequence

from bench.core.errors import InputError
from bench.core.records import BSDFRecord, json_default

__all__ = ["atomic_write", "write_text", "write_csv", "meta_json", "check_record"]


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, fsync it, then
    ``os.replace`` it onto ``path`` (parent folders created). The file gets the mode a plain
    ``open`` would give (``0666`` less the umask: 0644 usually), not ``mkstemp``'s 0600. On any
    error the temporary file is removed and ``path`` is left as it was. Returns ``path``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; a file people share reads as any other
        write(tmp_path)
        with open(tmp_path, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp_path, p)
    except BaseException:
        try:
            tmp_path.unlink()
        except FileNotFoundError:
            pass
        raise
    return p


def _umask() -> int:
    """The process umask (read by setting it and putting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8, ``\\n`` line ends) atomically; return the path."""
    def w(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    return atomic_write(path, w)


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

