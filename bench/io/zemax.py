"""Zemax OpticStudio tabular BSDF (``.bsdf``): resampling onto the specular-centred grid,
writer and reader.

``Source Measured``, ``Symmetry``, ``SpectralContent Monochrome``, ``ScatterType BRDF|BTDF``,
``SampleRotation`` (= the incidence azimuths phi_i of the record, degrees),
``AngleOfIncidence`` (theta_i), ``ScatterAzimuth``, ``ScatterRadial``, a blank line,
``Monochrome``, ``DataBegin``, per (rotation, incidence) ``TIS value`` and an
azimuth-rows x radial-columns block, ``DataEnd``. One wavelength per file (``# wavelength_nm``
comment records which). See :func:`zemax_grid` for the specular-centred angles
(:mod:`bench.io.specular`) and the resampling.

The standard uncertainty of every node (the ``std`` of the sample it takes) and which sample
that is, which the format has no field for, are written as header comments ``# std K J A v v v
...`` and ``# sample K J A i i i ...`` (rotation, incidence, azimuth indices, one entry per
radial; the sample is the row of the record's (rotation, incidence) part, -1 for none); Zemax
and other readers skip comments, :func:`read_zemax` restores the ``std`` and ``sample``
columns -- many nodes take the same sample, and a comparison counts it once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from bench.core.errors import InputError
from bench.core.records import BSDFRecord, record_identity, record_provenance
from bench.io.files import check_record, check_target, require_bsdf, write_text
from bench.io.reading import bad, complete, is_float, read_lines
from bench.io.specular import directions, from_specular

__all__ = ["ZemaxGrid", "zemax_grid", "record_to_zemax", "record_to_zemax_files", "wavelengths_of", "read_zemax"]


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
    std: np.ndarray | None = None
    sample: np.ndarray | None = None


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
        d = directions(part["theta_r"].to_numpy(float), part["phi_r"].to_numpy(float))
        q = directions(theta[todo], phi[todo])
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
               radials: Iterable[float] | None = None, max_distance_deg: float | None = None,
               fill: str | None = None) -> ZemaxGrid:
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
    fill : {None, "nearest"}
        An in-plane record (point samples in the plane of incidence only) on a grid with nodes off
        that plane is refused -- filling them would invent out-of-plane data -- unless
        ``max_distance_deg`` leaves them at 0 or ``fill="nearest"`` asks for nearest-sample
        filling (recorded in ``zemax_resampling`` and the file's header).

    Raises
    ------
    InputError
        For the in-plane case above, with the reason and the way out.
    """

    require_bsdf(record, "a Zemax tabular BSDF")
    table = check_record(record)
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
    if fill not in (None, "nearest"):
        raise InputError(f"fill must be None or 'nearest', got {fill!r}")
    az = np.asarray(list(azimuths) if azimuths is not None else
                    np.arange(0.0, 361.0 if symmetry == "Asymmetrical" else 181.0, 10.0), float)
    rad = np.asarray(list(radials) if radials is not None else np.arange(0.0, 91.0, 2.0), float)
    for name, arr, hi in (("azimuths", az, 360.0), ("radials", rad, 180.0)):
        if arr.ndim != 1 or arr.size < 1 or np.any(np.diff(arr) <= 0) or arr[0] < 0 or arr[-1] > hi:
            raise InputError(f"{name} must be strictly increasing within [0, {hi:g}] degrees")
    rots = np.unique(sel["phi_i"].to_numpy(float))
    incs = np.unique(sel["theta_i"].to_numpy(float))
    values = np.zeros((len(rots), len(incs), len(az), len(rad)))
    has_std = "std" in sel.columns and bool(sel["std"].notna().any())
    stds = np.full(values.shape, np.nan) if has_std else None
    samples = np.full(values.shape, -1, dtype=np.int64)
    tis = np.zeros((len(rots), len(incs)))
    A, R = np.meshgrid(az, rad, indexing="ij")
    groups = {k: g for k, g in sel.groupby(["phi_i", "theta_i"], sort=False)}
    bounds = ["theta_min", "theta_max", "phi_min", "phi_max"]
    patches = all(c in sel.columns for c in bounds) and bool(sel[bounds].notna().all().all())
    off_plane_nodes = bool(np.any(np.abs((az + 90.0) % 180.0 - 90.0) > 1e-9))
    if not patches and off_plane_nodes and fill is None and max_distance_deg is None and in_plane(sel):
        raise InputError("an in-plane scan measured nothing off the plane of incidence; a Zemax grid there would be "
                         "invented by nearest-neighbour filling: export it as csv/astm (what it is), or pass "
                         "--fill nearest (fill=\"nearest\") to fill it anyway, recorded in the file's header")
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
                ig, _ = _lookup(part.assign(value=np.arange(len(part), dtype=float)), th[inside], ph[inside],
                                max_distance_deg)
                sm = np.full(th.shape, -1, dtype=np.int64)
                sm[inside] = np.where(np.isfinite(ig), np.nan_to_num(ig, nan=-1), -1).astype(np.int64)
                samples[k, j] = sm
                if stds is not None:
                    sg, _ = _lookup(part.assign(value=part["std"]), th[inside], ph[inside], max_distance_deg)
                    sv = np.full(th.shape, np.nan)
                    sv[inside] = sg
                    stds[k, j] = sv
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
                                "max_distance_deg": max_distance_deg, "fill": fill}
    return ZemaxGrid(rots, incs, az, rad, values, tis, float(wavelength_nm), st, symmetry, meta, stds, samples)


