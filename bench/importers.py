"""Importers: files written by :mod:`bench.export` (and by other tools in the same layouts)
back into :class:`bench.core.records.BSDFRecord` (angles in degrees inside).

* :func:`read_tidy_csv` — our tidy CSV, metadata from the ``# meta:`` header or ``<file>.json``.
* :func:`read_parquet` — our Parquet, metadata from the schema's ``goniobench.meta`` key.
* :func:`read_astm` — the "ASTM" CSV layout (keywords, ``VARS``, rows in radians).
* :func:`read_zemax` — a Zemax tabular BSDF: every grid node becomes a row with its viewing
  direction converted back from the specular-centred angles (:func:`bench.export.from_specular`).
* :func:`read_record` — any of these by file name.

A malformed file raises :class:`bench.core.errors.InputError` naming the file, the line and what
was expected there.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from bench.core.errors import InputError
from bench.export import CSV_MAGIC, PARQUET_META_KEY, from_specular
from bench.core.records import BSDF_COLUMNS, BSDFRecord

__all__ = ["read_tidy_csv", "read_parquet", "read_astm", "read_zemax", "read_record"]

_CHANNEL = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?(?:[eE][-+]?[0-9]+)?)\s*nm\s*$", re.IGNORECASE)


def _bad(path: Path, lineno: int | None, what: str) -> InputError:
    where = f"{path}:{lineno}" if lineno is not None else str(path)
    return InputError(f"{where}: {what}")


def _read_lines(path: str | Path) -> tuple[Path, list[str]]:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{p}: not a UTF-8 text file ({e})") from None
    return p, text.splitlines()


def _complete(df: Any) -> Any:
    """Columns of BSDF_COLUMNS first (missing ones NaN), any others after."""
    import pandas as pd

    out = pd.DataFrame(index=df.index)
    for c in BSDF_COLUMNS:
        out[c] = df[c] if c in df.columns else np.nan
    for c in df.columns:
        if c not in out.columns:
            out[c] = df[c]
    return out


# --- tidy CSV / Parquet --------------------------------------------------------------------


def read_tidy_csv(path: str | Path) -> BSDFRecord:
    """Read a tidy CSV written by :func:`bench.export.record_to_csv` (or any CSV with a
    ``wavelength_nm`` column). Metadata from the ``# meta:`` header line, else from a sidecar
    ``<file>.json``, else empty."""
    import pandas as pd

    p, lines = _read_lines(path)
    meta: dict[str, Any] = {}
    skip = 0
    while skip < len(lines) and lines[skip].startswith("#"):
        line = lines[skip]
        if line.startswith("# meta:"):
            try:
                meta = json.loads(line[len("# meta:"):])
            except json.JSONDecodeError as e:
                raise _bad(p, skip + 1, f"expected JSON after '# meta:' ({e})") from None
        skip += 1
    if skip == 0 or not lines or not lines[0].startswith(CSV_MAGIC):
        side = Path(str(p) + ".json")
        if side.exists():
            try:
                meta = json.loads(side.read_text(encoding="utf-8"))
            except json.JSONDecodeError as e:
                raise InputError(f"{side}: not valid JSON ({e})") from None
    if skip >= len(lines):
        raise _bad(p, skip + 1, "expected a header line of column names, found the end of the file")
    try:
        df = pd.read_csv(p, skiprows=skip, keep_default_na=True)
    except (pd.errors.ParserError, ValueError) as e:
        raise _bad(p, None, f"malformed CSV ({e})") from None
    if "wavelength_nm" not in df.columns:
        raise _bad(p, skip + 1, f"expected a column wavelength_nm in the header, got {', '.join(map(str, df.columns))}")
    for c in ("count", "N"):
        if c in df.columns and df[c].notna().all() and len(df):
            df[c] = df[c].astype("int64")
    return BSDFRecord(_complete(df) if set(BSDF_COLUMNS) - set(df.columns) else df, meta)


def read_parquet(path: str | Path) -> BSDFRecord:
    """Read a Parquet file written by :func:`bench.export.record_to_parquet`."""
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
    raw = (t.schema.metadata or {}).get(PARQUET_META_KEY)
    meta = json.loads(raw.decode()) if raw else {}
    return BSDFRecord(t.to_pandas(), meta)


# --- ASTM CSV ------------------------------------------------------------------------------


def read_astm(path: str | Path) -> BSDFRecord:
    """Read the "ASTM" CSV layout: keyword lines, ``VARS theta_i,phi_i,theta_s,phi_s,<channels>``,
    rows with angles in radians. Returns degrees inside; channels ``<w>nm`` become
    ``wavelength_nm``; other channel names (``R``, ``G``, ``B``, ...) go to a ``channel`` column
    with ``wavelength_nm`` NaN. Keywords go to ``meta`` (lower-case keys); ``GONIOBENCH_META``
    JSON is merged in. ``NUM_POINTS``, when given, must match the rows."""
    import pandas as pd

    p, lines = _read_lines(path)
    keywords: dict[str, str] = {}
    varnames: list[str] | None = None
    vars_line = 0
    rows: list[list[float]] = []
    row_lines: list[int] = []
    for n, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if varnames is None:
            key, _, rest = line.partition(" ")
            key = key.strip().rstrip(",")
            if key.upper() == "VARS":
                varnames = [v.strip() for v in rest.replace("\t", "").split(",") if v.strip()]
                vars_line = n
                if len(varnames) < 5 or [v.lower() for v in varnames[:4]] != ["theta_i", "phi_i", "theta_s", "phi_s"]:
                    raise _bad(p, n, f"expected 'VARS theta_i,phi_i,theta_s,phi_s,<channel>,...', got {line!r}")
                continue
            if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", key):
                raise _bad(p, n, f"expected a header keyword line (KEYWORD value) or VARS, got {line!r}")
            keywords[key.upper()] = rest.strip()
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != len(varnames):
            raise _bad(p, n, f"expected {len(varnames)} comma-separated numbers ({', '.join(varnames)}), "
                             f"got {len(fields)}")
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            bad = next(f for f in fields if not _is_float(f))
            raise _bad(p, n, f"expected a number, got {bad!r}") from None
        row_lines.append(n)
    if varnames is None:
        raise _bad(p, len(lines) + 1, "expected a 'VARS theta_i,phi_i,theta_s,phi_s,...' line, found none")
    if "NUM_POINTS" in keywords:
        try:
            n_points = int(keywords["NUM_POINTS"].split()[0])
        except (ValueError, IndexError):
            raise _bad(p, None, f"NUM_POINTS must be an integer, got {keywords['NUM_POINTS']!r}") from None
        if n_points != len(rows):
            where = row_lines[-1] + 1 if row_lines else vars_line + 1
            raise _bad(p, where, f"NUM_POINTS says {n_points} rows, the file has {len(rows)}")
    data = np.asarray(rows, dtype=float).reshape(-1, len(varnames))
    for c, name, hi in ((0, "theta_i", math.pi), (2, "theta_s", math.pi)):
        bad = np.flatnonzero((data[:, c] < -1e-12) | (data[:, c] > hi + 1e-9))
        if bad.size:
            raise _bad(p, row_lines[bad[0]], f"{name} = {data[bad[0], c]} is outside [0, pi] radians "
                                             f"(angles must be in radians)")
    channels = varnames[4:]
    angles = np.degrees(data[:, :4])
    frames = []
    for k, ch in enumerate(channels):
        m = _CHANNEL.match(ch)
        frame = pd.DataFrame({"wavelength_nm": float(m.group(1)) if m else np.nan,
                              "theta_i": angles[:, 0], "phi_i": angles[:, 1] % 360.0,
                              "theta_r": angles[:, 2], "phi_r": angles[:, 3] % 360.0,
                              "value": data[:, 4 + k]})
        if not m:
            frame["channel"] = ch
        frames.append(frame)
    df = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["wavelength_nm"])
    df["hemisphere"] = np.where(df["theta_r"] > 90.0, "T", "R")
    # geometry-major, channel-minor: the order the rows were written in
    n_rows = len(data)
    idx = np.arange(len(df)).reshape(len(channels), n_rows).T.ravel() if n_rows else np.arange(0)
    df = df.iloc[idx].reset_index(drop=True)
    meta: dict[str, Any] = {}
    extra = keywords.pop("GONIOBENCH_META", None)
    if extra:
        try:
            meta.update(json.loads(extra))
        except json.JSONDecodeError as e:
            raise _bad(p, None, f"GONIOBENCH_META is not valid JSON ({e})") from None
    for k, v in keywords.items():
        meta[f"astm_{k.lower()}"] = v.strip('"')
    meta["format"] = "astm"
    meta["source_file"] = str(p)
    return BSDFRecord(_complete(df), meta)


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


# --- Zemax ---------------------------------------------------------------------------------


_ZEMAX_LISTS = ("SampleRotation", "AngleOfIncidence", "ScatterAzimuth", "ScatterRadial")


def read_zemax(path: str | Path, *, keep_beyond_horizon: bool = False) -> BSDFRecord:
    """Read a Zemax OpticStudio tabular BSDF (``Monochrome`` content).

    Every grid node (rotation, incidence, azimuth, radial) becomes one row: ``phi_i`` = sample
    rotation, ``theta_i`` = angle of incidence, ``(theta_r, phi_r)`` from
    :func:`bench.export.from_specular` (BTDF: mirrored to the transmission side), ``value``;
    ``radial_deg`` and ``azimuth_deg`` keep the file's angles. Nodes beyond the hemisphere are
    dropped unless ``keep_beyond_horizon``. ``wavelength_nm`` comes from a ``# wavelength_nm``
    comment when present (else NaN). ``meta["tis"]`` lists the TIS per (rotation, incidence).
    """
    import pandas as pd

    p, lines = _read_lines(path)
    header: dict[str, str] = {}
    lists: dict[str, np.ndarray] = {}
    wavelength = math.nan
    comments: dict[str, str] = {}
    i = 0
    n_lines = len(lines)

    def next_content(i: int) -> int:
        while i < n_lines and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
            s = lines[i].strip()
            if s.startswith("#"):
                key, _, val = s[1:].strip().partition(" ")
                comments[key] = val.strip()
            i += 1
        return i

    # header
    while True:
        i = next_content(i)
        if i >= n_lines:
            raise _bad(p, i + 1, "expected 'DataBegin', found the end of the file")
        parts = lines[i].split()
        key = parts[0]
        if key == "DataBegin":
            break
        if key in _ZEMAX_LISTS:
            if len(parts) != 2 or not parts[1].isdigit():
                raise _bad(p, i + 1, f"expected '{key} <count>', got {lines[i].strip()!r}")
            count = int(parts[1])
            vals: list[float] = []
            j = i + 1
            while len(vals) < count:
                j = next_content(j)
                if j >= n_lines:
                    raise _bad(p, j + 1, f"expected {count} values after {key}, found {len(vals)}")
                try:
                    vals.extend(float(x) for x in lines[j].split())
                except ValueError:
                    raise _bad(p, j + 1, f"expected numbers for {key}, got {lines[j].strip()!r}") from None
                j += 1
            if len(vals) != count:
                raise _bad(p, j, f"expected {count} values for {key}, got {len(vals)}")
            lists[key] = np.asarray(vals)
            i = j
            continue
        if key in ("Monochrome", "XYZ"):
            header["Content"] = key
        elif key in ("Source", "Symmetry", "SpectralContent", "ScatterType"):
            if len(parts) < 2:
                raise _bad(p, i + 1, f"expected '{key} <value>', got {lines[i].strip()!r}")
            header[key] = parts[1]
        else:
            raise _bad(p, i + 1, f"expected a Zemax BSDF header keyword (Source, Symmetry, SpectralContent, "
                                 f"ScatterType, {', '.join(_ZEMAX_LISTS)}, Monochrome, DataBegin), got {key!r}")
        i += 1
    for key in _ZEMAX_LISTS:
        if key not in lists:
            raise _bad(p, i + 1, f"expected a '{key} <count>' section before DataBegin")
    if header.get("SpectralContent", "Monochrome") != "Monochrome":
        raise _bad(p, None, f"only SpectralContent Monochrome is supported, got {header['SpectralContent']!r}")
    st = header.get("ScatterType", "BRDF").upper()
    if st not in ("BRDF", "BTDF"):
        raise _bad(p, None, f"ScatterType must be BRDF or BTDF, got {header.get('ScatterType')!r}")
    if "wavelength_nm" in comments:
        try:
            wavelength = float(comments["wavelength_nm"])
        except ValueError:
            pass
    rots, incs, az, rad = (lists[k] for k in _ZEMAX_LISTS)
    values = np.zeros((len(rots), len(incs), len(az), len(rad)))
    tis = []
    i += 1
    for k in range(len(rots)):
        for j in range(len(incs)):
            i = next_content(i)
            if i >= n_lines:
                raise _bad(p, i + 1, f"expected 'TIS <value>' for rotation {rots[k]:g}, incidence {incs[j]:g}, "
                                     f"found the end of the file")
            parts = lines[i].split()
            if len(parts) != 2 or parts[0] != "TIS" or not _is_float(parts[1]):
                raise _bad(p, i + 1, f"expected 'TIS <value>' for rotation {rots[k]:g}, incidence {incs[j]:g}, "
                                     f"got {lines[i].strip()!r}")
            tis.append({"rotation": float(rots[k]), "theta_i": float(incs[j]), "tis": float(parts[1])})
            i += 1
            for a in range(len(az)):
                i = next_content(i)
                if i >= n_lines:
                    raise _bad(p, i + 1, f"expected {len(az)} rows of {len(rad)} values, found the end of the file")
                fields = lines[i].split()
                if len(fields) != len(rad) or not all(_is_float(f) for f in fields):
                    raise _bad(p, i + 1, f"expected {len(rad)} numbers (one per ScatterRadial) for azimuth "
                                         f"{az[a]:g}, got {lines[i].strip()[:60]!r}")
                values[k, j, a] = [float(f) for f in fields]
                i += 1
    i = next_content(i)
    if i >= n_lines or lines[i].strip() != "DataEnd":
        raise _bad(p, i + 1, "expected 'DataEnd' after the last block"
                   + ("" if i >= n_lines else f", got {lines[i].strip()[:60]!r}"))
    A, R = np.meshgrid(az, rad, indexing="ij")
    frames = []
    trans = st == "BTDF"
    for k, rot in enumerate(rots):
        for j, inc in enumerate(incs):
            th, ph = from_specular(float(inc), float(rot), R, A, transmission=trans)
            up = 180.0 - th if trans else th
            keep = np.ones(th.shape, bool) if keep_beyond_horizon else up <= 90.0 + 1e-9
            frames.append(pd.DataFrame({
                "wavelength_nm": wavelength, "theta_i": float(inc), "phi_i": float(rot) % 360.0,
                "theta_r": th[keep], "phi_r": ph[keep], "hemisphere": "T" if trans else "R",
                "value": values[k, j][keep], "radial_deg": R[keep], "azimuth_deg": A[keep]}))
    df = pd.concat(frames, ignore_index=True)
    meta = {"format": "zemax", "source_file": str(p), "scatter_type": st,
            "symmetry": header.get("Symmetry"), "source": header.get("Source"), "tis": tis,
            "wavelength_nm": None if math.isnan(wavelength) else wavelength}
    if comments.get("specimen"):
        meta["specimen"] = comments["specimen"]
    return BSDFRecord(_complete(df), meta)


# --- dispatch ------------------------------------------------------------------------------


def read_record(path: str | Path, fmt: str | None = None, **options: Any) -> BSDFRecord:
    """Read a record in ``fmt`` (``csv``, ``parquet``, ``astm``, ``zemax``; default from the file
    name as in :func:`bench.export.export_record`)."""
    from bench.export import FORMATS, _infer_format

    p = Path(path)
    fmt = _infer_format(p) if fmt is None else fmt
    readers = {"csv": read_tidy_csv, "parquet": read_parquet, "astm": read_astm, "zemax": read_zemax}
    if fmt not in readers:
        raise InputError(f"unknown import format {fmt!r}; known: {', '.join(FORMATS)}")
    return readers[fmt](p, **options)
