"""The "ASTM" CSV layout (angles in radians, one channel per wavelength): writer and reader.

Header keyword lines (``SOURCE``, ``SAMPLE_NAME``, ``MEAS_DATE``, ``SCATTER_TYPE``,
``ANGLE_UNITS radians``, ``VALUE_UNITS 1/sr``, the record's identity -- ``SPECIMEN`` (its model),
``RUN_ID``, ``BENCH``, ``BODY``, ``PLAN`` when known -- ``GONIOBENCH_META`` <JSON>,
``NUM_POINTS n``), then ``VARS theta_i,phi_i,theta_s,phi_s,<channels>`` with one channel per
wavelength (``550nm``), then one comma-separated row per geometry: angles in RADIANS (17
significant digits), BRDF/BTDF values (1/sr) with ``digits`` significant digits. ``theta_s >
pi/2`` is the transmission side.

Radians are the layout's own convention (what libbsdf and the lab tools that read it expect;
see the formats reference), the one edge of goniobench whose angles are not degrees: the file
says so in ``ANGLE_UNITS``. Only a BSDF is written (:func:`bench.io.files.require_bsdf`): a
spectrophotometer's reflectance has no viewing direction and no 1/sr.

The standard uncertainty of every value (the record's ``std``), which the layout has no column
for, travels in our own ``GONIOBENCH_META`` line as ``"value_std"`` (rows x channels, null for
none): other readers ignore the line; :func:`read_astm` restores the ``std`` column, so a
comparison of an imported file knows each value's uncertainty.
"""

from __future__ import annotations

import json
import math
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from bench.core.errors import InputError
from bench.core.records import BSDFRecord, record_identity, record_provenance
from bench.io.files import check_record, meta_json, require_bsdf, write_text
from bench.io.reading import bad, complete, is_float, read_lines

__all__ = ["record_to_astm", "read_astm"]

_CHANNEL = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?(?:[eE][-+]?[0-9]+)?)\s*nm\s*$", re.IGNORECASE)


def _channel(w: float) -> str:
    return f"{w:g}nm"


def _quote(text: str) -> str:
    return '"' + str(text).replace('"', "'").replace("\n", " ") + '"'


def record_to_astm(record: BSDFRecord, path: str | Path, *, sample_name: str | None = None,
                   meas_date: str | None = None, digits: int = 9, scatter_type: str | None = None,
                   hemisphere: str | None = None) -> Path:
    """Write the "ASTM" CSV layout (angles in radians, one channel per wavelength).

    Rows are the distinct geometries ``(theta_i, phi_i, theta_r, phi_r)`` sorted; a geometry
    missing a wavelength gets ``nan``. Two rows with the same geometry and wavelength are
    refused (:class:`InputError`): the layout holds one value per cell.

    Parameters
    ----------
    sample_name : default ``meta["specimen"]`` or ``meta["sample_name"]``
    meas_date : default ``meta["created_utc"]`` date or today (UTC)
    digits : significant digits of the values (angles always get 17)
    scatter_type : default ``BRDF`` (``BTDF`` when every row is on the transmission side)
    hemisphere : ``"R"`` or ``"T"`` to write one side only (libbsdf's reader, for one, clamps
        theta_s to pi/2 and expects one side per file); default both
    """
    require_bsdf(record, "the ASTM layout")
    table = check_record(record)
    if hemisphere is not None:
        if hemisphere not in ("R", "T"):
            raise InputError(f"hemisphere must be 'R', 'T' or None, got {hemisphere!r}")
        side = table["hemisphere"] if "hemisphere" in table.columns else np.where(table.theta_r > 90, "T", "R")
        table = table[np.asarray(side == hemisphere)]
        if table.empty:
            raise InputError(f"record has no rows on the {hemisphere} side")
    if not isinstance(digits, int) or not 1 <= digits <= 17:
        raise InputError(f"digits must be an integer in 1..17, got {digits!r}")
    geo = ["theta_i", "phi_i", "theta_r", "phi_r"]
    dup = table.duplicated(geo + ["wavelength_nm"])
    if dup.any():
        r = table[dup].iloc[0]
        raise InputError(f"record has two values for geometry ({r.theta_i:g}, {r.phi_i:g}, {r.theta_r:g}, "
                         f"{r.phi_r:g}) at {r.wavelength_nm:g} nm; the ASTM layout holds one")
    # only the geometries the record holds (a pivot table would fill every combination of angles
    # with all-NaN rows); a geometry missing a wavelength keeps NaN in that channel
    wide = table.set_index(geo + ["wavelength_nm"])["value"].unstack("wavelength_nm").sort_index()
    wls = [float(w) for w in wide.columns]
    meta = dict(record.meta)
    if "std" in table.columns and table["std"].notna().any():
        sw = table.set_index(geo + ["wavelength_nm"])["std"].unstack("wavelength_nm").reindex(
            index=wide.index, columns=wide.columns)
        meta["value_std"] = [[None if not np.isfinite(x) else float(x) for x in row] for row in sw.to_numpy(float)]
    ident = {**record_provenance(meta), "specimen": record_identity(meta)["specimen"]}
    name = sample_name or ident.get("sample_name") or ident.get("specimen") or "unnamed"
    if meas_date is None:
        c = meta.get("created_utc")
        meas_date = str(c)[:10] if c else datetime.now(timezone.utc).strftime("%Y-%m-%d")
    if scatter_type is None:
        scatter_type = "BTDF" if len(table) and bool((table.theta_r > 90.0).all()) else "BRDF"
    lines = ["SOURCE goniobench", f"SAMPLE_NAME {_quote(name)}", f"MEAS_DATE {meas_date}",
             f"SCATTER_TYPE {scatter_type}", "ANGLE_UNITS radians", "VALUE_UNITS 1/sr",
             *(f"{key.upper()} {_quote(value)}" for key in ("specimen", "run_id", "bench", "body", "plan")
               if (value := ident.get(key))),
             f"GONIOBENCH_META {meta_json(meta)}", f"NUM_POINTS {len(wide)}",
             "VARS theta_i,phi_i,theta_s,phi_s," + ",".join(_channel(w) for w in wls)]
    ang = np.radians(np.asarray(wide.index.to_list(), dtype=float).reshape(-1, 4))
    vals = wide.to_numpy(dtype=float)
    fmt = f"%.{digits}g"
    for a, v in zip(ang, vals):
        lines.append(",".join([*(repr(float(x)) for x in a), *(fmt % x for x in v)]))
    return write_text(path, "\n".join(lines) + "\n")



