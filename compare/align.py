"""Alignment of an actual record with a candidate (virtual) record, point by point.

Records are :class:`bench.core.records.BSDFRecord` or :class:`bench.core.roles.Spectrum` objects;
this module reads their tables and metadata only (it never imports ``virtual`` or ``drivers``).

Matching rules
--------------
* The actual record is the reference grid: every actual point gets one candidate value or a
  row in ``Aligned.unmatched`` saying why not. Nothing is dropped silently.
* Wavelength: a candidate wavelength within ``wavelength_tol_nm`` is used as is; otherwise, when
  the actual wavelength lies inside the candidate's range, the candidate is interpolated
  linearly between the two bracketing wavelengths (the standard uncertainty propagated as for
  independent values, ``sqrt(a^2 s0^2 + b^2 s1^2)``); outside the range the point is unmatched
  (no extrapolation). ``pairs.wavelength_method`` says which (``"match"`` or ``"linear"``).
* Incidence (BSDF): the candidate incidence nearest in angular distance between incident
  directions, accepted within ``angle_tol_deg``.
* Viewing direction (BSDF): ``"patch"`` looks the actual direction up in the candidate's patch
  bounds (half-open ``[min, max)`` in theta and phi, the hemisphere's outer edge and pole
  included, so a direction falls in exactly one patch); ``"nearest"`` takes the nearest
  candidate direction within ``angle_tol_deg``; ``"auto"`` uses ``"patch"`` when the candidate
  has finite patch bounds.
* Quantities must agree (meta ``"quantity"``: BSDF vs reflectance factor vs reflectance, and
  ``"unit"``/``"units"`` when both give one); otherwise :class:`QuantityMismatchError`. No
  overlap at all raises :class:`NoOverlapError`, naming what is missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import PurePath
from typing import Any, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from bench.core.roles import Spectrum
from bench.core.records import BSDFRecord

__all__ = [
    "AlignmentError", "QuantityMismatchError", "NoOverlapError", "Aligned", "align", "as_record",
    "record_kind", "record_quantity", "is_virtual", "PAIR_COLUMNS", "UNMATCHED_COLUMNS",
    "DEFAULT_ANGLE_TOL_DEG", "DEFAULT_WAVELENGTH_TOL_NM",
]

DEFAULT_ANGLE_TOL_DEG = 1.0
DEFAULT_WAVELENGTH_TOL_NM = 0.5

PAIR_COLUMNS = ["channel", "wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "actual_value", "actual_std",
                "virtual_value", "virtual_std", "psa", "virtual_wavelength_nm", "virtual_theta_i", "virtual_phi_i",
                "virtual_theta_r", "virtual_phi_r", "angle_distance_deg", "wavelength_method", "match_method",
                "virtual_index", "actual_index", "actual_std_source", "virtual_std_source"]
UNMATCHED_COLUMNS = ["side", "channel", "wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "reason"]


class AlignmentError(InputError):
    """Two records that cannot be compared point by point."""


class QuantityMismatchError(AlignmentError):
    """The records hold different quantities or units (e.g. BRDF vs reflectance factor)."""


class NoOverlapError(AlignmentError):
    """No actual point has a counterpart in the candidate record."""


@dataclass
class Aligned:
    """Matched pairs of an actual and a candidate record.

    Attributes
    ----------
    pairs : pandas.DataFrame
        :data:`PAIR_COLUMNS`; the geometry and wavelength are the actual's, ``virtual_*`` say where
        the candidate value came from; ``actual_index``/``virtual_index`` are row labels of the
        records' tables (BSDF; for spectra, rows of the per-channel long table).
    unmatched : pandas.DataFrame
        :data:`UNMATCHED_COLUMNS`: actual points without a counterpart (``side == "actual"``) and
        candidate groups (wavelength/incidence) that no actual point used (``side == "candidate"``).
    kind : ``"spectrum"`` or ``"bsdf"``
    quantity : the common quantity (``"reflectance"``, ``"reflectance factor"``, ``"BSDF"``, ...)
    meta : tolerances, methods, both records' metadata (``actual_meta``, ``virtual_meta``) and
        whether each side is virtual.
    warnings : things a reader must know (reused candidate patches, interpolation, ...).
    """

    pairs: pd.DataFrame
    unmatched: pd.DataFrame
    kind: str
    quantity: str
    meta: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.pairs)


# --- record introspection ----------------------------------------------------------------


def as_record(obj: Any) -> BSDFRecord | Spectrum:
    """Accept a :class:`BSDFRecord`, a :class:`Spectrum`, or a ``pandas.DataFrame`` with the BSDF
    columns (wrapped as a record with empty metadata); anything else is an :class:`InputError`."""
    if isinstance(obj, (BSDFRecord, Spectrum)):
        return obj
    if isinstance(obj, pd.DataFrame):
        missing = {"wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "value"} - set(obj.columns)
        if missing:
            raise InputError(f"a BSDF table needs columns {sorted(missing)}")
        return BSDFRecord(obj.reset_index(drop=True), {})
    hint = " (read files with bench.io.read_record)" if isinstance(obj, (str, PurePath)) else ""
    raise InputError(f"expected a BSDFRecord or Spectrum, got {type(obj).__name__}{hint}")


def record_kind(rec: BSDFRecord | Spectrum) -> str:
    """``"spectrum"`` or ``"bsdf"``."""
    return "spectrum" if isinstance(rec, Spectrum) else "bsdf"


_BSDF_ALIASES = {"bsdf": "BSDF", "brdf": "BSDF", "btdf": "BSDF", "1/sr": "BSDF"}


def record_quantity(rec: BSDFRecord | Spectrum) -> str:
    """The measured quantity, normalized: ``"reflectance"``, ``"reflectance factor"`` (spectra),
    ``"BSDF"`` (BRDF/BTDF in 1/sr), or whatever else ``meta["quantity"]`` says (e.g. ``"DSF"``)."""
    if isinstance(rec, Spectrum):
        return str(rec.meta.get("quantity", "reflectance")).strip().lower()
    q = str(rec.meta.get("quantity", "BSDF")).strip()
    return _BSDF_ALIASES.get(q.lower(), q)


def _unit(rec: BSDFRecord | Spectrum) -> str | None:
    u = rec.meta.get("unit", rec.meta.get("units"))
    return None if u is None else str(u).strip()


def is_virtual(rec: BSDFRecord | Spectrum) -> bool:
    """True for a Monte Carlo record (``meta["source"] == "virtual"`` or, for a spectrum, ``N > 0``)."""
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
                                    "std_source": source, "psa": np.nan}))
    return pd.concat(frames, ignore_index=True)


def _bsdf_long(r: BSDFRecord) -> pd.DataFrame:
    t = r.table.reset_index(drop=True).copy()
    out = pd.DataFrame({
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
    for c in ("theta_min", "theta_max", "phi_min", "phi_max", "psa"):
        out[c] = t[c].astype(float) if c in t else np.nan
    return out


def _dirs(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def angular_distance_deg(t1: Any, p1: Any, t2: Any, p2: Any) -> np.ndarray:
    """Angle (deg) between directions (t1, p1) and (t2, p2), broadcasting."""
    d = np.sum(_dirs(t1, p1) * _dirs(t2, p2), axis=-1)
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def _wavelength_weights(w: float, grid: np.ndarray, tol: float) -> tuple[list[tuple[float, float]], str, str]:
    """``([(candidate wavelength, weight), ...], method, reason_if_empty)``."""
    if grid.size == 0:
        return [], "", "candidate has no wavelengths"
    j = int(np.argmin(np.abs(grid - w)))
    if abs(grid[j] - w) <= tol:
        return [(float(grid[j]), 1.0)], "match", ""
    if grid.size >= 2 and grid[0] < w < grid[-1]:
        k = int(np.searchsorted(grid, w))
        w0, w1 = float(grid[k - 1]), float(grid[k])
        a = (w - w0) / (w1 - w0)
        return [(w0, 1.0 - a), (w1, a)], "linear", ""
    return [], "", (f"wavelength {w:g} nm outside the candidate's range {grid[0]:g}-{grid[-1]:g} nm "
                    f"(tolerance {tol:g} nm; no extrapolation)")


def _locate_patch(th: np.ndarray, ph: np.ndarray, ch: np.ndarray, c: pd.DataFrame) -> np.ndarray:
    """Index into ``c`` of the patch containing each direction, -1 when none."""
    tmin, tmax = c.theta_min.to_numpy(), c.theta_max.to_numpy()
    pmin, pmax = c.phi_min.to_numpy(), c.phi_max.to_numpy()
    cch = c.channel.to_numpy()
    top = np.where(cch == "T", 180.0, 90.0)
    width = pmax - pmin
    inside_t = (th[:, None] >= tmin[None, :] - 1e-9) & (
        (th[:, None] < tmax[None, :]) | ((np.abs(tmax - top)[None, :] < 1e-9) & (th[:, None] <= tmax[None, :] + 1e-9)))
    rel = np.mod(ph[:, None] - pmin[None, :], 360.0)
    inside_p = (rel < width[None, :]) | (width[None, :] >= 360.0 - 1e-9)
    hit = inside_t & inside_p & (ch[:, None] == cch[None, :])
    idx = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
    return idx


def _check_compatible(actual: Any, cand: Any) -> tuple[str, str]:
    ka, kc = record_kind(actual), record_kind(cand)
    if ka != kc:
        raise QuantityMismatchError(f"cannot compare a {ka} record with a {kc} record "
                                    f"(quantities {record_quantity(actual)!r} vs {record_quantity(cand)!r})")
    qa, qc = record_quantity(actual), record_quantity(cand)
    if qa != qc:
        raise QuantityMismatchError(f"quantity mismatch: actual is {qa!r}, candidate is {qc!r} "
                                    f"(e.g. BRDF vs reflectance factor R = pi * BRDF); convert one first")
    ua, uc = _unit(actual), _unit(cand)
    if ua is not None and uc is not None and ua != uc:
        raise QuantityMismatchError(f"unit mismatch: actual in {ua!r}, candidate in {uc!r}")
    if ka == "spectrum" and str(actual.geometry) != str(cand.geometry):
        raise QuantityMismatchError(f"geometry mismatch: actual measured at {actual.geometry}, candidate at "
                                    f"{cand.geometry}")
    return ka, qa


def align(actual: Any, candidate: Any, *, angle_tol_deg: float = DEFAULT_ANGLE_TOL_DEG,
          wavelength_tol_nm: float = DEFAULT_WAVELENGTH_TOL_NM, match: str = "auto",
          channels: Sequence[str] | str = "auto") -> Aligned:
    """Match every point of ``actual`` with ``candidate`` (see the module docstring for the rules).

    Parameters
    ----------
    actual, candidate : BSDFRecord or Spectrum (or a BSDF DataFrame)
    angle_tol_deg : float
        Largest angle (deg) between incident directions (and, for ``match="nearest"``, viewing
        directions) accepted as the same geometry.
    wavelength_tol_nm : float
        Largest wavelength difference (nm) accepted as the same wavelength; beyond it the
        candidate is interpolated linearly inside its range.
    match : ``"auto"``, ``"patch"`` or ``"nearest"`` (BSDF only)
    channels : spectra: ``"auto"`` (reflectance, plus transmittance when either record has any
        non-zero transmittance) or a list of ``"reflectance"``/``"transmittance"``; BSDF:
        ``"auto"`` (the hemispheres of the actual record in which either record has a non-zero
        value; an all-zero hemisphere in both carries no information) or a list of ``"R"``/``"T"``.

    Returns
    -------
    Aligned

    Raises
    ------
    QuantityMismatchError, NoOverlapError, InputError
    """
    actual, candidate = as_record(actual), as_record(candidate)
    if not (math.isfinite(angle_tol_deg) and angle_tol_deg >= 0):
        raise InputError(f"angle_tol_deg must be finite and >= 0, got {angle_tol_deg}")
    if not (math.isfinite(wavelength_tol_nm) and wavelength_tol_nm >= 0):
        raise InputError(f"wavelength_tol_nm must be finite and >= 0, got {wavelength_tol_nm}")
    if match not in ("auto", "patch", "nearest"):
        raise InputError(f"match must be 'auto', 'patch' or 'nearest', got {match!r}")
    kind, quantity = _check_compatible(actual, candidate)
    warnings: list[str] = []
    meta: dict[str, Any] = {"angle_tol_deg": float(angle_tol_deg), "wavelength_tol_nm": float(wavelength_tol_nm),
                            "wavelength_interpolation": "linear in wavelength (candidate onto the actual grid)",
                            "actual_meta": dict(actual.meta), "virtual_meta": dict(candidate.meta),
                            "actual_is_virtual": is_virtual(actual), "virtual_is_virtual": is_virtual(candidate)}
    if kind == "spectrum":
        if channels == "auto":
            chans = ["reflectance"]
            if np.any(np.asarray(actual.transmittance) != 0) or np.any(np.asarray(candidate.transmittance) != 0):
                chans.append("transmittance")
        else:
            chans = list(channels)
            bad = set(chans) - {"reflectance", "transmittance"}
            if bad:
                raise InputError(f"spectrum channels are 'reflectance' and 'transmittance', got {sorted(bad)}")
        meta["channels"] = chans
        meta["geometry"] = str(actual.geometry)
        a, c = _spectrum_long(actual, chans), _spectrum_long(candidate, chans)
        pairs, unmatched = _align_groups(a, c, angle_tol_deg, wavelength_tol_nm, "none", warnings)
        meta["match_method"] = "wavelength only (same CIE geometry)"
    else:
        a, c = _bsdf_long(actual), _bsdf_long(candidate)
        if channels == "auto":
            present = set(a.channel)
            chans = [h for h in ("R", "T") if h in present and ((a[a.channel == h].value.abs() > 0).any()
                                                                or (c[c.channel == h].value.abs() > 0).any())]
            chans = chans or sorted(present)[:1] or ["R"]
        else:
            chans = list(channels)
        meta["channels"] = chans
        dropped = a[~a.channel.isin(chans)]
        a = a[a.channel.isin(chans)]  # keep the record's row labels: pairs name the rows they came from
        c = c[c.channel.isin(chans)]
        if len(dropped):
            meta["channels_note"] = (f"{len(dropped)} actual points in hemisphere(s) "
                                     f"{sorted(set(dropped.channel))} not compared (zero in both records)")
        has_bounds = bool(len(c)) and bool(np.all(np.isfinite(c[["theta_min", "theta_max", "phi_min",
                                                                 "phi_max"]].to_numpy())))
        how = match if match != "auto" else ("patch" if has_bounds else "nearest")
        if how == "patch" and not has_bounds:
            raise InputError("match='patch' needs patch bounds (theta_min ... phi_max) in the candidate record")
        meta["match_method"] = how
        pairs, unmatched = _align_groups(a, c, angle_tol_deg, wavelength_tol_nm, how, warnings)
    if pairs.empty:
        reasons = unmatched[unmatched.side == "actual"].reason.value_counts().head(3)
        detail = "; ".join(f"{n} x {r}" for r, n in reasons.items()) or "the actual record is empty"
        raise NoOverlapError(f"no actual point has a counterpart in the candidate record: {detail}")
    if (pairs.wavelength_method == "linear").any():
        warnings.append(f"{int((pairs.wavelength_method == 'linear').sum())} candidate values interpolated "
                        f"linearly in wavelength onto the actual grid")
    if kind == "bsdf":
        reuse = pairs.groupby(["virtual_wavelength_nm", "virtual_index"], dropna=False).size()
        if (reuse > 1).any():
            warnings.append(f"{int((reuse > 1).sum())} candidate patches serve more than one actual point "
                            f"(their discrepancies are correlated; chi-square treats them as independent)")
    n_unmatched = int((unmatched.side == "actual").sum())
    if n_unmatched:
        warnings.append(f"{n_unmatched} actual points could not be matched (see the unmatched report)")
    return Aligned(pairs=pairs, unmatched=unmatched, kind=kind, quantity=quantity, meta=meta, warnings=warnings)


def _align_groups(a: pd.DataFrame, c: pd.DataFrame, angle_tol: float, wl_tol: float, how: str,
                  warnings: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    rows: list[pd.DataFrame] = []
    unmatched: list[dict[str, Any]] = []
    used_groups: set[tuple[float, float, float]] = set()
    spectral = how == "none"

    def miss(sub: pd.DataFrame, reason: str) -> None:
        for r in sub.itertuples(index=False):
            unmatched.append({"side": "actual", "channel": r.channel, "wavelength_nm": r.wavelength_nm,
                              "theta_i": r.theta_i, "phi_i": r.phi_i, "theta_r": r.theta_r, "phi_r": r.phi_r,
                              "reason": reason})

    if spectral:
        inc_groups = [((np.nan, np.nan), a)]
        cand_inc = [(np.nan, np.nan)]
    else:
        inc_groups = list(a.groupby(["theta_i", "phi_i"], sort=True))
        cand_inc = [tuple(k) for k, _ in c.groupby(["theta_i", "phi_i"], sort=True)]
    for (ti, pi_), ga in inc_groups:
        if spectral:
            cg = c
            cti, cpi = np.nan, np.nan
        else:
            if not cand_inc:
                miss(ga, "candidate record is empty")
                continue
            d = np.array([float(angular_distance_deg(ti, pi_, t2, p2)) for t2, p2 in cand_inc])
            j = int(np.argmin(d))
            if d[j] > angle_tol:
                miss(ga, f"no candidate incidence within {angle_tol:g} deg of ({ti:g}, {pi_:g}) "
                         f"(nearest ({cand_inc[j][0]:g}, {cand_inc[j][1]:g}) at {d[j]:.3g} deg)")
                continue
            cti, cpi = cand_inc[j]
            cg = c[(c.theta_i == cti) & (c.phi_i == cpi)]
        for ch, gch in ga.groupby("channel", sort=False):
            cch = cg[cg.channel == ch]
            grid = np.unique(cch.wavelength_nm.to_numpy(float))
            for w, gw in gch.groupby("wavelength_nm", sort=True):
                weights, wmethod, reason = _wavelength_weights(float(w), grid, wl_tol)
                if not weights:
                    miss(gw, reason if grid.size else f"candidate has no {ch} data at this incidence")
                    continue
                value = np.zeros(len(gw))
                var = np.zeros(len(gw))
                ok = np.ones(len(gw), dtype=bool)
                first_idx = np.full(len(gw), -1)
                reasons = np.full(len(gw), "", dtype=object)
                srcs = np.full(len(gw), "", dtype=object)
                for wc, wt in weights:
                    cw = cch[cch.wavelength_nm == wc]
                    used_groups.add((cti, cpi, wc))
                    if spectral:
                        idx = np.zeros(len(gw), dtype=int)
                    elif how == "patch":
                        idx = _locate_patch(gw.theta_r.to_numpy(float), gw.phi_r.to_numpy(float) % 360.0,
                                            gw.channel.to_numpy(), cw)
                        reasons[idx < 0] = "direction outside every candidate patch"
                    else:
                        dd = angular_distance_deg(gw.theta_r.to_numpy(float)[:, None],
                                                  gw.phi_r.to_numpy(float)[:, None],
                                                  cw.theta_r.to_numpy(float)[None, :],
                                                  cw.phi_r.to_numpy(float)[None, :])
                        idx = np.argmin(dd, axis=1)
                        best = dd[np.arange(len(gw)), idx]
                        far = best > angle_tol
                        for i in np.flatnonzero(far):
                            reasons[i] = (f"no candidate direction within {angle_tol:g} deg "
                                          f"(nearest at {best[i]:.3g} deg)")
                        idx = np.where(far, -1, idx)
                    ok &= idx >= 0
                    safe = np.maximum(idx, 0)
                    cv, cs = cw.value.to_numpy(float)[safe], cw["std"].to_numpy(float)[safe]
                    value += wt * cv
                    var += (wt * cs) ** 2
                    srcs = np.where(srcs == "", cw.std_source.to_numpy()[safe], srcs)
                    if wt == weights[0][1] and wc == weights[0][0]:
                        first_idx = np.where(idx >= 0, cw.index.to_numpy()[safe], -1)
                        vt = cw.theta_r.to_numpy(float)[safe]
                        vp = cw.phi_r.to_numpy(float)[safe]
                        cpsa = cw.psa.to_numpy(float)[safe]
                if (~ok).any():
                    miss(gw[~ok], "; ".join(sorted(set(reasons[~ok]) - {""})) or "no candidate point")
                if not ok.any():
                    continue
                g = gw[ok]
                vwl = float(weights[0][0]) if wmethod == "match" else np.nan
                dist = (angular_distance_deg(g.theta_r.to_numpy(float), g.phi_r.to_numpy(float), vt[ok], vp[ok])
                        if not spectral else np.full(len(g), np.nan))
                psa = g.psa.to_numpy(float)
                if not spectral:
                    psa = np.where(np.isfinite(psa), psa, cpsa[ok])
                rows.append(pd.DataFrame({
                    "channel": g.channel.to_numpy(), "wavelength_nm": g.wavelength_nm.to_numpy(float),
                    "theta_i": g.theta_i.to_numpy(float), "phi_i": g.phi_i.to_numpy(float),
                    "theta_r": g.theta_r.to_numpy(float), "phi_r": g.phi_r.to_numpy(float),
                    "actual_value": g.value.to_numpy(float), "actual_std": g["std"].to_numpy(float),
                    "virtual_value": value[ok], "virtual_std": np.sqrt(var[ok]), "psa": psa,
                    "virtual_wavelength_nm": vwl, "virtual_theta_i": cti, "virtual_phi_i": cpi,
                    "virtual_theta_r": vt[ok] if not spectral else np.nan,
                    "virtual_phi_r": vp[ok] if not spectral else np.nan,
                    "angle_distance_deg": dist, "wavelength_method": wmethod, "match_method": how,
                    "virtual_index": first_idx[ok], "actual_index": g.index.to_numpy(),
                    "actual_std_source": g.std_source.to_numpy(),
                    "virtual_std_source": srcs[ok],
                }))
    # candidate groups no actual point used
    cand_groups = c.groupby(["theta_i", "phi_i", "wavelength_nm"], dropna=False, sort=True).size()
    for (t2, p2, wc), n in cand_groups.items():
        key = (t2, p2, wc)
        if not any(_same_key(key, u) for u in used_groups):
            unmatched.append({"side": "candidate", "channel": "", "wavelength_nm": wc, "theta_i": t2, "phi_i": p2,
                              "theta_r": np.nan, "phi_r": np.nan,
                              "reason": f"no actual point uses this candidate "
                                        f"{'wavelength' if spectral else 'incidence/wavelength'} ({n} values)"})
    pairs = pd.concat(rows, ignore_index=True)[PAIR_COLUMNS] if rows else pd.DataFrame(columns=PAIR_COLUMNS)
    return pairs, pd.DataFrame(unmatched, columns=UNMATCHED_COLUMNS)


def _same_key(a: tuple, b: tuple) -> bool:
    return all((x == y) or (isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y))
               for x, y in zip(a, b))
