"""Exports of records to files people and tools read.

Every writer goes through :func:`atomic_write`: the file is written to a temporary file in the
same folder, flushed and fsynced, then moved over the target with :func:`os.replace`, so a
reader (or a crash) never sees a half-written export.

Formats
-------
tidy CSV (:func:`record_to_csv`)
    One row per record row, every column of the table. Floats are written with Python's
    shortest round-trip repr, so values read back exactly. Metadata: by default a commented
    header — first line ``# goniobench-record 1``, then one line ``# meta: <JSON>`` — which
    ``pandas.read_csv(path, comment="#")`` skips; or (``meta="sidecar"``) a JSON file next to
    the CSV named ``<file>.json``; or none.
Parquet (:func:`record_to_parquet`)
    The table via pyarrow; the metadata as JSON under the key ``goniobench.meta`` of the
    schema's key-value metadata (next to pandas' own ``pandas`` key).
"ASTM" CSV (:func:`record_to_astm`)
    Header keyword lines (``SOURCE``, ``SAMPLE_NAME``, ``MEAS_DATE``, ``SCATTER_TYPE``,
    ``GONIOBENCH_META`` <JSON>, ``NUM_POINTS n``), then ``VARS theta_i,phi_i,theta_s,phi_s,
    <channels>`` with one channel per wavelength (``550nm``), then one comma-separated row per
    geometry: angles in RADIANS (17 significant digits), BRDF/BTDF values (1/sr) with ``digits``
    significant digits. ``theta_s > pi/2`` is the transmission side.
Zemax OpticStudio tabular BSDF (:func:`record_to_zemax`)
    ``Source Measured``, ``Symmetry``, ``SpectralContent Monochrome``, ``ScatterType BRDF|BTDF``,
    ``SampleRotation`` (= the incidence azimuths phi_i of the record, degrees),
    ``AngleOfIncidence`` (theta_i), ``ScatterAzimuth``, ``ScatterRadial``, a blank line,
    ``Monochrome``, ``DataBegin``, per (rotation, incidence) ``TIS value`` and an
    azimuth-rows x radial-columns block, ``DataEnd``. One wavelength per file (``# wavelength_nm``
    comment records which). See :func:`zemax_grid` for the specular-centred angles and the
    resampling.

Specular-centred angles (Zemax)
-------------------------------
For incidence (theta_i, phi_i) the specular direction is s = (theta_i, phi_i + 180). The frame
about it is the one libbsdf's ``SpecularCoordinateSystem`` uses to read Zemax files: take
spherical angles (radial, azimuth) about +z, rotate by theta_i about +y (x toward z), then by
phi_i about +z. So ``e_1`` (azimuth 0) lies in the plane of incidence and points from the
specular direction *toward the specimen normal and the source*; ``e_2`` (azimuth 90) is
horizontal, perpendicular to the plane of incidence (+y when phi_i = 0); ``(e_1, e_2, s)`` is
right-handed. A viewing direction v has ``radial`` = angle(v, s) and
``azimuth`` = atan2(v . e_2, v . e_1) in [0, 360); azimuth 180 is in the plane of incidence
beyond the specular direction (toward forward grazing). At theta_i = 0 the frame still follows
phi_i. ``PlaneSymmetrical`` files hold azimuths 0..180 (the half with v . e_2 >= 0; readers
mirror it). For a BTDF the transmitted side is mirrored through the specimen plane (z -> -z)
first, so the "specular" direction is the undeviated straight-through direction -incident (no
refraction is assumed). ``SampleRotation`` is read as phi_i (as libbsdf does).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from bench.core.errors import InputError
from bench.core.roles import Spectrum
from bench.core.records import BSDFRecord, json_default

__all__ = [
    "spectrum_table", "spectrum_to_csv", "atomic_write", "json_default",
    "record_to_csv", "record_to_parquet", "record_to_astm", "record_to_zemax", "ZemaxGrid", "zemax_grid",
    "specular_frame", "to_specular", "from_specular", "export_record", "export_run", "FORMATS",
    "PARQUET_META_KEY", "CSV_MAGIC",
]

PARQUET_META_KEY = b"goniobench.meta"
CSV_MAGIC = "# goniobench-record 1"
FORMATS = ("csv", "parquet", "astm", "zemax")


# --- spectra (unchanged API) -------------------------------------------------------------


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
        "geometry": s.geometry,
        "seed": s.seed,
        "confidence": 1.0 - s.delta,
    })


def spectrum_to_csv(s: Spectrum, path: str | Path) -> Path:
    """Write :func:`spectrum_table` as CSV (parent folders created, atomic); return the path."""
    table = spectrum_table(s)
    return atomic_write(path, lambda tmp: table.to_csv(tmp, index=False, float_format="%.8g"))


# --- plumbing ------------------------------------------------------------------------------


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, fsync it, then
    ``os.replace`` it onto ``path`` (parent folders created). On any error the temporary file is
    removed and ``path`` is left as it was. Returns ``path``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
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


def _write_text(path: str | Path, text: str) -> Path:
    def w(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
    return atomic_write(path, w)


def _meta_json(meta: dict[str, Any]) -> str:
    return json.dumps(meta, default=json_default)


def _check_record(record: Any, need: Sequence[str] = ("wavelength_nm", "theta_i", "phi_i", "theta_r",
                                                       "phi_r", "value")) -> Any:
    import pandas as pd

    if not isinstance(record, BSDFRecord) or not isinstance(record.table, pd.DataFrame):
        raise InputError(f"expected a BSDFRecord with a pandas table, got {type(record).__name__}")
    missing = [c for c in need if c not in record.table.columns]
    if missing:
        raise InputError(f"record has no column(s) {', '.join(missing)}")
    return record.table


# --- tidy CSV and Parquet ------------------------------------------------------------------


def record_to_csv(record: BSDFRecord, path: str | Path, *, meta: str = "header") -> Path:
    """Write a record as tidy CSV (every column; floats as shortest round-trip repr).

    Parameters
    ----------
    meta : {"header", "sidecar", "none"}
        ``header``: ``# goniobench-record 1`` and ``# meta: <JSON>`` lines before the column
        names; ``sidecar``: ``<path>.json`` beside the file (written atomically too).
    """
    table = _check_record(record, ("wavelength_nm",))
    if meta not in ("header", "sidecar", "none"):
        raise InputError(f"meta must be 'header', 'sidecar' or 'none', got {meta!r}")
    body = table.to_csv(index=False, lineterminator="\n")
    if meta == "header":
        body = f"{CSV_MAGIC}\n# meta: {_meta_json(record.meta)}\n" + body
    out = _write_text(path, body)
    if meta == "sidecar":
        _write_text(Path(str(out) + ".json"), json.dumps(record.meta, default=json_default, indent=1) + "\n")
    return out


def record_to_parquet(record: BSDFRecord, path: str | Path) -> Path:
    """Write a record as Parquet; ``meta`` as JSON under :data:`PARQUET_META_KEY` in the
    schema's key-value metadata. Needs pyarrow (``pip install goniobench[parquet]``)."""
    table = _check_record(record, ("wavelength_nm",))
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as e:  # pragma: no cover - pyarrow is installed here
        raise InputError("Parquet export needs pyarrow: pip install 'goniobench[parquet]'") from e
    t = pa.Table.from_pandas(table, preserve_index=False)
    md = dict(t.schema.metadata or {})
    md[PARQUET_META_KEY] = _meta_json(record.meta).encode()
    t = t.replace_schema_metadata(md)
    return atomic_write(path, lambda tmp: pq.write_table(t, tmp))


