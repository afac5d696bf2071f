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
* Identity keys (``specimen``, ``collector``, ``geometry``, ``quantity``; see
  :data:`bench.core.records.IDENTITY_KEYS`): a key on which either record has more than one
  value (a multi-specimen sweep, a spectro sweep over geometries) is matched exactly -- each
  actual row is compared only with candidate rows of the same specimen, collector, CIE geometry
  and quantity. A record with a single value of a key is one measurement *of* something (a model
  of the measured specimen need not share its name), so single-valued keys are not matched,
  except ``geometry`` and ``quantity`` which must agree. Actual key values the candidate lacks
  are unmatched rows naming them; when none of the actual's key values is in the candidate,
  :class:`NoOverlapError` names the missing keys.
* Quantities must agree (meta ``"quantity"``: BSDF vs reflectance factor vs reflectance, and
  ``"unit"``/``"units"`` when both give one); otherwise :class:`QuantityMismatchError`. No
  overlap at all raises :class:`NoOverlapError`, naming what is missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from compare.records import (_bsdf_long, _spectra_long, _unit, angular_distance_deg, as_record, is_virtual, record_kind, record_meta, record_quantity)

__all__ = [
    "AlignmentError", "QuantityMismatchError", "NoOverlapError", "MissingValueError", "Aligned", "align", "as_record",
    "record_kind", "record_quantity", "record_meta", "is_virtual", "MATCH_KEYS", "PAIR_COLUMNS", "UNMATCHED_COLUMNS",
    "DEFAULT_ANGLE_TOL_DEG", "DEFAULT_WAVELENGTH_TOL_NM",
]

DEFAULT_ANGLE_TOL_DEG = 1.0
DEFAULT_WAVELENGTH_TOL_NM = 0.5

MATCH_KEYS = ("specimen", "collector", "geometry", "quantity")

PAIR_COLUMNS = ["specimen", "collector", "geometry", "quantity", "channel", "wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "actual_value", "actual_std",
                "virtual_value", "virtual_std", "psa", "virtual_wavelength_nm", "virtual_theta_i", "virtual_phi_i",
                "virtual_theta_r", "virtual_phi_r", "angle_distance_deg", "wavelength_method", "match_method",
                "virtual_index", "actual_index", "actual_std_source", "virtual_std_source", "actual_sample",
                "virtual_sample"]
UNMATCHED_COLUMNS = ["side", "specimen", "collector", "geometry", "channel", "wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r", "reason"]


class AlignmentError(InputError):
    """Two records that cannot be compared point by point."""


class QuantityMismatchError(AlignmentError):
    """The records hold different quantities or units (e.g. BRDF vs reflectance factor)."""


class NoOverlapError(AlignmentError):
    """No actual point has a counterpart in the candidate record."""


class MissingValueError(AlignmentError):
    """A matched point whose actual or candidate value is missing or not finite (NaN, a masked
    reading): refused, since a test that left it out would accept on the rest."""