def _identity(meta: dict[str, Any]) -> dict[str, str]:
    """The record's identity for the header comments: specimen (model), sample name, run, bench,
    body, plan and the quantity with its unit (a BSDF in 1/sr)."""
    out = {"specimen": record_identity(meta)["specimen"] or meta.get("sample_name") or ""}
    out.update(record_provenance(meta))
    out["quantity"] = f"{record_identity(meta)['quantity']} (1/sr)"
    return out


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
             *(f"# {k} {v}" for k, v in _identity(meta).items()),
             "# SampleRotation = incidence azimuth phi_i (deg); AngleOfIncidence = theta_i (deg)",
             "# ScatterRadial/ScatterAzimuth about the specular direction; azimuth 0 = plane of incidence,"
             " toward the normal; 90 = +y at phi_i = 0 (libbsdf's specular frame)",
             *_resampling_lines(meta.get("zemax_resampling")),
             *_std_lines(g, digits),
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
    return write_text(path, "\n".join(lines) + "\n")


def _std_lines(g: ZemaxGrid, digits: int) -> list[str]:
    """``# std K J A ...`` comments: each node's standard uncertainty (``nan`` where unknown)."""
    out = []
    if g.sample is not None:
        out.append("# sample K J A <per ScatterRadial: the record row (of this rotation and incidence) the node "
                   "takes its value from, -1 none>")
        for k, j, a in np.ndindex(*g.sample.shape[:3]):
            out.append(f"# sample {k} {j} {a} " + " ".join(str(int(x)) for x in g.sample[k, j, a]))
    if g.std is not None:
        out.append("# std K J A <one standard uncertainty (1/sr) per ScatterRadial>: the std of each node's sample")
        for k, j, a in np.ndindex(*g.std.shape[:3]):
            out.append(f"# std {k} {j} {a} " + " ".join(f"{x:.{digits - 1}e}" for x in g.std[k, j, a]))
    return out


def in_plane(table: Any) -> bool:
    """Whether every row views in its plane of incidence (``phi_r = phi_i`` or ``phi_i + 180``,
    or the zenith): an in-plane scan."""
    gap = np.abs((table["phi_r"].to_numpy(float) - table["phi_i"].to_numpy(float) + 90.0) % 180.0 - 90.0)
    return bool(np.all((gap < 1e-6) | (table["theta_r"].to_numpy(float) == 0.0)))


def _resampling_lines(r: dict[str, Any] | None) -> list[str]:
    """Header comments saying how the record was resampled onto the grid (and how far)."""
    if not r:
        return []
    limit = r.get("max_distance_deg")
    asked = (["# resampling fill nearest (asked for): nodes off the measured plane take the nearest in-plane "
              "sample; they were not measured"] if r.get("fill") == "nearest" else [])
    return asked + [f"# resampling {r['method']}: each node takes the value of the "
            + ("collector patch containing its direction" if r["method"] == "containing patch"
               else "angularly nearest measured direction"),
            f"# resampling farthest node from its sample {float(r['max_nearest_distance_deg']):.6g} deg; "
            f"nodes left at 0 (beyond max_distance_deg {'none' if limit is None else f'{float(limit):g}'}): "
            f"{int(r['nodes_unfilled'])}"]