def read_astm(path: str | Path) -> BSDFRecord:
    """Read the "ASTM" CSV layout: keyword lines, ``VARS theta_i,phi_i,theta_s,phi_s,<channels>``,
    rows with angles in radians. Returns degrees inside; channels ``<w>nm`` become
    ``wavelength_nm``; other channel names (``R``, ``G``, ``B``, ...) go to a ``channel`` column
    with ``wavelength_nm`` NaN. Keywords go to ``meta`` (lower-case keys); ``GONIOBENCH_META``
    JSON is merged in. ``NUM_POINTS``, when given, must match the rows."""
    import pandas as pd

    p, lines = read_lines(path)
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
                    raise bad(p, n, f"expected 'VARS theta_i,phi_i,theta_s,phi_s,<channel>,...', got {line!r}")
                continue
            if not re.match(r"^[A-Za-z_][A-Za-z0-9_]*$", key):
                raise bad(p, n, f"expected a header keyword line (KEYWORD value) or VARS, got {line!r}")
            keywords[key.upper()] = rest.strip()
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != len(varnames):
            raise bad(p, n, f"expected {len(varnames)} comma-separated numbers ({', '.join(varnames)}), "
                             f"got {len(fields)}")
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            word = next(f for f in fields if not is_float(f))
            raise bad(p, n, f"expected a number, got {word!r}") from None
        row_lines.append(n)
    if varnames is None:
        raise bad(p, len(lines) + 1, "expected a 'VARS theta_i,phi_i,theta_s,phi_s,...' line, found none")
    if "NUM_POINTS" in keywords:
        try:
            n_points = int(keywords["NUM_POINTS"].split()[0])
        except (ValueError, IndexError):
            raise bad(p, None, f"NUM_POINTS must be an integer, got {keywords['NUM_POINTS']!r}") from None
        if n_points != len(rows):
            where = row_lines[-1] + 1 if row_lines else vars_line + 1
            raise bad(p, where, f"NUM_POINTS says {n_points} rows, the file has {len(rows)}")
    data = np.asarray(rows, dtype=float).reshape(-1, len(varnames))
    for c, name, hi in ((0, "theta_i", math.pi), (2, "theta_s", math.pi)):
        outside = np.flatnonzero((data[:, c] < -1e-12) | (data[:, c] > hi + 1e-9))
        if outside.size:
            raise bad(p, row_lines[outside[0]], f"{name} = {data[outside[0], c]} is outside [0, pi] radians "
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
        except ValueError as e:  # JSONDecodeError, or a number longer than int() takes (a plain ValueError)
            raise bad(p, None, f"GONIOBENCH_META is not valid JSON ({e})") from None
    std = meta.pop("value_std", None)
    if std is not None:
        sd = np.asarray([[np.nan if x is None else float(x) for x in row] for row in std], dtype=float)
        if sd.shape != (n_rows, len(channels)):
            raise bad(p, None, f"GONIOBENCH_META value_std has shape {sd.shape}, the table {(n_rows, len(channels))}")
        df["std"] = sd.ravel()  # geometry-major, channel-minor like the rows above
    for key, value in keywords.items():
        meta[f"astm_{key.lower()}"] = value.strip('"')
    meta["format"] = "astm"
    meta["source_file"] = str(p)
    return BSDFRecord(complete(df), meta)