# --- ASTM CSV ------------------------------------------------------------------------------


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
    table = _check_record(record)
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
    wide = table.pivot_table(index=geo, columns="wavelength_nm", values="value", aggfunc="first",
                             dropna=False).sort_index()
    wls = [float(w) for w in wide.columns]
    meta = record.meta
    name = sample_name or meta.get("sample_name") or meta.get("specimen") or "unnamed"
    if meas_date is None:
        c = meta.get("created_utc")
        meas_date = str(c)[:10] if c else datetime.now(timezone.utc).strftime("%Y-%m-%d")
    if scatter_type is None:
        scatter_type = "BTDF" if len(table) and bool((table.theta_r > 90.0).all()) else "BRDF"
    lines = ["SOURCE goniobench", f"SAMPLE_NAME {_quote(name)}", f"MEAS_DATE {meas_date}",
             f"SCATTER_TYPE {scatter_type}", "ANGLE_UNITS radians", "VALUE_UNITS 1/sr",
             f"GONIOBENCH_META {_meta_json(meta)}", f"NUM_POINTS {len(wide)}",
             "VARS theta_i,phi_i,theta_s,phi_s," + ",".join(_channel(w) for w in wls)]
    ang = np.radians(np.asarray(wide.index.to_list(), dtype=float).reshape(-1, 4))
    vals = wide.to_numpy(dtype=float)
    fmt = f"%.{digits}g"
    for a, v in zip(ang, vals):
        lines.append(",".join([*(repr(float(x)) for x in a), *(fmt % x for x in v)]))
    return _write_text(path, "\n".join(lines) + "\n")


