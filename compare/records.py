"""Record introspection for comparisons: what a record is (BSDF table, spectrum, set of spectra),
its quantity, unit and metadata, and its long form (one row per compared value, with the
identity keys, the value and its standard uncertainty and where that came from).

Used by :mod:`compare.align` (matching) and :mod:`compare.checks` (physical checks).
"""

from __future__ import annotations

from pathlib import PurePath
from typing import Any, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from bench.core.records import BSDFRecord, with_keys
from bench.core.roles import Spectrum

#: what the comparison takes: a BSDF record, a spectrum, or a set of spectra (a spectro sweep)
Record = BSDFRecord | Spectrum | tuple[Spectrum, ...]

__all__ = ["Record", "as_record", "record_kind", "record_quantity", "record_meta", "is_virtual", "angular_distance_deg"]


def as_record(obj: Any) -> Record:
    """Accept a :class:`BSDFRecord`, a :class:`Spectrum`, a sequence of spectra, or a ``pandas.DataFrame`` with the BSDF
    columns (wrapped as a record with empty metadata); anything else is an :class:`InputError`."""
    if isinstance(obj, (BSDFRecord, Spectrum)):
        return obj
    if isinstance(obj, (list, tuple)) and obj and all(isinstance(x, Spectrum) for x in obj):
        return tuple(obj)  # a set of spectra (a spectro sweep): specimen/geometry are its keys
    if isinstance(obj, pd.DataFrame):
        missing = {"wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "value"} - set(obj.columns)
        if missing:
            raise InputError(f"a BSDF table needs columns {sorted(missing)}")
        return BSDFRecord(obj.reset_index(drop=True), {})
    hint = " (read files with bench.io.read_record)" if isinstance(obj, (str, PurePath)) else ""
    raise InputError(f"expected a BSDFRecord or Spectrum, got {type(obj).__name__}{hint}")


def record_kind(rec: Record) -> str:
    """``"spectrum"`` or ``"bsdf"``."""
    return "spectrum" if isinstance(rec, (Spectrum, tuple)) else "bsdf"


_BSDF_ALIASES = {"bsdf": "BSDF", "brdf": "BSDF", "btdf": "BSDF", "1/sr": "BSDF"}


def record_quantity(rec: Record) -> str:
    """The measured quantity, normalized: ``"reflectance"``, ``"reflectance factor"`` (spectra),
    ``"BSDF"`` (BRDF/BTDF in 1/sr), or whatever else ``meta["quantity"]`` says (e.g. ``"DSF"``)."""
    if isinstance(rec, tuple):
        qs = sorted({record_quantity(x) for x in rec})
        return qs[0] if len(qs) == 1 else " / ".join(qs)
    if isinstance(rec, Spectrum):
        return str(rec.meta.get("quantity", "reflectance")).strip().lower()
    q = str(rec.meta.get("quantity", "BSDF")).strip()
    return _BSDF_ALIASES.get(q.lower(), q)


def record_meta(rec: Record) -> dict[str, Any]:
    """A record's metadata; for a set of spectra, the first one's with ``n_spectra``, the
    ``specimens`` and the ``geometries`` of the set."""
    if isinstance(rec, tuple):
        return {**dict(rec[0].meta), "n_spectra": len(rec),
                "specimens": sorted({str(x.meta.get("specimen")) for x in rec}),
                "geometries": sorted({str(x.geometry) for x in rec})}
    return dict(rec.meta)


def _unit(rec: Record) -> str | None:
    if isinstance(rec, tuple):
        return _unit(rec[0])
    u = rec.meta.get("unit", rec.meta.get("units"))
    return None if u is None else str(u).strip()


def is_virtual(rec: Record) -> bool:
    """True for a Monte Carlo record (``meta["source"] == "virtual"`` or, for a spectrum, ``N > 0``)."""
    if isinstance(rec, tuple):
        return all(is_virtual(x) for x in rec)
    src = rec.meta.get("source")
    if src is not None:
        return str(src) == "virtual"
    if isinstance(rec, Spectrum):
        return bool(np.any(np.asarray(rec.N) > 0))
    t = rec.table
    return "N" in t and bool((pd.to_numeric(t["N"], errors="coerce").fillna(0) > 0).any())


def _z_two_sided(delta: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(1.0 - delta / 2.0))


def _std_from_ci(lo: np.ndarray, hi: np.ndarray, delta: float) -> np.ndarray:
    return (np.asarray(hi, float) - np.asarray(lo, float)) / (2.0 * _z_two_sided(delta))


def _spectra_long(s: Spectrum | tuple, channels: Sequence[str]) -> pd.DataFrame:
    """:func:`_spectrum_long` of one spectrum or of every spectrum of a set, with the keys."""
    items = s if isinstance(s, tuple) else (s,)
    frames = []
    for x in items:
        f = _spectrum_long(x, channels)
        f.insert(0, "quantity", record_quantity(x))
        f.insert(0, "geometry", str(x.geometry))
        f.insert(0, "collector", None)
        f.insert(0, "specimen", None if x.meta.get("specimen") is None else str(x.meta["specimen"]))
        frames.append(f)
    return pd.concat(frames, ignore_index=True)


def _spectrum_long(s: Spectrum, channels: Sequence[str]) -> pd.DataFrame:
    """One row per (channel, wavelength); ``std`` from ``meta["<channel>_std"]`` when given, else
    the binomial standard error sqrt(p(1-p)/N) (hemispherical quantities, 0 < p < 1), else the
    interval half-width / z_(1-delta/2); ``std_source`` says which."""
    wl = np.asarray(s.wavelengths, float)
    frames = []
    for ch in channels:
        v = np.asarray(getattr(s, ch), float)
        ci = np.asarray(getattr(s, f"{ch}_ci"), float)
        std = np.full(v.shape, np.nan)
        source = np.full(v.shape, "none", dtype=object)
        given = s.meta.get(f"{ch}_std")
        if given is not None:
            std = np.asarray(given, float) * np.ones_like(v)
            source[:] = "given"
        elif np.any(np.asarray(s.N) > 0):
            n = np.asarray(s.N, float) * np.ones_like(v)
            ok = (v > 0) & (v < 1) & (n > 0) & (record_quantity(s) == "reflectance" or ch == "transmittance")
            std[ok] = np.sqrt(v[ok] * (1 - v[ok]) / n[ok])
            source[ok] = "binomial"
            rest = ~ok & np.all(np.isfinite(ci), axis=1)
            std[rest] = _std_from_ci(ci[rest, 0], ci[rest, 1], float(s.delta))
            source[rest] = "interval"
        frames.append(pd.DataFrame({"channel": ch, "wavelength_nm": wl, "theta_i": np.nan, "phi_i": np.nan,
                                    "theta_r": np.nan, "phi_r": np.nan, "value": v, "std": std,
                                    "std_source": source, "psa": np.nan, "sample": np.nan}))
    return pd.concat(frames, ignore_index=True)


def _bsdf_long(r: BSDFRecord) -> pd.DataFrame:
    t = with_keys(BSDFRecord(r.table.reset_index(drop=True), r.meta)).table
    out = pd.DataFrame({
        "specimen": t["specimen"].astype(object), "collector": t["collector"].astype(object),
        "geometry": t["geometry"].astype(object),
        "quantity": [_BSDF_ALIASES.get(str(q).lower(), str(q)) for q in t["quantity"]],
        "channel": t["hemisphere"].astype(str) if "hemisphere" in t else np.where(t.theta_r > 90, "T", "R"),
        "wavelength_nm": t.wavelength_nm.astype(float), "theta_i": t.theta_i.astype(float),
        "phi_i": t.phi_i.astype(float), "theta_r": t.theta_r.astype(float), "phi_r": t.phi_r.astype(float),
        "value": t.value.astype(float),
    })
    std = t["std"].astype(float).to_numpy() if "std" in t else np.full(len(t), np.nan)
    source = np.where(np.isfinite(std), "given", "none").astype(object)
    # a zero-count patch has a zero binomial std but not zero uncertainty: use its interval
    delta = float(r.meta.get("delta", 0.01))
    if {"ci_lo", "ci_hi"} <= set(t.columns):
        lo, hi = t.ci_lo.to_numpy(float), t.ci_hi.to_numpy(float)
        fix = (~np.isfinite(std) | (std == 0)) & np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
        std = std.copy()
        std[fix] = _std_from_ci(lo[fix], hi[fix], delta)
        source[fix] = "interval"
    out["std"] = std
    out["std_source"] = source
    for c in ("theta_min", "theta_max", "phi_min", "phi_max", "psa", "sample"):
        out[c] = t[c].astype(float) if c in t else np.nan
    return out


def _dirs(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def angular_distance_deg(t1: Any, p1: Any, t2: Any, p2: Any) -> np.ndarray:
    """Angle (deg) between directions (t1, p1) and (t2, p2), broadcasting."""
    d = np.sum(_dirs(t1, p1) * _dirs(t2, p2), axis=-1)
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