def _refuse_missing(pairs: pd.DataFrame) -> None:
    """Raise :class:`MissingValueError` naming how many matched values are not finite and where
    the first one is."""
    for side in ("actual", "virtual"):
        bad = ~np.isfinite(pairs[f"{side}_value"].to_numpy(float))
        if bad.any():
            r = pairs[bad].iloc[0]
            where = ", ".join(f"{k} {r[k]}" for k in ("specimen", "geometry", "channel") if isinstance(r[k], str))
            angles = "" if not np.isfinite(r.theta_r) else f", theta_i/r {r.theta_i:g}/{r.theta_r:g} deg"
            record = "actual" if side == "actual" else "candidate"
            raise MissingValueError(
                f"{record} record: {int(bad.sum())} matched value(s) missing or not finite (first: {where}, "
                f"{r.wavelength_nm:g} nm{angles}, value {r[f'{side}_value']}); refused rather than left out "
                f"of the test: drop or re-measure those points")


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
    if isinstance(actual, tuple) or isinstance(cand, tuple):
        sa = {record_quantity(x) for x in (actual if isinstance(actual, tuple) else (actual,))}
        sc = {record_quantity(x) for x in (cand if isinstance(cand, tuple) else (cand,))}
        if not sa & sc:
            raise QuantityMismatchError(f"quantity mismatch: actual is {sorted(sa)}, candidate is {sorted(sc)}")
        return ka, qa
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
                            "actual_meta": record_meta(actual), "virtual_meta": record_meta(candidate),
                            "actual_is_virtual": is_virtual(actual), "virtual_is_virtual": is_virtual(candidate)}
    if kind == "spectrum":
        if channels == "auto":
            chans = ["reflectance"]
            both = [x for r in (actual, candidate) for x in (r if isinstance(r, tuple) else (r,))]
            if any(np.any(np.asarray(x.transmittance) != 0) for x in both):
                chans.append("transmittance")
        else:
            chans = list(channels)
            bad = set(chans) - {"reflectance", "transmittance"}
            if bad:
                raise InputError(f"spectrum channels are 'reflectance' and 'transmittance', got {sorted(bad)}")
        meta["channels"] = chans
        meta["geometry"] = (", ".join(sorted({str(x.geometry) for x in actual})) if isinstance(actual, tuple)
                            else str(actual.geometry))
        a, c = _spectra_long(actual, chans), _spectra_long(candidate, chans)
        pairs, unmatched = _align_keyed(a, c, angle_tol_deg, wavelength_tol_nm, "none", warnings, meta)
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
        pairs, unmatched = _align_keyed(a, c, angle_tol_deg, wavelength_tol_nm, how, warnings, meta)
    if pairs.empty:
        reasons = unmatched[unmatched.side == "actual"].reason.value_counts().head(3)
        detail = "; ".join(f"{n} x {r}" for r, n in reasons.items()) or "the actual record is empty"
        raise NoOverlapError(f"no actual point has a counterpart in the candidate record: {detail}")
    pairs = _drop_repeats(pairs, warnings)
    _refuse_missing(pairs)
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


def _drop_repeats(pairs: pd.DataFrame, warnings: list[str]) -> pd.DataFrame:
    """One observation per repeated sample: a resampled record (a Zemax grid, whose nodes take
    the value of the patch containing them) says which measured sample each row repeats (its
    ``sample`` column); pairs of the same actual sample and the same candidate sample (or row)
    at one incidence and wavelength are one observation, kept once."""
    if pairs.empty or not pairs.actual_sample.notna().any():
        return pairs
    cand = pairs.virtual_sample.where(pairs.virtual_sample.notna(), pairs.virtual_index.astype(float))
    key = pd.DataFrame({"c": pairs.channel, "w": pairs.wavelength_nm, "t": pairs.theta_i, "p": pairs.phi_i,
                        "a": pairs.actual_sample.where(pairs.actual_sample.notna(), -1.0 - np.arange(len(pairs))),
                        "v": cand})
    dup = key.duplicated().to_numpy()
    if dup.any():
        warnings.append(f"{int(dup.sum())} pairs repeat a sample already compared (a resampled record, e.g. "
                        f"Zemax nodes inside one patch): counted once")
        pairs = pairs[~dup].reset_index(drop=True)
    return pairs


def _key_values(df: pd.DataFrame, k: str) -> list[Any]:
    return sorted({v for v in df[k] if v is not None and not (isinstance(v, float) and math.isnan(v))}, key=str)