def wavelengths_of(record: BSDFRecord) -> list[float]:
    """The distinct wavelengths (nm) of a record, ascending."""
    return [float(w) for w in np.unique(check_record(record, ("wavelength_nm",))["wavelength_nm"].to_numpy(float))]


def record_to_zemax_files(record: BSDFRecord, path: str | Path, *, wavelength_nm: float | None = None,
                          **options: Any) -> list[Path]:
    """Zemax files of a record: one file at ``wavelength_nm`` when given (or when the record has
    one wavelength) at ``path``; else one file per wavelength, ``<stem>-<w>nm<suffix>`` beside
    ``path`` (a Zemax tabular BSDF holds one wavelength). ``options`` go to :func:`record_to_zemax`."""
    p = Path(path)
    require_bsdf(record, "a Zemax tabular BSDF")
    wls = wavelengths_of(record)
    if wavelength_nm is not None or len(wls) == 1:
        return [record_to_zemax(record, p, wavelength_nm=wavelength_nm, **options)]
    name = p.name[:-len(p.suffix)] if p.suffix else p.name
    targets = {w: p.with_name(f"{name}-{w:g}nm{p.suffix or '.bsdf'}") for w in wls}
    for target in targets.values():  # every file refused before any is written
        check_target(target)
    new = [t for t in targets.values() if not t.exists()]
    written: list[Path] = []
    try:
        for w, target in targets.items():
            written.append(record_to_zemax(record, target, wavelength_nm=w, **options))
    except BaseException:  # a full disk at the third wavelength: the files this call created go too
        for t in new:
            if t in written:
                t.unlink(missing_ok=True)
        raise
    return written


# --- Zemax ---------------------------------------------------------------------------------


def _read_std_lines(lines: list[str], shape: tuple[int, ...], tag: str = "std") -> np.ndarray:
    """The ``# std K J A ...`` (or ``# sample ...``) comments as an array of ``shape`` (NaN where
    absent or malformed)."""
    out = np.full(shape, np.nan)
    head = f"# {tag} "
    for line in lines:
        s = line.strip()
        if not s.startswith(head):
            continue
        parts = s[len(head):].split()
        if len(parts) != 3 + shape[3] or not all(x.isdigit() for x in parts[:3]):
            continue
        k, j, a = (int(x) for x in parts[:3])
        if k < shape[0] and j < shape[1] and a < shape[2] and all(is_float(x) for x in parts[3:]):
            out[k, j, a] = [float(x) for x in parts[3:]]
    return out


_ZEMAX_LISTS = ("SampleRotation", "AngleOfIncidence", "ScatterAzimuth", "ScatterRadial")


