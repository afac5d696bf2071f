"""Likelihoods of a record under a candidate specimen, as residual vectors.

Every likelihood here returns residuals ``r(specimen)`` whose sum of squares is ``-2 log L``
up to a constant that does not depend on the model, so a least-squares minimizer finds the
maximum-likelihood estimate and differences of ``sum(r**2)`` are likelihood-ratio statistics:

* **virtual counts** (:mod:`bench.identify.likelihood_counts`: :class:`GonioCounts`,
  :class:`SpectroCounts`): the counts of a virtual
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
* **calibrated readings** (:mod:`bench.identify.likelihood_readings`: :class:`GaussianReadings`): a scan's BSDF values or spectra with
  their uncertainties, ``r = L^-1 (y - model)`` with ``L L^T`` the readings' covariance from
  :func:`record_covariance` (the one place the covariance comes from) less the shared
  scales, which are fitted as nuisance parameters (:mod:`bench.identify.scales`), and ``model`` what
  the body read (:mod:`bench.identify.prediction`, the design's prediction too): the cone of the
  detector aperture the record's metadata gives, calibrated against the white read through the
  same cone, or the collector patch of a virtual body without an aperture.

The residuals' base and what a fit takes are in :mod:`bench.identify.likelihood_base`. The
record's kind decides (:func:`likelihood_for`): integer counts with ray totals are
virtual counts, anything else is calibrated readings.
"""

from __future__ import annotations

import numpy as np

from bench.core.errors import InputError
from bench.core.geometry import cie_geometry
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from bench.identify.likelihood_base import FitInput, Group, Likelihood, spectra_of
from bench.identify.likelihood_counts import CRN_SEED, RAY_FACTOR, GonioCounts, SpectroCounts, multinomial_residuals
from bench.identify.likelihood_readings import GaussianReadings, reading_rows, record_covariance

__all__ = ["Likelihood", "Group", "GonioCounts", "SpectroCounts", "GaussianReadings", "likelihood_for",
           "record_covariance", "reading_rows", "FitInput", "multinomial_residuals", "CRN_SEED", "RAY_FACTOR"]


def _has_counts(record: FitInput) -> bool:
    if isinstance(record, BSDFRecord):
        t = record.table
        if not {"count", "N"} <= set(t.columns) or len(t) == 0:
            return False
        c, n = t["count"].to_numpy(float), t["N"].to_numpy(float)
        return bool(np.all(np.isfinite(c)) and np.all(np.isfinite(n)) and np.all(n > 0))
    spectra = spectra_of(record)
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
