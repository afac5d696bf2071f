"""The one registry of record file formats: name -> (reader, writer, suffixes, magic).

Everything that reads or writes a record file -- ``bench export``, ``bench compare``, the Python
API -- goes through :func:`read_record` / :func:`export_record`, which look the format up here:
by the name given, else by the file's first line (its *magic*, e.g. the tidy CSV's header row
or ``SOURCE ...`` for ASTM), else by its suffix. A lab adds a format with
:func:`register_format`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from bench.core.errors import InputError
from bench.core.plugins import FORMAT_GROUP, load_plugins
from bench.core.records import BSDF_COLUMNS, BSDFRecord, with_keys
from bench.core.roles import Spectrum
from bench.io.astm import read_astm, record_to_astm
from bench.io.gonio_json import is_gonio_json, read_gonio_json
from bench.io.tidy import (CSV_MAGIC, SPECTRUM_COLUMNS, read_parquet, read_spectrum_csv, read_tidy_csv,
                           record_to_csv, record_to_parquet)
from bench.io.zemax import read_zemax, record_to_zemax

__all__ = ["FileFormat", "FORMATS", "register_format", "formats", "infer_format", "read_record",
           "export_record", "default_suffix", "suffix_format", "suffixes"]


@dataclass(frozen=True)
class FileFormat:
    """One record file format.

    Attributes
    ----------
    name : what ``--format`` / ``fmt=`` call it
    suffixes : file-name endings that select it (longest match wins), first = default suffix
    reader : ``reader(path, **options) -> BSDFRecord | Spectrum`` (None: write-only)
    writer : ``writer(record, path, **options) -> Path`` (None: read-only)
    magic : ``magic(first_line) -> bool``, recognising the format from the file's first line
    """

    name: str
    suffixes: tuple[str, ...]
    reader: Callable[..., BSDFRecord | Spectrum] | None
    writer: Callable[..., Path] | None
    magic: Callable[[str], bool] | None = None


_REGISTRY: dict[str, FileFormat] = {}


def register_format(fmt: FileFormat) -> None:
    """Add (or replace) a format; its name and suffixes become known to every reader and writer."""
    _REGISTRY[fmt.name] = fmt


def _register_plugin(entry: str, obj: Any) -> None:
    """A ``goniobench.formats`` entry point: a :class:`FileFormat`."""
    if not isinstance(obj, FileFormat):
        raise InputError(f"expected a bench.io.registry.FileFormat, got {obj!r}")
    if obj.name in _REGISTRY:
        raise InputError(f"format name {obj.name!r} is already taken")
    register_format(obj)


def _registry() -> dict[str, FileFormat]:
    """The registered formats, those of installed ``goniobench.formats`` plugins included."""
    load_plugins(FORMAT_GROUP, _register_plugin)
    return _REGISTRY


def formats(*, readable: bool | None = None, writable: bool | None = None) -> tuple[str, ...]:
    """Names of the registered formats (optionally only those with a reader / a writer)."""
    return tuple(n for n, f in _registry().items()
                 if (readable is None or (f.reader is not None) == readable)
                 and (writable is None or (f.writer is not None) == writable))


def _spectrum_header(line: str) -> bool:
    cols = [c.strip() for c in line.split(",")]
    return cols[:len(SPECTRUM_COLUMNS)] == list(SPECTRUM_COLUMNS)


def _tidy_header(line: str) -> bool:
    """Our tidy CSV: the older ``# goniobench-record`` line, or a header row that starts with
    the columns every record has (``wavelength_nm, theta_i, phi_i, theta_r, phi_r, hemisphere, value``)."""
    cols = [c.strip() for c in line.split(",")]
    return line.startswith(CSV_MAGIC) or cols[:7] == BSDF_COLUMNS[:7]


register_format(FileFormat("csv", (".csv",), read_tidy_csv, record_to_csv, _tidy_header))
register_format(FileFormat("parquet", (".parquet", ".pq"), read_parquet, record_to_parquet,
                           lambda line: line.startswith("PAR1")))
register_format(FileFormat("astm", (".astm.csv", ".astm"), read_astm, record_to_astm,
                           lambda line: re.match(r"^(VARS|[A-Z][A-Z0-9_]*) \S", line) is not None))  # KEYWORD value
register_format(FileFormat("zemax", (".bsdf",), read_zemax, record_to_zemax,
                           lambda line: line.startswith(("# goniobench Zemax", "Source ", "Source\t"))))
register_format(FileFormat("spectrum-csv", (".spectrum.csv",), read_spectrum_csv, None, _spectrum_header))
register_format(FileFormat("gonio-json", (".json",), read_gonio_json, None, is_gonio_json))

#: the project's own formats that write a record of a run (``bench export --format`` also offers
#: those of installed plugins: :func:`formats` with ``writable=True``)
FORMATS = tuple(n for n, f in _REGISTRY.items() if f.writer is not None)


def suffixes(*, writable: bool | None = None) -> tuple[str, ...]:
    """Every suffix of the registered formats (optionally only of those with a writer)."""
    return tuple(s for f in _registry().values() if writable is None or (f.writer is not None) == writable
                 for s in f.suffixes)


def default_suffix(fmt: str) -> str:
    """The suffix a file of ``fmt`` gets when the user names none (``astm`` -> ``.astm.csv``)."""
    if fmt not in _registry():
        raise InputError(f"unknown format {fmt!r}; known: {', '.join(_registry())}")
    return _registry()[fmt].suffixes[0]


def suffix_format(path: str | Path) -> str | None:
    """The format whose suffix ``path`` ends with (longest match), None when none does."""
    return _by_suffix(Path(path))


def _by_suffix(path: Path) -> str | None:
    name = path.name.lower()
    best: tuple[int, str] | None = None
    for f in _registry().values():
        for suf in f.suffixes:
            if name.endswith(suf) and (best is None or len(suf) > best[0]):
                best = (len(suf), f.name)
    return best[1] if best else None


def _first_line(path: Path) -> str | None:
    try:
        with open(path, "rb") as fh:
            raw = fh.readline(4096)
    except OSError:
        return None
    return raw.decode("utf-8", errors="replace").rstrip("\r\n")


def infer_format(path: str | Path, *, reading: bool = False) -> str:
    """The format of ``path``: from its first line when ``reading`` an existing file (a magic
    line wins over the suffix: a ``.csv`` may hold our tidy record, an ASTM table or a
    spectrum), else from its suffix.

    Raises
    ------
    InputError
        When neither tells.
    """
    p = Path(path)
    if reading and p.is_file():
        line = _first_line(p)
        if line is not None:
            for f in _registry().values():
                if f.reader is not None and f.magic is not None and f.magic(line):
                    return f.name
    fmt = _by_suffix(p)
    if fmt is None:
        known = ", ".join(s for f in _registry().values() for s in f.suffixes)
        raise InputError(f"cannot tell the {'import' if reading else 'export'} format from {p.name!r}; pass fmt= "
                         f"one of {', '.join(_registry())} ({known})")
    return fmt


def _lookup(fmt: str, *, reading: bool) -> FileFormat:
    f = _registry().get(fmt)
    if f is None or (f.reader if reading else f.writer) is None:
        known = formats(readable=True) if reading else formats(writable=True)
        raise InputError(f"unknown {'import' if reading else 'export'} format {fmt!r}; known: {', '.join(known)}")
    return f


def read_record(path: str | Path, fmt: str | None = None, **options: Any) -> BSDFRecord | Spectrum:
    """Read a record file in ``fmt`` (default: inferred, see :func:`infer_format`); a BSDF
    record comes back with its identity key columns (:func:`bench.core.records.with_keys`)."""
    p = Path(path)
    f = _lookup(infer_format(p, reading=True) if fmt is None else fmt, reading=True)
    assert f.reader is not None  # _lookup(reading=True) finds only formats that read
    rec = f.reader(p, **options)
    return with_keys(rec) if isinstance(rec, BSDFRecord) else rec


def export_record(record: BSDFRecord, path: str | Path, fmt: str | None = None, **options: Any) -> Path:
    """Write a record in ``fmt`` (``csv``, ``parquet``, ``astm``, ``zemax``; default from the
    file name) with the format's ``options``; return the path."""
    p = Path(path)
    f = _lookup(infer_format(p) if fmt is None else fmt, reading=False)
    assert f.writer is not None  # _lookup(reading=False) finds only formats that write
    return f.writer(record, p, **options)
