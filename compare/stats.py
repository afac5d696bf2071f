"""Discrepancy statistics between an actual record and a virtual (candidate) one.

Definitions (``a`` actual, ``v`` virtual, ``d = v - a``; sums over compared points)
-----------------------------------------------------------------------------------
mean_abs_discrepancy_pct  mean of ``100 |d| / |a|`` over points with ``a != 0``; points with a
                          zero reference are excluded from this metric only, counted in
                          ``n_reference_zero`` and named in ``warnings``.
rmse, bias, max_abs       ``sqrt(mean d^2)``, ``mean d``, ``max |d|`` (record units).
u_c                       combined standard uncertainty of ``d``:
                          ``sqrt(u_inst^2 + s_v^2 + s_a^2)`` with ``u_inst`` the instrument's
                          standard uncertainty (absolute, e.g. 0.005 for a spectrophotometer,
                          seed 3.1.1; or relative to ``|a|``, e.g. 0.5 % for a goniophotometer,
                          seed 3.2.1), ``s_v`` the Monte Carlo standard error of the virtual
                          value and ``s_a`` the actual's own std when it has one.
z                         ``d / u_c``. Points where both values are exactly 0 carry no
                          information and are left out of z, chi-square and the fraction
                          (``n_both_zero``); points with ``u_c = 0`` and ``d != 0`` have no z
                          (``n_no_uncertainty``, a warning).
chi2, dof, p_value        ``sum z^2``, the number of z's (no fitted parameters),
                          ``scipy.stats.chi2.sf(chi2, dof)``. When the actual record carries GUM
                          budgets (a calibrated scan, :mod:`bench.core.budget`), ``chi2 = d^T C^-1 d``
                          with ``C`` the full covariance of the differences: the actual readings'
                          (shared inputs such as the white standard's certificate counted once for
                          the run, not once per point) plus the virtual std^2 on the diagonal
                          (Cholesky solve); ``z`` stays ``d / sqrt(C_ii)``, and the instrument term
                          is the budget itself (no default 0.5 % on top).
fraction_within           fraction of ``|z| <= k`` (default k = 2) with its nominal value
                          ``erf(k / sqrt 2)`` for a correct uncertainty model and the
                          3-sigma binomial band around it for this many points.
bland_altman              bias ``mean d``, limits ``bias +- 1.96 sd(d)`` (sample sd, ddof 1).
delta_e2000               CIEDE2000 between the colours of the actual and virtual reflectance
                          (and transmittance) spectra: colour-science ``sd_to_XYZ`` (ASTM E308)
                          -> ``XYZ_to_Lab`` (white of the same illuminant and observer) ->
                          ``delta_E(method="CIE 2000")``; default D65 and CIE 1931 2 deg.

Nothing is reported as a silent NaN: metrics that cannot be formed are ``None`` with a warning
saying why, and chi-square without any uncertainty raises :class:`UncertaintyError` unless
``allow_missing_uncertainty=True``.
"""

from __future__ import annotations

import math
import warnings as _warnings
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from bench.core.errors import InputError

from compare.align import Aligned, align
from compare._covariance import (BUDGET_SOURCE, UncertaintyError, actual_budgets, chi_square, pair_covariance,
                                sub_covariance)

__all__ = [
    "UncertaintyError", "UncertaintyModel", "Comparison", "compare", "point_table", "summarize",
    "default_uncertainty", "nominal_fraction", "fraction_band", "bland_altman", "delta_e2000",
    "spectrum_lab", "rank", "SUMMARY_KEYS", "RANK_METRICS", "SPECTRO_UNCERTAINTY", "GONIO_UNCERTAINTY",
    "DEFAULT_ILLUMINANT", "DEFAULT_OBSERVER",
]

SPECTRO_UNCERTAINTY = 0.005  # absolute, reflectance units (seed 3.1.1)
GONIO_UNCERTAINTY = 0.005  # relative, 0.5 % (seed 3.2.1)
DEFAULT_ILLUMINANT = "D65"
DEFAULT_OBSERVER = "CIE 1931 2 Degree Standard Observer"