def _align_keyed(a: pd.DataFrame, c: pd.DataFrame, angle_tol: float, wl_tol: float, how: str,
                 warnings: list[str], meta: dict[str, Any]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Split both long tables by the identity keys that distinguish rows (see the module
    docstring), align each actual key group with the candidate rows of the same key values."""
    keys = [k for k in MATCH_KEYS if len(_key_values(a, k)) > 1 or len(_key_values(c, k)) > 1]
    meta["match_keys"] = keys
    if not keys:
        pairs, unmatched = _align_groups(a, c, angle_tol, wl_tol, how, warnings)
        return pairs, unmatched
    missing_in_c = [k for k in keys if not _key_values(c, k)]
    if missing_in_c:
        raise NoOverlapError(f"the candidate record has no {', '.join(missing_in_c)} column, but the actual record "
                             f"holds several values of it ({', '.join(f'{k}: {_key_values(a, k)}' for k in missing_in_c)}); "
                             f"cannot tell which candidate rows to compare")
    fa, fc = a[keys].astype(str), c[keys].astype(str)
    ca = fc.agg("\x1f".join, axis=1)
    all_pairs, all_unmatched, absent = [], [], []
    seen: set[str] = set()
    for kv, ga in a.groupby(fa.agg("\x1f".join, axis=1), sort=True):
        seen.add(kv)
        cg = c[ca == kv]
        label = ", ".join(f"{k}={v}" for k, v in zip(keys, kv.split("\x1f")))
        if cg.empty:
            absent.append(label)
            all_unmatched.append(_miss_frame(ga, f"candidate has no rows with {label}"))
            continue
        p, u = _align_groups(ga, cg, angle_tol, wl_tol, how, warnings)
        all_pairs.append(p)
        all_unmatched.append(u)
    for kv, gc in c.groupby(ca, sort=True):
        if kv not in seen:
            label = ", ".join(f"{k}={v}" for k, v in zip(keys, kv.split("\x1f")))
            all_unmatched.append(pd.DataFrame([{"side": "candidate", "reason": f"no actual rows with {label} "
                                                f"({len(gc)} values)", **dict(zip(keys, kv.split("\x1f")))}],
                                              columns=UNMATCHED_COLUMNS))
    pairs = [p for p in all_pairs if len(p)]
    if not pairs:
        raise NoOverlapError(f"the candidate matches no key of the actual record: missing {'; '.join(absent[:6])}"
                             + (f" (and {len(absent) - 6} more)" if len(absent) > 6 else "")
                             if absent else "no actual point has a counterpart in the candidate record")
    if absent:
        warnings.append(f"the candidate has no rows for {len(absent)} key group(s) of the actual record: "
                        f"{'; '.join(absent[:4])}")
    unm = [u for u in all_unmatched if len(u)]
    return (pd.concat(pairs, ignore_index=True)[PAIR_COLUMNS],
            pd.concat(unm, ignore_index=True)[UNMATCHED_COLUMNS] if unm else pd.DataFrame(columns=UNMATCHED_COLUMNS))


def _miss_frame(sub: pd.DataFrame, reason: str) -> pd.DataFrame:
    f = sub[["specimen", "collector", "geometry", "channel", "wavelength_nm", "theta_i", "phi_i", "theta_r",
             "phi_r"]].copy()
    f.insert(0, "side", "actual")
    f["reason"] = reason
    return f[UNMATCHED_COLUMNS].reset_index(drop=True)


def _align_groups(a: pd.DataFrame, c: pd.DataFrame, angle_tol: float, wl_tol: float, how: str,
                  warnings: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    rows: list[pd.DataFrame] = []
    unmatched: list[dict[str, Any]] = []
    used_groups: set[tuple[float, float, float]] = set()
    spectral = how == "none"

    def miss(sub: pd.DataFrame, reason: str) -> None:
        for r in sub.itertuples(index=False):
            unmatched.append({"side": "actual", "specimen": r.specimen, "collector": r.collector,
                              "geometry": r.geometry, "channel": r.channel, "wavelength_nm": r.wavelength_nm,
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
                vsample = np.full(len(gw), np.nan)
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
                    if wc == weights[0][0]:
                        vsample = cw["sample"].to_numpy(float)[safe]
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
                    "specimen": g.specimen.to_numpy(), "collector": g.collector.to_numpy(),
                    "geometry": g.geometry.to_numpy(), "quantity": g.quantity.to_numpy(),
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
                    "virtual_std_source": srcs[ok], "actual_sample": g["sample"].to_numpy(float),
                    "virtual_sample": vsample[ok],
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