def read_zemax(path: str | Path, *, keep_beyond_horizon: bool = False) -> BSDFRecord:
    """Read a Zemax OpticStudio tabular BSDF (``Monochrome`` content).

    Every grid node (rotation, incidence, azimuth, radial) becomes one row: ``phi_i`` = sample
    rotation, ``theta_i`` = angle of incidence, ``(theta_r, phi_r)`` from
    :func:`bench.io.specular.from_specular` (BTDF: mirrored to the transmission side), ``value``;
    ``radial_deg`` and ``azimuth_deg`` keep the file's angles. Nodes beyond the hemisphere are
    dropped unless ``keep_beyond_horizon``. ``wavelength_nm`` comes from a ``# wavelength_nm``
    comment when present (else NaN). ``meta["tis"]`` lists the TIS per (rotation, incidence).
    """
    import pandas as pd

    p, lines = read_lines(path)
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
            raise bad(p, i + 1, "expected 'DataBegin', found the end of the file")
        parts = lines[i].split()
        key = parts[0]
        if key == "DataBegin":
            break
        if key in _ZEMAX_LISTS:
            if len(parts) != 2 or not parts[1].isdigit():
                raise bad(p, i + 1, f"expected '{key} <count>', got {lines[i].strip()!r}")
            count = int(parts[1])
            vals: list[float] = []
            j = i + 1
            while len(vals) < count:
                j = next_content(j)
                if j >= n_lines:
                    raise bad(p, j + 1, f"expected {count} values after {key}, found {len(vals)}")
                try:
                    vals.extend(float(x) for x in lines[j].split())
                except ValueError:
                    raise bad(p, j + 1, f"expected numbers for {key}, got {lines[j].strip()!r}") from None
                j += 1
            if len(vals) != count:
                raise bad(p, j, f"expected {count} values for {key}, got {len(vals)}")
            lists[key] = np.asarray(vals)
            i = j
            continue
        if key in ("Monochrome", "XYZ"):
            header["Content"] = key
        elif key in ("Source", "Symmetry", "SpectralContent", "ScatterType"):
            if len(parts) < 2:
                raise bad(p, i + 1, f"expected '{key} <value>', got {lines[i].strip()!r}")
            header[key] = parts[1]
        else:
            raise bad(p, i + 1, f"expected a Zemax BSDF header keyword (Source, Symmetry, SpectralContent, "
                                 f"ScatterType, {', '.join(_ZEMAX_LISTS)}, Monochrome, DataBegin), got {key!r}")
        i += 1
    for key in _ZEMAX_LISTS:
        if key not in lists:
            raise bad(p, i + 1, f"expected a '{key} <count>' section before DataBegin")
    if header.get("SpectralContent", "Monochrome") != "Monochrome":
        raise bad(p, None, f"only SpectralContent Monochrome is supported, got {header['SpectralContent']!r}")
    st = header.get("ScatterType", "BRDF").upper()
    if st not in ("BRDF", "BTDF"):
        raise bad(p, None, f"ScatterType must be BRDF or BTDF, got {header.get('ScatterType')!r}")
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
                raise bad(p, i + 1, f"expected 'TIS <value>' for rotation {rots[k]:g}, incidence {incs[j]:g}, "
                                     f"found the end of the file")
            parts = lines[i].split()
            if len(parts) != 2 or parts[0] != "TIS" or not is_float(parts[1]):
                raise bad(p, i + 1, f"expected 'TIS <value>' for rotation {rots[k]:g}, incidence {incs[j]:g}, "
                                     f"got {lines[i].strip()!r}")
            tis.append({"rotation": float(rots[k]), "theta_i": float(incs[j]), "tis": float(parts[1])})
            i += 1
            for a in range(len(az)):
                i = next_content(i)
                if i >= n_lines:
                    raise bad(p, i + 1, f"expected {len(az)} rows of {len(rad)} values, found the end of the file")
                fields = lines[i].split()
                if len(fields) != len(rad) or not all(is_float(f) for f in fields):
                    raise bad(p, i + 1, f"expected {len(rad)} numbers (one per ScatterRadial) for azimuth "
                                         f"{az[a]:g}, got {lines[i].strip()[:60]!r}")
                values[k, j, a] = [float(f) for f in fields]
                i += 1
    i = next_content(i)
    if i >= n_lines or lines[i].strip() != "DataEnd":
        raise bad(p, i + 1, "expected 'DataEnd' after the last block"
                   + ("" if i >= n_lines else f", got {lines[i].strip()[:60]!r}"))
    stds = _read_std_lines(lines, values.shape)
    samples = _read_std_lines(lines, values.shape, "sample")
    samples[samples < 0] = np.nan
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
                "value": values[k, j][keep], "std": stds[k, j][keep], "sample": samples[k, j][keep],
                "radial_deg": R[keep],
                "azimuth_deg": A[keep]}))
    df = pd.concat(frames, ignore_index=True)
    meta = {"format": "zemax", "source_file": str(p), "scatter_type": st,
            "symmetry": header.get("Symmetry"), "source": header.get("Source"), "tis": tis,
            "wavelength_nm": None if math.isnan(wavelength) else wavelength}
    for key in ("specimen", "run_id", "bench", "body", "plan", "sample_name"):  # the identity our header states
        if comments.get(key):
            meta[key] = comments[key]
    if comments.get("plan"):
        meta["plan_name"] = comments["plan"]
    if comments.get("bench"):
        meta["bench_name"] = comments["bench"]
    return BSDFRecord(complete(df), meta)