SUMMARY_KEYS = ("n_points", "mean_abs_discrepancy_pct", "rmse", "bias", "max_abs", "chi2", "dof", "p_value",
                "chi2_per_dof", "fraction_within_uncertainty", "k", "nominal_fraction", "fraction_band",
                "bland_altman", "n_reference_zero", "n_both_zero", "n_no_uncertainty", "warnings")

#: metrics a ranking can sort by; all "lower is better" (bias by its absolute value)
RANK_METRICS = ("chi2_per_dof", "mean_abs_discrepancy_pct", "rmse", "abs_bias", "max_abs", "delta_e2000_mean")


@dataclass(frozen=True)
class UncertaintyModel:
    """How the combined standard uncertainty of a difference is formed.

    ``instrument`` is the actual instrument's standard uncertainty, ``kind`` ``"absolute"`` (record
    units) or ``"relative"`` (fraction of ``|actual|``); ``source`` says where it came from.
    """

    instrument: float
    kind: str = "absolute"
    source: str = ""
    use_actual_std: bool = True
    use_virtual_std: bool = True

    def __post_init__(self) -> None:
        if self.kind not in ("absolute", "relative"):
            raise InputError(f"instrument uncertainty kind must be 'absolute' or 'relative', got {self.kind!r}")
        if not (math.isfinite(self.instrument) and self.instrument >= 0):
            raise InputError(f"instrument uncertainty must be finite and >= 0, got {self.instrument}")

    def as_dict(self) -> dict[str, Any]:
        return {"instrument": self.instrument, "kind": self.kind, "source": self.source,
                "use_actual_std": self.use_actual_std, "use_virtual_std": self.use_virtual_std}


def default_uncertainty(aligned: Aligned) -> UncertaintyModel:
    """The instrument term the actual record calls for.

    * ``meta["instrument_uncertainty"]`` (and ``meta["instrument_uncertainty_kind"]``) of the
      actual record when present;
    * a virtual actual record (a Monte Carlo stand-in): 0 -- its Monte Carlo std is its whole
      uncertainty;
    * otherwise the seed's figures: 0.005 absolute for spectra (3.1.1), 0.5 % relative for BSDF
      records (3.2.1).
    """
    m = aligned.meta.get("actual_meta", {})
    if m.get("instrument_uncertainty") is not None:
        kind = str(m.get("instrument_uncertainty_kind", "absolute" if aligned.kind == "spectrum" else "relative"))
        return UncertaintyModel(float(m["instrument_uncertainty"]), kind, "actual record's metadata")
    if aligned.meta.get("actual_is_virtual"):
        return UncertaintyModel(0.0, "absolute", "actual record is virtual: its Monte Carlo std is its whole "
                                                 "uncertainty (no instrument term)")
    if aligned.kind == "spectrum":
        return UncertaintyModel(SPECTRO_UNCERTAINTY, "absolute",
                                "spectrophotometer default: 0.005 absolute (seed 3.1.1)")
    return UncertaintyModel(GONIO_UNCERTAINTY, "relative", "goniophotometer default: 0.5 % relative (seed 3.2.1)")


def nominal_fraction(k: float) -> float:
    """P(|Z| <= k) for a standard normal Z: the fraction within k sigma a correct model gives."""
    return math.erf(k / math.sqrt(2.0))


def fraction_band(k: float, n: int, width: float = 3.0) -> tuple[float, float]:
    """``nominal +- width * sqrt(p(1-p)/n)``: the binomial band the observed fraction of ``n``
    independent points falls in with probability ~0.997 (width 3) when the model is right."""
    p = nominal_fraction(k)
    h = width * math.sqrt(p * (1 - p) / max(n, 1))
    return max(0.0, p - h), min(1.0, p + h)


