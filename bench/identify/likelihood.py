"""Likelihoods of a record under a candidate specimen, as residual vectors.

Every likelihood here returns residuals ``r(specimen)`` whose sum of squares is ``-2 log L``
up to a constant that does not depend on the model, so a least-squares minimizer finds the
maximum-likelihood estimate and differences of ``sum(r**2)`` are likelihood-ratio statistics:

* **virtual counts** (:class:`GonioCounts`, :class:`SpectroCounts`): the counts of a virtual
  record are one multinomial draw per (incidence, wavelength) over the collector's bins plus
  "absorbed" (a goniophotometer), or over reflected / transmitted / absorbed (a
  spectrophotometer with hemispherical collection). The residuals are the deviance residuals
  ``sign(k - m) sqrt(2 (k ln(k/m) - (k - m)))``, ``m = N p``; with the probabilities summing to
  one, ``sum(r**2)`` is the multinomial deviance ``2 sum k ln(k / (N p))``. The probabilities
  come from the certified fast path -- the goniophotometer's own
  :meth:`~virtual.goniophotometer.VirtualGoniophotometer.bin_probabilities` once
  :meth:`~virtual.goniophotometer.VirtualGoniophotometer.fast_path_for` certifies them (a fit
  searches with the certificate deferred -- the same first quadrature attempt without its
  independent albedo, nine tenths of the cost -- and certifies at its optimum, :meth:`certify`), the
  specimen's directional (R, T) for a spectrophotometer -- and, where that cannot be certified
  (a conical beam, a gloss trap, a density the quadrature cannot bound), from rays counted with
  common random numbers (one fixed seed for every evaluation, :data:`CRN_SEED`, and
  :data:`RAY_FACTOR` times the record's rays), so the likelihood surface stays smooth in the
  parameters;
* **calibrated readings** (:class:`GaussianReadings`): a scan's BSDF values or spectra with
  their uncertainties, ``r = L^-1 (y - model)`` with ``L L^T`` the readings' covariance from
  :func:`record_covariance` (the one place the covariance comes from) less the shared
  scales, which are fitted as nuisance parameters (:mod:`bench.identify.scales`), and ``model`` what
  the body read (:mod:`bench.identify.prediction`, the design's prediction too): the cone of the
  detector aperture the record's metadata gives, calibrated against the white read through the
  same cone, or the collector patch of a virtual body without an aperture.

The record's kind decides (:func:`likelihood_for`): integer counts with ray totals are
virtual counts, anything else is calibrated readings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Sequence, TypeAlias

import numpy as np

from bench.core.budget import readings_and_covariance
from bench.core.errors import InputError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from bench.identify.gof import ReadingNoise, reading_noise, type_a_dof
from bench.identify.prediction import (PATCH_BOUNDS, band_mean, cone_nodes, directional_rt, ideal_rf,
                                       patch_nodes, record_aperture, record_bands, virtual_body_patches,
                                       white_geometry)
from bench.identify.scales import SharedScales, split_scales
from virtual.beam import Beam
from virtual.collector import SCHEMES, Collector
from virtual.specimens import Specimen

if TYPE_CHECKING:  # annotations only: the goniophotometer (its kernels) is imported where a fit counts rays
    import pandas as pd

    from virtual.goniophotometer import VirtualGoniophotometer

__all__ = ["Likelihood", "GonioCounts", "SpectroCounts", "GaussianReadings", "likelihood_for",
           "record_covariance", "FitInput", "multinomial_residuals", "CRN_SEED", "RAY_FACTOR"]

#: what a fit takes: a BSDF record, or one or several spectra
FitInput: TypeAlias = "BSDFRecord | Spectrum | Sequence[Spectrum]"

#: the one seed of the rays counted where the fast path cannot certify (common random numbers)
CRN_SEED = 20261202
#: rays counted per evaluation, as a multiple of the record's rays, where the fast path cannot certify
RAY_FACTOR = 10
#: probabilities below this are raised to it (a count in a bin the model gives nothing stays finite)
P_FLOOR = 1e-15


def multinomial_residuals(k: np.ndarray, n: float, p: np.ndarray) -> np.ndarray:
    """Deviance residuals of counts ``k`` (every category, summing to ``n``) under
    probabilities ``p`` (floored at :data:`P_FLOOR` and renormalized): ``sum(r**2)`` is the
    multinomial deviance ``2 sum k ln(k / (n p))``."""
    p = np.maximum(np.asarray(p, float), P_FLOOR)
    m = n * (p / p.sum())
    k = np.asarray(k, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(k > 0, k * np.log(np.where(k > 0, k, 1.0) / m), 0.0) - (k - m)
    return np.sign(k - m) * np.sqrt(2.0 * np.maximum(term, 0.0))


@dataclass(frozen=True)
class Group:
    """One block of residuals for the residual figure: its label, slice and x coordinates."""

    label: str
    start: int
    stop: int
    x: np.ndarray


class Likelihood:
    """Base: ``residuals(specimen)`` (see the module docstring), ``n_data`` independent data,
    ``groups`` for the figure, ``kind`` ("multinomial" or "gaussian") and ``xlabel``."""

    kind = ""
    xlabel = ""
    groups: tuple[Group, ...] = ()
    #: evaluate without the fast path's certificate, to be checked at the optimum (:meth:`certify`)
    defer_certification = False
    #: set once an evaluation counted rays: the likelihood is then a step function of the
    #: parameters at the scale of single rays (the fit differentiates over wider steps)
    counted_rays = False

    def certify(self, specimen: Specimen) -> bool:
        """Whether what was evaluated with :attr:`defer_certification` is certified at ``specimen``."""
        return True

    def residuals(self, specimen: Specimen) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def n_data(self, specimen: Specimen) -> int:  # pragma: no cover - abstract
        """Independent data at ``specimen`` (the goodness of fit's dof is this less the free parameters)."""
        raise NotImplementedError


# --- virtual counts: goniophotometer ------------------------------------------------------


def _beam(meta: Mapping[str, Any]) -> Beam:
    b = meta.get("beam") or {"kind": "collimated"}
    if isinstance(b, str):
        return Beam(b)
    keep = ("kind", "emitter_radius_mm", "specimen_radius_mm", "distance_mm", "disk_sampling")
    return Beam(**{k: b[k] for k in keep if k in b})


def _collector(record: BSDFRecord) -> Collector:
    """The record's collector: from its metadata, else the scheme whose patch bounds match the
    table's (a CSV written without its metadata)."""
    c = record.meta.get("collector")
    if isinstance(c, dict) and {"scheme", "n_theta", "n_phi"} <= set(c):
        return Collector(c["scheme"], int(c["n_theta"]), int(c["n_phi"]))
    t = record.table
    if not {"theta_min", "theta_max", "phi_min", "phi_max"} <= set(t.columns):
        raise InputError("record: counts without a collector (no metadata and no patch bounds)")
    first = t[(t.wavelength_nm == t.wavelength_nm.iloc[0]) & (t.theta_i == t.theta_i.iloc[0])]
    r = first[first.hemisphere == "R"]
    n_theta = len(np.unique(np.round(r.theta_min.to_numpy(float), 4)))
    n_phi = max(1, len(r) // max(n_theta, 1))
    edges = np.unique(np.round(np.concatenate([r.theta_min, r.theta_max]).astype(float), 4))
    for scheme in SCHEMES:
        col = Collector(scheme, n_theta, n_phi)
        if col.n_patches == len(r) and np.allclose(np.degrees(col.theta_edges), edges, atol=1e-3):
            return col
    raise InputError(f"record: its {len(r)} patches match no collector scheme ({', '.join(SCHEMES)})")


class GonioCounts(Likelihood):
    """Multinomial counts of a virtual goniophotometric record (see the module docstring)."""

    kind = "multinomial"
    xlabel = "collector bin (R patches, T patches, absorbed)"

    def __init__(self, record: BSDFRecord) -> None:
        t = record.table
        for key in ("specimen", "collector", "quantity"):  # a sweep's record holds several measurements
            if key in t.columns and t[key].nunique(dropna=True) > 1:
                raise InputError(f"record holds several {key} values ({', '.join(map(str, t[key].unique()[:4]))}"
                                 f"...); fit one measurement: select its rows first")
        self.collector = _collector(record)
        self.beam = _beam(record.meta)
        col = self.collector
        nb = col.n_bins
        centres = col.centres_deg
        index = {(h, round(float(a), 3), round(float(b), 3) % 360.0): i
                 for i, (h, (a, b)) in enumerate(zip(np.where(np.arange(nb) < col.n_patches, "R", "T"), centres))}
        self.blocks: list[tuple[float, float, float, np.ndarray, int]] = []
        groups = []
        start = 0
        for (wl, ti, pi), g in t.groupby(["wavelength_nm", "theta_i", "phi_i"], sort=True):
            if len(g) != nb:
                raise InputError(f"record: theta_i = {ti:g} deg, {wl:g} nm has {len(g)} of the collector's {nb} "
                                 "bins; the counts' likelihood needs the whole sphere")
            k = np.zeros(nb + 1)
            for h, tr, pr, c in zip(g.hemisphere, g.theta_r, g.phi_r, g["count"]):
                i = index.get((str(h), round(float(tr), 3), round(float(pr), 3) % 360.0))
                if i is None:
                    raise InputError(f"record: patch ({h}, {tr:g}, {pr:g}) is not a bin of collector {col}")
                k[i] = float(c)
            n = float(g["N"].iloc[0])
            if not (math.isfinite(n) and n >= k.sum() > 0):
                raise InputError(f"record: ray total N = {n:g} at theta_i = {ti:g}, {wl:g} nm is below its counts")
            k[nb] = n - k[:nb].sum()  # absorbed
            self.blocks.append((float(wl), float(ti), float(pi), k, int(n)))
            groups.append(Group(f"theta_i {ti:g} deg, {wl:g} nm", start, start + nb + 1, np.arange(nb + 1)))
            start += nb + 1
        self.groups = tuple(groups)

    def _instrument(self, specimen: Specimen, wl: float, n: int) -> VirtualGoniophotometer:
        from virtual.goniophotometer import VirtualGoniophotometer

        return VirtualGoniophotometer(specimen, collector=self.collector, beam=self.beam, wavelengths=(wl,),
                                      rays=RAY_FACTOR * n, seed=CRN_SEED, common_random_numbers=True)

    def _deferred(self, specimen: Specimen, ti: float, pi: float, wl: float) -> np.ndarray | None:
        """The fast path's probabilities from the certification's first attempt, uncertified
        (``None`` where the fast path does not apply or that attempt fails)."""
        from bench.core.errors import SimulationError
        from virtual.goniophotometer import bin_probabilities
        from virtual.quadrature import CERTIFY_ATTEMPTS, integrate_patches

        if not (specimen.has_density and self.beam.kind == "collimated"):
            return None
        try:
            integrals = integrate_patches(specimen, Geometry(ti, pi, 0.0, 0.0).incident, self.collector, wl,
                                          **CERTIFY_ATTEMPTS[0])
        except SimulationError:
            return None
        return bin_probabilities(integrals)

    def probabilities(self, specimen: Specimen) -> list[np.ndarray]:
        """Per block, the probabilities of every bin and "absorbed": certified quadrature, else
        rays with common random numbers. Under :attr:`defer_certification` the quadrature's
        certificate (an independent albedo, 90 % of its cost) is skipped: :meth:`certify`
        checks it at the optimum."""
        nb = self.collector.n_bins
        out = []
        for wl, ti, pi, _k, n in self.blocks:
            p = self._deferred(specimen, ti, pi, wl) if self.defer_certification else None
            if p is None:
                g = self._instrument(specimen, wl, n)
                if g.fast_path_for(ti, pi, wl):
                    p = g.bin_probabilities(ti, pi, wl)
                else:  # rays: the fractions of those that reached the specimen (the record's N counts only these)
                    self.counted_rays = True
                    c = g.simulate(ti, pi, wl)[:nb + 1].astype(float)
                    p = c / max(c.sum(), 1.0)
            out.append(p[:nb + 1])
        return out

    def certify(self, specimen: Specimen) -> bool:
        """Whether the deferred probabilities at ``specimen`` are exactly the certified fast
        path's (its first attempt certified), so a fit found with them stands."""
        for wl, ti, pi, _k, n in self.blocks:
            p = self._deferred(specimen, ti, pi, wl)
            if p is None:
                continue  # evaluated the certified way already
            g = self._instrument(specimen, wl, n)
            if not (g.fast_path_for(ti, pi, wl) and np.array_equal(g.bin_probabilities(ti, pi, wl), p)):
                return False
        return True

    def residuals(self, specimen: Specimen) -> np.ndarray:
        return np.concatenate([multinomial_residuals(b[3], b[4], p)
                               for b, p in zip(self.blocks, self.probabilities(specimen))])

    def n_data(self, specimen: Specimen) -> int:
        return sum(int(np.count_nonzero((b[3] > 0) | (p > P_FLOOR))) - 1
                   for b, p in zip(self.blocks, self.probabilities(specimen)))


# --- virtual counts: spectrophotometer ----------------------------------------------------


def _spectra(record: Spectrum | Sequence[Spectrum]) -> tuple[Spectrum, ...]:
    return (record,) if isinstance(record, Spectrum) else tuple(record)


class SpectroCounts(Likelihood):
    """Multinomial (reflected, transmitted, absorbed) counts per wavelength of virtual spectra
    measured with hemispherical collection (see the module docstring)."""

    kind = "multinomial"
    xlabel = "wavelength (nm)"

    def __init__(self, record: Spectrum | Sequence[Spectrum]) -> None:
        self.spectra = _spectra(record)
        groups = []
        start = 0
        self.blocks = []
        for s in self.spectra:
            g = cie_geometry(s.geometry)
            measured = g.reciprocal_directional
            if measured.viewing != "diffuse":
                raise InputError(f"spectrum {s.geometry}: counts of a directional viewing geometry are fitted as "
                                 "calibrated readings, not counts")
            n = np.asarray(s.N, float)
            k_r = np.rint(np.asarray(s.reflectance, float) * n)
            k_t = np.rint(np.asarray(s.transmittance, float) * n)
            k = np.column_stack([k_r, k_t, n - k_r - k_t])
            beam = _beam(s.meta or {})
            self.blocks.append((g, measured, np.asarray(s.wavelengths, float), k, n, beam))
            m = len(n)  # residuals of a spectrum: its R block, T block, absorbed block (one per wavelength)
            for name, col in (("R", 0), ("T", 1), ("absorbed", 2)):
                groups.append(Group(f"{s.geometry} {name}", start + col * m, start + (col + 1) * m,
                                    np.asarray(s.wavelengths, float)))
            start += 3 * m
        self.groups = tuple(groups)

    def probabilities(self, specimen: Specimen) -> list[np.ndarray]:
        """Per spectrum, (n_wavelengths, 3) probabilities of reflected, transmitted, absorbed."""
        out = []
        for g, measured, wl, _k, n, beam in self.blocks:
            rt = None
            if beam.kind == "collimated" and measured.specular_included:
                rt = [directional_rt(specimen, measured.theta_i, float(w)) for w in wl]
            if rt is None or any(v is None for v in rt):
                from virtual.spectrophotometer import VirtualSpectrophotometer

                self.counted_rays = True
                rays = int(RAY_FACTOR * n.max())
                s = VirtualSpectrophotometer(specimen, rays=rays, beam=beam, seed=CRN_SEED,
                                             common_random_numbers=True).measure(g, wl)
                rt = list(zip(s.reflectance, s.transmittance))
            p = np.array(rt, dtype=float)
            out.append(np.column_stack([p, np.clip(1.0 - p.sum(axis=1), 0.0, 1.0)]))
        return out

    def residuals(self, specimen: Specimen) -> np.ndarray:
        parts = []
        for b, p in zip(self.blocks, self.probabilities(specimen)):
            k, n = b[3], b[4]
            r = np.array([multinomial_residuals(k[i], n[i], p[i]) for i in range(len(n))])
            parts.append(r.T.ravel())  # R block, T block, absorbed block
        return np.concatenate(parts)

    def n_data(self, specimen: Specimen) -> int:
        return sum(int(np.count_nonzero((b[3] > 0) | (p > P_FLOOR))) - len(b[4])
                   for b, p in zip(self.blocks, self.probabilities(specimen)))


# --- calibrated readings --------------------------------------------------------------------


def _z(delta: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(1.0 - delta / 2.0))


def reading_rows(record: FitInput) -> list[dict[str, Any]]:
    """The readings of a calibrated record, in the order of :func:`record_covariance`:
    one dict per reading with its quantity (``bsdf``, ``R``, ``T``, ``RF``), geometry,
    wavelength, value and standard uncertainty ``u``."""
    rows: list[dict[str, Any]] = []
    if isinstance(record, BSDFRecord):
        t = _measured(record)
        u = t["std"].to_numpy(float) if "std" in t.columns else np.full(len(t), np.nan)
        bounds = (np.array(t[list(PATCH_BOUNDS)].to_numpy(float)) if set(PATCH_BOUNDS) <= set(t.columns)
                  else np.full((len(t), 4), np.nan))
        missing = ~np.all(np.isfinite(bounds), axis=1)
        if missing.any():
            bounds[missing] = virtual_body_patches(record.meta, t["theta_r"].to_numpy(float)[missing],
                                                   t["phi_r"].to_numpy(float)[missing])
        for r, ui, b in zip(t.itertuples(index=False), u, bounds):
            rows.append({"quantity": "bsdf", "wavelength_nm": float(r.wavelength_nm), "theta_i": float(r.theta_i),
                         "phi_i": float(r.phi_i), "theta_r": float(r.theta_r), "phi_r": float(r.phi_r),
                         "value": float(r.value), "u": float(ui),
                         "patch": tuple(float(x) for x in b) if np.all(np.isfinite(b)) and b[1] != b[0] else None})
        return rows
    for s in _spectra(record):
        meta = s.meta or {}
        rf = str(meta.get("quantity", "")).lower() == "reflectance factor"
        for name, values, ci, std in (("R", s.reflectance, s.reflectance_ci, meta.get("reflectance_std")),
                                      ("T", s.transmittance, s.transmittance_ci, meta.get("transmittance_std"))):
            values = np.asarray(values, float)
            ci = np.asarray(ci, float).reshape(len(values), 2)
            if std is not None:
                u = np.asarray(std, float)
            elif math.isfinite(float(s.delta)) and 0 < float(s.delta) < 1:
                u = (ci[:, 1] - ci[:, 0]) / (2.0 * _z(float(s.delta)))
            else:
                u = np.full(len(values), np.nan)
            if name == "T" and not (np.any(values != 0) or np.any(u > 0)):
                continue  # a reflectance-only record (a scan's spectra)
            for w, v, ui in zip(s.wavelengths, values, u):
                rows.append({"quantity": "RF" if rf and name == "R" else name, "geometry": s.geometry,
                             "wavelength_nm": float(w), "value": float(v), "u": float(ui)})
    return rows


def _measured(record: BSDFRecord) -> pd.DataFrame:
    """The rows of a BSDF record that hold a reading: a masked reading (saturated, or refused by
    the calibration: its value NaN) carries no information and is left out, in table order."""
    t = record.table
    return t[np.isfinite(t["value"].to_numpy(float))]


def record_covariance(record: FitInput) -> tuple[np.ndarray, np.ndarray]:
    """The readings of a calibrated record and their covariance matrix, in the order of
    :func:`reading_rows`.

    A scan whose readings carry GUM budgets gets their full covariance
    (:func:`bench.core.budget.readings_and_covariance`: the white standard's term and the other
    inputs shared by the run's readings as correlations); other records ``diag(u**2)`` from
    their per-reading standard uncertainty.

    Raises
    ------
    InputError
        When a reading has no (finite, positive) uncertainty.
    """
    rows = reading_rows(record)
    if not rows:
        raise InputError("record has no readings to fit")
    if isinstance(record, BSDFRecord) and "uncertainty_budget" in record.table.columns:
        values, cov = readings_and_covariance(_measured(record))
        u2 = np.diag(cov)
    else:
        values = np.array([r["value"] for r in rows], dtype=float)
        u2 = np.array([r["u"] for r in rows], dtype=float) ** 2
        cov = np.diag(u2)
    bad = ~(np.isfinite(u2) & (u2 > 0))
    if bad.any():
        raise InputError(f"record has no uncertainty for a calibrated fit: {int(bad.sum())} of {len(u2)} readings "
                         "lack a finite positive standard uncertainty")
    return values, cov


class GaussianReadings(Likelihood):
    """Calibrated readings with their covariance (see the module docstring)."""

    kind = "gaussian"

    def __init__(self, record: FitInput) -> None:
        from scipy.linalg import cholesky

        self.rows = reading_rows(record)
        meta = record.meta if isinstance(record, BSDFRecord) else {}
        #: the detector's half-angle (deg) and where its white was read (the record's metadata)
        self.aperture_deg = record_aperture(meta)
        self.white = white_geometry(meta)
        #: each band's averaged wavelengths: a spectral specimen's band is their mean
        self.bands = record_bands(meta) or {}
        self._nodes: list[Any] | None = None
        self.values, cov = record_covariance(record)
        #: shared scales (white certificate, white reading, lamp drift) fitted, not in the covariance
        self.scales = SharedScales((), np.zeros((len(self.values), 0)))
        #: the covariance's parts and Type A dof, for the p-value (:mod:`bench.identify.gof`)
        self.noise: ReadingNoise | None = None
        if isinstance(record, BSDFRecord) and "uncertainty_budget" in record.table.columns:
            t = _measured(record)
            std = t["std"].to_numpy(float) if "std" in t.columns else np.full(len(t), np.nan)
            cov, self.scales = split_scales(list(t["uncertainty_budget"]), std)
            self.noise = reading_noise(list(t["uncertainty_budget"]), std,
                                       type_a_dof(meta, t["wavelength_nm"].to_numpy(float)))
        self.chol = cholesky(cov, lower=True)
        self.xlabel = "reading" if isinstance(record, BSDFRecord) else "wavelength (nm)"
        groups: list[Group] = []
        keys = [(r["quantity"], r.get("geometry"), r.get("theta_i"), r["wavelength_nm"] if r["quantity"] == "bsdf"
                 else None) for r in self.rows]
        i = 0
        while i < len(keys):
            j = i
            while j < len(keys) and keys[j] == keys[i]:
                j += 1
            q, geo, ti, wl = keys[i]
            label = f"theta_i {ti:g} deg, {wl:g} nm" if q == "bsdf" else f"{geo} {q}"
            x = np.arange(j - i) if q == "bsdf" else np.array([r["wavelength_nm"] for r in self.rows[i:j]])
            groups.append(Group(label, i, j, x))
            i = j
        self.groups = tuple(groups)

    def bsdf_nodes(self, row: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(incident direction, directions, weights) of a BSDF reading's prediction ``weights @ f``:
        the collector patch it averaged (a virtual body without an aperture), else the detector's
        cone through the record's aperture, calibrated against its white
        (:func:`bench.identify.prediction.cone_nodes`; no aperture: the viewing direction)."""
        g = Geometry(row["theta_i"], row["phi_i"], row["theta_r"], row["phi_r"])
        if row.get("patch") is not None:
            return (g.incident, *patch_nodes(*row["patch"]))
        return (g.incident, *cone_nodes(g, self.aperture_deg, self.white))

    def predictions(self, specimen: Specimen) -> np.ndarray:
        if self._nodes is None:
            self._nodes = [self.bsdf_nodes(r) if r["quantity"] == "bsdf" else None for r in self.rows]
        out = np.empty(len(self.rows))
        bands = self.bands if specimen.wavelength_range() is not None else {}
        for i, (r, nodes) in enumerate(zip(self.rows, self._nodes)):
            q = r["quantity"]
            if nodes is not None:
                wi, dirs, weights = nodes
                band = bands.get(float(r["wavelength_nm"]))
                out[i] = (band_mean(specimen, wi, dirs, weights, band) if band is not None else
                          float(weights @ np.asarray(specimen.bsdf(wi, dirs, r["wavelength_nm"]), dtype=float)))
            elif q == "RF":
                out[i] = ideal_rf(specimen, r["geometry"], r["wavelength_nm"])
            else:
                rt = directional_rt(specimen, cie_geometry(r["geometry"]).reciprocal_directional.theta_i,
                                    r["wavelength_nm"])
                if rt is None:
                    raise InputError(f"model {specimen.label}: no certified directional R, T for {r['geometry']}")
                out[i] = rt[0] if q == "R" else rt[1]
        return out

    def residuals(self, specimen: Specimen) -> np.ndarray:
        """Whitened residuals at the profiled shared scales, then the scales' prior residuals."""
        return self.scales.profile(self.chol, self.values, self.predictions(specimen))[0]

    def n_data(self, specimen: Specimen) -> int:
        return len(self.values)


def _has_counts(record: FitInput) -> bool:
    if isinstance(record, BSDFRecord):
        t = record.table
        if not {"count", "N"} <= set(t.columns) or len(t) == 0:
            return False
        c, n = t["count"].to_numpy(float), t["N"].to_numpy(float)
        return bool(np.all(np.isfinite(c)) and np.all(np.isfinite(n)) and np.all(n > 0))
    spectra = _spectra(record)
    return bool(spectra) and all(np.all(np.asarray(s.N) > 0) and str((s.meta or {}).get("source", "")) != "scan"
                                 and cie_geometry(s.geometry).reciprocal_directional.viewing == "diffuse"
                                 for s in spectra)


def likelihood_for(record: FitInput) -> Likelihood:
    """The likelihood of ``record``: virtual counts (multinomial) when it holds counts with ray
    totals, else its calibrated readings (Gaussian)."""
    if not isinstance(record, (BSDFRecord, Spectrum, tuple, list)):
        raise InputError(f"cannot fit a {type(record).__name__}: expected a BSDF record or spectra")
    if _has_counts(record):
        return GonioCounts(record) if isinstance(record, BSDFRecord) else SpectroCounts(record)
    return GaussianReadings(record)
