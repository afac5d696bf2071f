"""The likelihood of calibrated readings (:class:`GaussianReadings`).

A scan's BSDF values or spectra with their uncertainties: ``r = L^-1 (y - model)`` with
``L L^T`` the readings' covariance from :func:`record_covariance` (the one place the covariance
comes from) less the shared scales, which are fitted as nuisance parameters
(:mod:`bench.identify.scales`), and ``model`` what the body read
(:mod:`bench.identify.prediction`, the design's prediction too): the cone of the detector
aperture the record's metadata gives, calibrated against the white read through the same cone,
or the collector patch of a virtual body without an aperture.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.core.budget import readings_and_covariance
from bench.core.errors import InputError
from bench.core.geometry import Geometry, cie_geometry
from bench.core.records import BSDFRecord
from bench.identify.gof import ReadingNoise, reading_noise, type_a_dof
from bench.identify.likelihood_base import FitInput, Group, Likelihood, spectra_of
from bench.identify.prediction import (PATCH_BOUNDS, band_mean, cone_nodes, directional_rt, ideal_rf,
                                       patch_nodes, record_aperture, record_bands, virtual_body_patches,
                                       white_geometry)
from bench.identify.scales import SharedScales, split_scales
from virtual.specimens import Specimen

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["GaussianReadings", "record_covariance", "reading_rows"]


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
    for s in spectra_of(record):
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