def _f(x: Any) -> float | None:
    """A finite float or None (never NaN/inf in a summary)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def point_table(aligned: Aligned, model: UncertaintyModel, k: float = 2.0) -> pd.DataFrame:
    """Per-point discrepancies: the aligned pairs plus ``diff``, ``abs_diff``, ``rel_pct``,
    ``reference_zero``, ``u_instrument``, ``u_combined``, ``z``, ``z_note`` and ``within``.

    ``rel_pct`` is NaN exactly where ``reference_zero`` is True; ``z`` is NaN exactly where
    ``z_note`` says why (``"both zero"``, ``"identical"`` -- equal values and no uncertainty,
    ``"no uncertainty"``).
    """
    p = aligned.pairs.copy()
    a = p.actual_value.to_numpy(float)
    v = p.virtual_value.to_numpy(float)
    d = v - a
    p["diff"] = d
    p["abs_diff"] = np.abs(d)
    ref0 = a == 0
    p["reference_zero"] = ref0
    with np.errstate(divide="ignore", invalid="ignore"):
        p["rel_pct"] = np.where(ref0, np.nan, 100.0 * d / np.abs(np.where(ref0, 1.0, a)))
    u_inst = np.full(a.shape, model.instrument) if model.kind == "absolute" else model.instrument * np.abs(a)
    sa = p.actual_std.to_numpy(float) if model.use_actual_std else np.zeros_like(a)
    sv = p.virtual_std.to_numpy(float) if model.use_virtual_std else np.zeros_like(a)
    p["u_instrument"] = u_inst
    p["actual_std_missing"] = ~np.isfinite(sa)
    p["virtual_std_missing"] = ~np.isfinite(sv)
    uc = np.sqrt(u_inst ** 2 + np.nan_to_num(sa, nan=0.0) ** 2 + np.nan_to_num(sv, nan=0.0) ** 2)
    p["u_combined"] = uc
    both0 = (a == 0) & (v == 0)
    same = ~both0 & (d == 0) & ~(uc > 0)  # equal values without uncertainty: no information either
    nou = ~both0 & ~same & ~(uc > 0)
    note = np.where(both0, "both zero", np.where(same, "identical", np.where(nou, "no uncertainty", "")))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(note == "", d / np.where(uc > 0, uc, 1.0), np.nan)
    p["z"] = z
    p["z_note"] = note
    p["within"] = np.where(note == "", np.abs(np.nan_to_num(z, nan=np.inf)) <= k, False)
    return p


def bland_altman(actual: np.ndarray, virtual: np.ndarray) -> dict[str, float | None]:
    """Bland-Altman agreement of ``virtual - actual``: ``bias``, ``sd``, ``lower``, ``upper``
    (``bias -+ 1.96 sd``, sample sd) and ``n``; sd and limits are None for fewer than 2 points."""
    d = np.asarray(virtual, float) - np.asarray(actual, float)
    if d.size == 0:
        return {"bias": None, "sd": None, "lower": None, "upper": None, "n": 0}
    bias = float(d.mean())
    if d.size < 2:
        return {"bias": bias, "sd": None, "lower": None, "upper": None, "n": int(d.size)}
    sd = float(d.std(ddof=1))
    return {"bias": bias, "sd": sd, "lower": bias - 1.96 * sd, "upper": bias + 1.96 * sd, "n": int(d.size)}


def summarize(points: pd.DataFrame, k: float = 2.0, *, allow_missing_uncertainty: bool = False,
              label: str = "", covariance: np.ndarray | None = None) -> dict[str, Any]:
    """The stable summary (:data:`SUMMARY_KEYS`) of a per-point table from :func:`point_table`;
    chi-square with ``covariance`` (of the differences, rows as ``points``) when given.

    Raises
    ------
    UncertaintyError
        when no point has a usable combined uncertainty (chi-square impossible) and
        ``allow_missing_uncertainty`` is False.
    """
    w: list[str] = []
    where = f" ({label})" if label else ""
    n = int(len(points))
    out: dict[str, Any] = {key: None for key in SUMMARY_KEYS}
    out.update({"n_points": n, "k": float(k), "nominal_fraction": nominal_fraction(k), "warnings": w})
    if n == 0:
        w.append(f"no points{where}")
        out.update({"n_reference_zero": 0, "n_both_zero": 0, "n_no_uncertainty": 0,
                    "bland_altman": bland_altman(np.array([]), np.array([]))})
        return out
    d = points["diff"].to_numpy(float)
    ref0 = points.reference_zero.to_numpy(bool)
    out["n_reference_zero"] = int(ref0.sum())
    if ref0.any():
        w.append(f"{int(ref0.sum())} points with a zero reference value excluded from the % discrepancy{where}")
    rel = points.rel_pct.to_numpy(float)[~ref0]
    out["mean_abs_discrepancy_pct"] = _f(np.mean(np.abs(rel))) if rel.size else None
    if not rel.size:
        w.append(f"mean_abs_discrepancy_pct undefined: every reference value is zero{where}")
    out["rmse"] = _f(np.sqrt(np.mean(d ** 2)))
    out["bias"] = _f(np.mean(d))
    out["max_abs"] = _f(np.max(np.abs(d)))
    for side in ("actual", "virtual"):
        miss = int(points[f"{side}_std_missing"].sum()) if f"{side}_std_missing" in points else 0
        if miss:
            w.append(f"{side} std missing for {miss} of {n} points: left out of the combined uncertainty{where}")
    note = points.z_note.to_numpy(object)
    out["n_both_zero"] = int((note == "both zero").sum())
    out["n_no_uncertainty"] = int((note == "no uncertainty").sum())
    if out["n_both_zero"]:
        w.append(f"{out['n_both_zero']} points are zero in both records: no information, left out of z, "
                 f"chi-square and the fraction within uncertainty{where}")
    zmask = note == ""
    if out["n_no_uncertainty"]:
        msg = (f"{out['n_no_uncertainty']} points have no uncertainty (combined u = 0 with a non-zero "
               f"difference): no z-score{where}")
        w.append(msg)
    z = points.z.to_numpy(float)[zmask]
    if z.size == 0:
        msg = (f"chi-square impossible{where}: no point has a non-zero combined uncertainty "
               f"(give the instrument uncertainty or records with std)")
        if out["n_both_zero"] == n:
            w.append(f"chi-square undefined{where}: every point is zero in both records")
        elif int(np.isin(note, ["both zero", "identical"]).sum()) == n:
            w.append(f"chi-square undefined{where}: the records hold identical values without uncertainty")
        elif not allow_missing_uncertainty:
            raise UncertaintyError(msg)
        else:
            w.append(msg)
    else:
        if covariance is None:
            chi2 = float(np.sum(z ** 2))
        else:
            chi2 = chi_square(d[zmask], covariance[np.ix_(zmask, zmask)])
        from scipy.stats import chi2 as chi2_dist

        out["chi2"] = chi2
        out["dof"] = int(z.size)
        out["p_value"] = float(chi2_dist.sf(chi2, z.size))
        out["chi2_per_dof"] = chi2 / z.size
        out["fraction_within_uncertainty"] = float(np.mean(np.abs(z) <= k))
        out["fraction_band"] = list(fraction_band(k, int(z.size)))
    out["bland_altman"] = bland_altman(points.actual_value.to_numpy(float), points.virtual_value.to_numpy(float))
    if n < 2:
        w.append(f"Bland-Altman limits need at least 2 points{where}")
    return out


def _grouped(points: pd.DataFrame, by: Sequence[str], k: float, covariance: np.ndarray | None = None) -> pd.DataFrame:
    rows = []
    for key, g in points.groupby(list(by), sort=True, dropna=False):
        s = summarize(g, k, allow_missing_uncertainty=True, covariance=sub_covariance(points, g, covariance))
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        for name in ("n_points", "mean_abs_discrepancy_pct", "rmse", "bias", "max_abs", "chi2", "dof",
                     "p_value", "fraction_within_uncertainty", "n_reference_zero"):
            row[name] = s[name]
        ba = s["bland_altman"]
        row.update({"ba_bias": ba["bias"], "ba_lower": ba["lower"], "ba_upper": ba["upper"]})
        rows.append(row)
    return pd.DataFrame(rows)


# --- colour -------------------------------------------------------------------------------


def spectrum_lab(wavelengths: np.ndarray, values: np.ndarray, illuminant: str = DEFAULT_ILLUMINANT,
                 observer: str = DEFAULT_OBSERVER) -> tuple[np.ndarray, list[str]]:
    """CIELAB of a reflectance (or transmittance) spectrum, and notes on what was done.

    colour-science's ASTM E308 method needs a 1/5/10/20 nm grid: other grids are interpolated
    linearly onto a 5 nm grid inside their range first (noted). XYZ is scaled to [0, 1] (Y of the
    perfect diffuser = 1) for ``XYZ_to_Lab`` with the illuminant's white under the same observer
    (``CCS_ILLUMINANTS``) when the spectrum spans 360-780 nm, else the white of the perfect
    diffuser weighted over the same trimmed range (so a flat spectrum stays neutral).
    """
    import colour

    notes: list[str] = []
    wl = np.asarray(wavelengths, float)
    v = np.asarray(values, float)
    order = np.argsort(wl, kind="stable")
    wl, v = wl[order], v[order]
    steps = np.diff(wl)
    uniform = steps.size > 0 and np.allclose(steps, steps[0]) and any(np.isclose(steps[0], s) for s in (1, 5, 10, 20))
    if not uniform:
        grid = np.arange(math.ceil(wl[0] / 5) * 5, wl[-1] + 1e-9, 5.0)
        v = np.interp(grid, wl, v)
        wl = grid
        notes.append("spectrum interpolated linearly onto a 5 nm grid for ASTM E308 weighting")
    trimmed = bool(wl[0] > 360 or wl[-1] < 780)
    if trimmed:
        notes.append(f"spectrum covers {wl[0]:g}-{wl[-1]:g} nm: colour-science trims the CMFs and illuminant "
                     f"to this range; the white point is computed over the same range")
    cmfs = colour.MSDS_CMFS[observer]
    illum = colour.SDS_ILLUMINANTS[illuminant]
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        xyz = colour.sd_to_XYZ(colour.SpectralDistribution(v, wl), cmfs, illum) / 100.0
        if trimmed:
            # the white of the same (trimmed) weighting, so that a flat spectrum stays neutral
            white = colour.XYZ_to_xy(colour.sd_to_XYZ(colour.SpectralDistribution(np.ones_like(v), wl), cmfs, illum))
        else:
            white = colour.CCS_ILLUMINANTS[observer][illuminant]
    return np.asarray(colour.XYZ_to_Lab(xyz, white), float), notes


def delta_e2000(wavelengths: np.ndarray, reference: np.ndarray, test: np.ndarray,
                illuminant: str = DEFAULT_ILLUMINANT, observer: str = DEFAULT_OBSERVER) -> dict[str, Any]:
    """CIEDE2000 between two spectra on the same wavelengths: ``{"delta_e2000", "lab_actual",
    "lab_virtual", "illuminant", "observer", "notes"}``."""
    import colour

    if len(wavelengths) < 3:
        raise InputError(f"CIEDE2000 needs a spectrum of at least 3 wavelengths, got {len(wavelengths)}")
    lab_a, notes = spectrum_lab(wavelengths, reference, illuminant, observer)
    lab_v, _ = spectrum_lab(wavelengths, test, illuminant, observer)
    de = float(colour.delta_E(lab_a, lab_v, method="CIE 2000"))
    return {"delta_e2000": de, "lab_actual": lab_a.tolist(), "lab_virtual": lab_v.tolist(),
            "illuminant": illuminant, "observer": observer, "notes": notes}


# --- the comparison ----------------------------------------------------------------------


@dataclass
class Comparison:
    """One candidate against the actual record: the alignment, per-point table, summaries."""

    name: str
    aligned: Aligned
    points: pd.DataFrame
    summary: dict[str, Any]
    by_wavelength: pd.DataFrame
    by_incidence: pd.DataFrame
    uncertainty: UncertaintyModel
    colour: dict[str, Any] = field(default_factory=dict)
    by_group: pd.DataFrame = field(default_factory=pd.DataFrame)
    covariance: np.ndarray | None = None  # of the differences, when the actual record has GUM budgets
    budgets: list[Any] | None = None  # the actual readings' budgets, as the points


def compare(actual: Any, candidate: Any, *, name: str = "candidate", k: float = 2.0,
            instrument_uncertainty: float | None = None, instrument_uncertainty_kind: str | None = None,
            allow_missing_uncertainty: bool = False, illuminant: str = DEFAULT_ILLUMINANT,
            observer: str = DEFAULT_OBSERVER, aligned: Aligned | None = None,
            **align_kwargs: Any) -> Comparison:
    """Align ``candidate`` to ``actual`` and compute every discrepancy statistic.

    Parameters
    ----------
    actual, candidate : BSDFRecord or Spectrum
    name : the candidate's name in summaries and rankings
    k : coverage factor for the fraction within uncertainty (nominal ``erf(k/sqrt 2)``)
    instrument_uncertainty, instrument_uncertainty_kind : float, ``"absolute"``/``"relative"``
        the actual instrument's standard uncertainty; default :func:`default_uncertainty`.
    allow_missing_uncertainty : report chi-square as None with a warning instead of raising
        :class:`UncertaintyError` when no uncertainty can be formed.
    illuminant, observer : colour-science names for CIEDE2000 (spectra only)
    aligned : a precomputed :class:`Aligned` (then ``align_kwargs`` are ignored)
    **align_kwargs : passed to :func:`compare.align.align` (``angle_tol_deg``,
        ``wavelength_tol_nm``, ``match``, ``channels``)

    Returns
    -------
    Comparison
        ``summary`` has :data:`SUMMARY_KEYS` plus ``delta_e2000_mean`` (spectra; None for BSDF),
        ``delta_e2000`` (per channel), ``uncertainty_model``, ``n_unmatched``, ``quantity``.
    """
    if not (math.isfinite(k) and k > 0):
        raise InputError(f"k must be finite and > 0, got {k}")
    al = aligned if aligned is not None else align(actual, candidate, **align_kwargs)
    budgets = actual_budgets(actual, al.pairs)
    model = default_uncertainty(al) if budgets is None else UncertaintyModel(0.0, "relative", BUDGET_SOURCE)
    if instrument_uncertainty is not None:
        kind = instrument_uncertainty_kind or ("absolute" if al.kind == "spectrum" else "relative")
        model = UncertaintyModel(float(instrument_uncertainty), kind, "given by the caller")
    elif instrument_uncertainty_kind is not None and instrument_uncertainty_kind != model.kind:
        raise InputError("instrument_uncertainty_kind given without instrument_uncertainty")
    pts = point_table(al, model, k)
    cov = None if budgets is None else pair_covariance(pts, budgets, model)
    summary = summarize(pts, k, allow_missing_uncertainty=allow_missing_uncertainty, covariance=cov)
    summary["warnings"] = list(al.warnings) + summary["warnings"]
    if model.instrument == 0 and not al.meta.get("actual_is_virtual") and budgets is None:
        summary["warnings"].append("instrument uncertainty is 0: only the records' own std enter u_c")
    summary["uncertainty_model"] = model.as_dict()
    summary["n_unmatched"] = int((al.unmatched.side == "actual").sum())
    summary["quantity"] = al.quantity
    summary["kind"] = al.kind
    summary["delta_e2000_mean"] = None
    summary["delta_e2000"] = None
    colour_info: dict[str, Any] = {}
    if al.kind == "spectrum":
        per: dict[str, float] = {}
        per_group: list[dict[str, Any]] = []
        keys = [c for c in ("specimen", "geometry") if pts[c].notna().any() and pts[c].nunique() > 1]
        for key, g in pts.groupby(["specimen", "geometry", "channel"], sort=False, dropna=False):
            label = " ".join(str(v) for c, v in zip(("specimen", "geometry", "channel"), key)
                             if c == "channel" or c in keys)
            g = g.sort_values("wavelength_nm", kind="stable")
            try:
                res = delta_e2000(g.wavelength_nm.to_numpy(), g.actual_value.to_numpy(), g.virtual_value.to_numpy(),
                                  illuminant, observer)
            except (InputError, KeyError, ValueError) as exc:
                summary["warnings"].append(f"CIEDE2000 not computed for {label}: {exc}")
                continue
            per[label] = res["delta_e2000"]
            per_group.append({"specimen": key[0], "geometry": key[1], "channel": key[2],
                              "delta_e2000": res["delta_e2000"]})
            colour_info[label] = res
            summary["warnings"].extend(f"CIEDE2000 ({label}): {n}" for n in res["notes"])
        if per:
            summary["delta_e2000"] = per
            summary["delta_e2000_mean"] = float(np.mean(list(per.values())))
            summary["delta_e2000_max"] = float(np.max(list(per.values())))
            summary["delta_e2000_groups"] = per_group
            summary["colour"] = {"illuminant": illuminant, "observer": observer}
    summary["covariance"] = "full (GUM budgets)" if cov is not None else "diagonal"
    by_wl = _grouped(pts, ["channel", "wavelength_nm"], k, cov)
    by_inc = _grouped(pts, ["channel", "theta_i", "phi_i"], k, cov) if al.kind == "bsdf" else pd.DataFrame()
    by_group = _grouped(pts, group_keys(pts, al.kind), k, cov)
    return Comparison(name=name, aligned=al, points=pts, summary=summary, by_wavelength=by_wl, by_incidence=by_inc,
                      uncertainty=model, colour=colour_info, by_group=by_group, covariance=cov, budgets=budgets)


def group_keys(points: pd.DataFrame, kind: str) -> list[str]:
    """The columns a verdict is given per: the identity keys that vary, then the incidence and
    wavelength (BSDF) or the CIE geometry (spectra; one group per specimen and geometry)."""
    ident = [c for c in ("specimen", "collector") if c in points and points[c].nunique(dropna=True) > 1]
    if kind == "spectrum":
        return ident + ["geometry", "channel"]
    return ident + ["theta_i", "phi_i", "wavelength_nm"]


def rank(summaries: Mapping[str, Mapping[str, Any]], primary: str = "chi2_per_dof") -> list[dict[str, Any]]:
    """Order candidates by ``primary`` (lower is better; :data:`RANK_METRICS`), the other metrics
    alongside. Candidates whose primary metric is None come last, with ``rank`` None and a note."""
    if primary not in RANK_METRICS:
        raise InputError(f"primary metric must be one of {', '.join(RANK_METRICS)}, got {primary!r}")

    def metric(s: Mapping[str, Any], m: str) -> float | None:
        if m == "abs_bias":
            return None if s.get("bias") is None else abs(float(s["bias"]))
        return _f(s.get(m))

    rows: list[dict[str, Any]] = []
    for name, s in summaries.items():
        row: dict[str, Any] = {"name": name, "primary": primary, "primary_value": metric(s, primary)}
        for m in RANK_METRICS:
            row[m] = metric(s, m)
        row["p_value"] = _f(s.get("p_value"))
        row["fraction_within_uncertainty"] = _f(s.get("fraction_within_uncertainty"))
        row["n_points"] = s.get("n_points")
        rows.append(row)
    ranked = sorted((r for r in rows if r["primary_value"] is not None), key=lambda r: r["primary_value"])
    missing = [r for r in rows if r["primary_value"] is None]
    for i, r in enumerate(ranked, 1):
        r["rank"] = i
        r["note"] = ""
    for r in missing:
        r["rank"] = None
        r["note"] = f"{primary} not available"
    return ranked + missing