# --- Zemax tabular BSDF --------------------------------------------------------------------


def specular_frame(theta_i: float, phi_i: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(s, e_1, e_2)``: the specular direction of incidence (theta_i, phi_i) (degrees) and the
    unit vectors of azimuth 0 and 90 about it (see the module docstring)."""
    t, p = math.radians(theta_i), math.radians(phi_i)
    st, ct, sp, cp = math.sin(t), math.cos(t), math.sin(p), math.cos(p)
    s = np.array([-st * cp, -st * sp, ct])
    e_1 = np.array([ct * cp, ct * sp, st])
    e_2 = np.array([-sp, cp, 0.0])
    return s, e_1, e_2


def _dirs(theta: Any, phi: Any) -> np.ndarray:
    t, p = np.radians(np.asarray(theta, float)), np.radians(np.asarray(phi, float))
    st = np.sin(t)
    return np.stack([st * np.cos(p), st * np.sin(p), np.cos(t)], axis=-1)


def _angles(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rho = np.hypot(v[..., 0], v[..., 1])
    theta = np.degrees(np.arctan2(rho, v[..., 2]))
    phi = np.where(rho > 0, np.degrees(np.arctan2(v[..., 1], v[..., 0])) % 360.0, 0.0)
    phi = np.where(phi >= 360.0, 0.0, phi)
    return theta, phi


def to_specular(theta_i: float, phi_i: float, theta_r: Any, phi_r: Any,
                transmission: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(radial, azimuth) in degrees about the specular direction of viewing directions
    ``(theta_r, phi_r)`` (degrees, arrays). ``transmission`` mirrors them through the specimen
    plane first (BTDF)."""
    v = _dirs(theta_r, phi_r)
    if transmission:
        v = v * np.array([1.0, 1.0, -1.0])
    s, e_1, e_2 = specular_frame(theta_i, phi_i)
    c = v @ s
    sin_r = np.linalg.norm(np.cross(v, s), axis=-1)
    radial = np.degrees(np.arctan2(sin_r, c))
    az = np.degrees(np.arctan2(v @ e_2, v @ e_1)) % 360.0
    az = np.where((sin_r == 0) | (az >= 360.0), 0.0, az)
    return radial, az


def from_specular(theta_i: float, phi_i: float, radial: Any, azimuth: Any,
                  transmission: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Viewing directions ``(theta_r, phi_r)`` (degrees) of specular-centred angles
    (inverse of :func:`to_specular`)."""
    r, a = np.radians(np.asarray(radial, float)), np.radians(np.asarray(azimuth, float))
    s, e_1, e_2 = specular_frame(theta_i, phi_i)
    v = (np.cos(r)[..., None] * s + np.sin(r)[..., None] * (np.cos(a)[..., None] * e_1
                                                             + np.sin(a)[..., None] * e_2))
    if transmission:
        v = v * np.array([1.0, 1.0, -1.0])
    return _angles(v)


@dataclass
class ZemaxGrid:
    """A record resampled for a Zemax tabular BSDF.

    ``values[k, j, a, r]`` is the BSDF (1/sr) at sample rotation ``rotations[k]`` (= phi_i),
    incidence ``incidences[j]`` (theta_i), azimuth ``azimuths[a]`` and radial angle
    ``radials[r]`` about the specular direction; directions beyond the hemisphere hold 0.
    ``tis[k, j]`` is the total integrated scatter of that hemisphere.
    """

    rotations: np.ndarray
    incidences: np.ndarray
    azimuths: np.ndarray
    radials: np.ndarray
    values: np.ndarray
    tis: np.ndarray
    wavelength_nm: float | None
    scatter_type: str = "BRDF"
    symmetry: str = "Asymmetrical"
    meta: dict[str, Any] = field(default_factory=dict)


def _lookup(part: Any, theta: np.ndarray, phi: np.ndarray,
            max_distance_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``part`` (rows of one hemisphere, incidence and wavelength) at directions
    (theta, phi) (degrees): the collector patch containing the direction when the rows carry
    patch bounds, else the angularly nearest sample (NaN when farther than
    ``max_distance_deg``). Also returns the angular distance (degrees) to the sample used (0
    inside a patch)."""
    vals = part["value"].to_numpy(float)
    bounds = ["theta_min", "theta_max", "phi_min", "phi_max"]
    out = np.full(theta.shape, np.nan)
    dist = np.zeros(theta.shape)
    todo = np.ones(theta.shape, bool)
    if all(c in part.columns for c in bounds) and part[bounds].notna().all().all():
        tmin, tmax, pmin, pmax = (part[c].to_numpy(float) for c in bounds)
        tlo, thi = np.minimum(tmin, tmax), np.maximum(tmin, tmax)
        th, ph = theta.ravel()[:, None], phi.ravel()[:, None]
        closed = np.isin(thi, (90.0, 180.0))  # the ring at the horizon / pole includes its edge
        in_t = (th >= tlo) & ((th < thi) | ((th <= thi) & closed))
        in_p = (ph >= pmin) & (ph < pmax)
        hit = in_t & in_p
        any_hit = hit.any(axis=1)
        first = np.argmax(hit, axis=1)
        flat = out.ravel()
        flat[any_hit] = vals[first[any_hit]]
        out = flat.reshape(theta.shape)
        todo = ~any_hit.reshape(theta.shape)
    if todo.any():
        d = _dirs(part["theta_r"].to_numpy(float), part["phi_r"].to_numpy(float))
        q = _dirs(theta[todo], phi[todo])
        cos = q @ d.T
        best = np.argmax(cos, axis=1)
        gap = np.degrees(np.arccos(np.clip(cos[np.arange(len(best)), best], -1.0, 1.0)))
        got = vals[best]
        if max_distance_deg is not None:
            got = np.where(gap <= max_distance_deg, got, np.nan)
        out[todo] = got
        dist[todo] = gap
    return out, dist


def zemax_grid(record: BSDFRecord, *, wavelength_nm: float | None = None, scatter_type: str = "BRDF",
               symmetry: str = "Asymmetrical", azimuths: Iterable[float] | None = None,
               radials: Iterable[float] | None = None, max_distance_deg: float | None = None) -> ZemaxGrid:
    """Resample a record onto the regular specular-centred (azimuth, radial) grid of a Zemax file.

    Each grid node (rotation = phi_i, incidence = theta_i, azimuth, radial) is turned into a
    viewing direction with :func:`from_specular`; its value is that of the **collector patch
    containing the direction** (piecewise-constant, exactly what a virtual collector measured)
    when the record has patch bounds, else of the **angularly nearest measured direction**. Nodes
    beyond the hemisphere (below the specimen plane for a BRDF) get 0. Every (rotation,
    incidence) pair must be in the record.

    Nearest-sample filling fills every node however far the nearest measurement is (an in-plane
    scan would be spread over the whole hemisphere): pass ``max_distance_deg`` to write 0 at
    nodes farther than that from any sample, or choose ``azimuths=(0, 180)`` with
    ``PlaneSymmetrical`` for in-plane data. ``grid.meta["zemax_resampling"]`` reports the
    method, the largest nearest-sample distance used and the nodes left at 0.

    TIS per (rotation, incidence): ``sum(value * psa)`` over the hemisphere's rows when the record
    has ``psa`` (exact for a collector), else a quadrature of the grid
    (``sum f cos(theta) sin(radial) d radial d azimuth``, trapezoid weights).

    Parameters
    ----------
    wavelength_nm : the wavelength to export (may be omitted when the record has one)
    scatter_type : ``"BRDF"`` (reflection rows, ``hemisphere == "R"``) or ``"BTDF"`` ("T")
    symmetry : ``"Asymmetrical"`` (default azimuths 0..360 step 10) or ``"PlaneSymmetrical"``
        (0..180 step 10)
    radials : default 0..90 step 2 degrees
    max_distance_deg : float, optional
        Farthest a node may be from the sample it takes (point samples only; default: no limit).
    """
    import pandas as pd

    table = _check_record(record)
    st = str(scatter_type).upper()
    if st not in ("BRDF", "BTDF"):
        raise InputError(f"scatter_type must be 'BRDF' or 'BTDF', got {scatter_type!r}")
    if symmetry not in ("Asymmetrical", "PlaneSymmetrical"):
        raise InputError(f"symmetry must be 'Asymmetrical' or 'PlaneSymmetrical', got {symmetry!r}")
    wls = np.unique(table["wavelength_nm"].to_numpy(float))
    if wavelength_nm is None:
        if len(wls) != 1:
            raise InputError(f"a Zemax tabular BSDF holds one wavelength; pass wavelength_nm= "
                             f"(record has {', '.join(f'{w:g}' for w in wls)} nm)")
        wavelength_nm = float(wls[0])
    sel = table[np.isclose(table["wavelength_nm"].to_numpy(float), float(wavelength_nm), rtol=0, atol=1e-9)]
    if sel.empty:
        raise InputError(f"record has no rows at {wavelength_nm:g} nm (it has "
                         f"{', '.join(f'{w:g}' for w in wls)} nm)")
    hemi = "T" if st == "BTDF" else "R"
    if "hemisphere" in sel.columns and sel["hemisphere"].notna().any():
        sel = sel[sel["hemisphere"] == hemi]
    else:
        sel = sel[(sel["theta_r"] > 90.0) == (hemi == "T")]
    if sel.empty:
        raise InputError(f"record has no {st} rows ({hemi} hemisphere) at {wavelength_nm:g} nm")
    az = np.asarray(list(azimuths) if azimuths is not None else
                    np.arange(0.0, 361.0 if symmetry == "Asymmetrical" else 181.0, 10.0), float)
    rad = np.asarray(list(radials) if radials is not None else np.arange(0.0, 91.0, 2.0), float)
    for name, arr, hi in (("azimuths", az, 360.0), ("radials", rad, 180.0)):
        if arr.ndim != 1 or arr.size < 1 or np.any(np.diff(arr) <= 0) or arr[0] < 0 or arr[-1] > hi:
            raise InputError(f"{name} must be strictly increasing within [0, {hi:g}] degrees")
    rots = np.unique(sel["phi_i"].to_numpy(float))
    incs = np.unique(sel["theta_i"].to_numpy(float))
    values = np.zeros((len(rots), len(incs), len(az), len(rad)))
    tis = np.zeros((len(rots), len(incs)))
    A, R = np.meshgrid(az, rad, indexing="ij")
    groups = {k: g for k, g in sel.groupby(["phi_i", "theta_i"], sort=False)}
    bounds = ["theta_min", "theta_max", "phi_min", "phi_max"]
    patches = all(c in sel.columns for c in bounds) and bool(sel[bounds].notna().all().all())
    unfilled, farthest = 0, 0.0
    for k, rot in enumerate(rots):
        for j, inc in enumerate(incs):
            part = groups.get((rot, inc))
            if part is None:
                raise InputError(f"record has no {st} rows for incidence theta_i={inc:g}, phi_i={rot:g} at "
                                 f"{wavelength_nm:g} nm; a Zemax file needs every (rotation, incidence) pair")
            th, ph = from_specular(float(inc), float(rot), R, A, transmission=(hemi == "T"))
            up = th if hemi == "R" else 180.0 - th
            inside = up <= 90.0 + 1e-9
            v = np.zeros(th.shape)
            if inside.any():
                got, dist = _lookup(part, th[inside], ph[inside], max_distance_deg)
                unfilled += int(np.isnan(got).sum())
                farthest = max(farthest, float(dist.max()))
                v[inside] = np.nan_to_num(got, nan=0.0)
            values[k, j] = v
            if "psa" in part.columns and part["psa"].notna().all():
                tis[k, j] = float(np.nansum(part["value"].to_numpy(float) * part["psa"].to_numpy(float)))
            else:
                cos_t = np.abs(np.cos(np.radians(th)))
                wa = np.gradient(np.radians(az)) if len(az) > 1 else np.array([2 * math.pi])
                wr = np.gradient(np.radians(rad)) if len(rad) > 1 else np.array([0.0])
                tis[k, j] = float(np.sum(v * cos_t * np.sin(np.radians(R)) * wa[:, None] * wr[None, :]))
    meta = dict(record.meta)
    meta["zemax_resampling"] = {"method": "containing patch" if patches else "nearest sample",
                                "max_nearest_distance_deg": farthest, "nodes_unfilled": unfilled,
                                "max_distance_deg": max_distance_deg}
    return ZemaxGrid(rots, incs, az, rad, values, tis, float(wavelength_nm), st, symmetry, meta)


def _fmt_list(values: np.ndarray) -> str:
    return "\t".join(f"{float(x):.10g}" for x in values)


def record_to_zemax(record: BSDFRecord | ZemaxGrid, path: str | Path, *, digits: int = 6, **grid: Any) -> Path:
    """Write a Zemax OpticStudio tabular BSDF (``.bsdf``); ``grid`` keywords go to
    :func:`zemax_grid` (or pass a :class:`ZemaxGrid`). Values with ``digits`` significant
    digits (``%.{digits-1}e``)."""
    g = record if isinstance(record, ZemaxGrid) else zemax_grid(record, **grid)
    if not isinstance(digits, int) or not 1 <= digits <= 17:
        raise InputError(f"digits must be an integer in 1..17, got {digits!r}")
    fmt = f"%.{digits - 1}e"
    meta = g.meta
    lines = ["# goniobench Zemax OpticStudio tabular BSDF export",
             f"# wavelength_nm {g.wavelength_nm:.10g}",
             f"# specimen {meta.get('specimen', meta.get('sample_name', ''))}",
             "# SampleRotation = incidence azimuth phi_i (deg); AngleOfIncidence = theta_i (deg)",
             "# ScatterRadial/ScatterAzimuth about the specular direction; azimuth 0 = plane of incidence,"
             " toward the normal; 90 = +y at phi_i = 0 (libbsdf's specular frame)",
             "Source  Measured", f"Symmetry  {g.symmetry}", "SpectralContent  Monochrome",
             f"ScatterType  {g.scatter_type}",
             f"SampleRotation  {len(g.rotations)}", _fmt_list(g.rotations),
             f"AngleOfIncidence  {len(g.incidences)}", _fmt_list(g.incidences),
             f"ScatterAzimuth  {len(g.azimuths)}", _fmt_list(g.azimuths),
             f"ScatterRadial  {len(g.radials)}", _fmt_list(g.radials),
             "", "Monochrome", "DataBegin"]
    for k in range(len(g.rotations)):
        for j in range(len(g.incidences)):
            lines.append(f"TIS  {g.tis[k, j]:.{digits - 1}e}")
            for a in range(len(g.azimuths)):
                lines.append("\t".join(fmt % x for x in g.values[k, j, a]))
    lines.append("DataEnd")
    return _write_text(path, "\n".join(lines) + "\n")


# --- dispatch ------------------------------------------------------------------------------


def _infer_format(path: Path) -> str:
    name = path.name.lower()
    if name.endswith((".parquet", ".pq")):
        return "parquet"
    if name.endswith(".bsdf"):
        return "zemax"
    if name.endswith((".astm", ".astm.csv")):
        return "astm"
    if name.endswith(".csv"):
        return "csv"
    raise InputError(f"cannot tell the export format from {path.name!r}; pass fmt= one of {', '.join(FORMATS)} "
                     f"(.csv, .parquet, .astm/.astm.csv, .bsdf)")


def export_record(record: BSDFRecord, path: str | Path, fmt: str | None = None, **options: Any) -> Path:
    """Write a record in ``fmt`` (``csv``, ``parquet``, ``astm``, ``zemax``; default from the
    file name) with the format's ``options``; return the path."""
    p = Path(path)
    fmt = _infer_format(p) if fmt is None else fmt
    writers = {"csv": record_to_csv, "parquet": record_to_parquet, "astm": record_to_astm,
               "zemax": record_to_zemax}
    if fmt not in writers:
        raise InputError(f"unknown export format {fmt!r}; known: {', '.join(FORMATS)}")
    return writers[fmt](record, p, **options)


def export_run(store: Any, run_id: str, path: str | Path, fmt: str | None = None, **options: Any) -> Path:
    """Export a stored run (``store`` is a :class:`bench.store.RunStore` or a path to one)."""
    from bench.store import RunStore

    if isinstance(store, RunStore):
        return export_record(store.to_record(run_id), path, fmt, **options)
    with RunStore(store, create=False) as s:
        return export_record(s.to_record(run_id), path, fmt, **options)
