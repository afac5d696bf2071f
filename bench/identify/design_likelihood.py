"""The likelihood a design assumes, for fitting the scans it plans: calibrated readings of a bench.

:class:`BenchReadings` is the fit's Gaussian likelihood of calibrated readings
(:class:`bench.identify.likelihood.GaussianReadings`) with the two things the design's Fisher
information (:mod:`bench.identify.design`) also counts:

* the prediction is the model averaged over the detector's aperture, as the bench description
  declares it (:func:`bench.builders.instrument.declared_aperture`), calibrated against the
  white read through the same cone (:func:`bench.identify.prediction.predicted_brdf`): near a
  glossy peak a 1 deg aperture changes the reading by up to a few per cent at grazing angles,
  far more than the readings' noise;
* optionally (``shared=True``) the white standard's relative uncertainty as one error shared by
  every reading (covariance ``rho^2 y y^T``, what the design's information counts by default)
  rather than an independent error per reading (the default here: the diagonal of the readings'
  covariance). ``bench fit`` and the sequential design's fits divide by the budgets' full
  covariance (:func:`bench.identify.design_sequential.fit_readings`).

Readings the calibration masked (saturated, at or below dark: no value) are left out, as they
carry no information; :func:`valid_readings` drops them from a record.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.core.records import BSDFRecord
from bench.builders.instrument import declared_aperture
from bench.identify.likelihood import GaussianReadings

__all__ = ["BenchReadings", "bench_likelihood", "valid_readings", "aperture_of", "shared_relative"]


def valid_readings(record: BSDFRecord) -> BSDFRecord:
    """The record without its masked readings (no value: saturated, or no signal above dark)."""
    t = record.table
    keep = t["value"].notna() & t["std"].notna()
    return BSDFRecord(t[keep].reset_index(drop=True), record.meta)


def aperture_of(description: Any) -> float:
    """The detector aperture half-angle (deg) a bench description declares (0 when none):
    :func:`bench.builders.instrument.declared_aperture`."""
    return declared_aperture(description or {})


def shared_relative(record: BSDFRecord) -> float:
    """The white standard's relative standard uncertainty, from the record's calibration."""
    std = ((record.meta.get("calibration") or {}).get("standard") or {})
    rf, u = std.get("reflectance_factor"), std.get("uncertainty")
    if isinstance(rf, (int, float)) and isinstance(u, (int, float)) and rf > 0:
        return float(u) / float(rf)
    return 0.0


class BenchReadings(GaussianReadings):
    """Calibrated readings of a bench: the fit's predictions through the aperture ``aperture_deg``
    the bench description declares (and optionally a shared white scale)."""

    def __init__(self, record: BSDFRecord, aperture_deg: float = 0.0, shared: bool = False) -> None:
        from scipy.linalg import cholesky

        record = valid_readings(record)
        super().__init__(record)
        # the aperture the description declares; the prediction is the fit's own
        # (GaussianReadings.bsdf_nodes: the patch a virtual body without an aperture read, else the cone)
        self.aperture_deg = float(aperture_deg)
        # the design's Fisher information is diagonal in the readings: so is this likelihood (the
        # fit proper, bench.identify.likelihood, takes the budgets' full covariance)
        self.chol = np.diag(np.sqrt(np.diag(self.chol @ self.chol.T)))
        if shared:
            rho = shared_relative(record)
            u = np.sqrt(np.diag(self.chol @ self.chol.T))
            y = self.values
            own = np.maximum(u**2 - (rho * y) ** 2, (0.05 * u) ** 2)  # the rest of each reading's variance
            cov = np.diag(own) + rho**2 * np.outer(y, y)
            self.chol = cholesky(cov, lower=True)

    def n_data(self, specimen: Any) -> int:
        return len(self.values)


def bench_likelihood(record: BSDFRecord, description: Any) -> BenchReadings:
    """The likelihood of a scan on the bench ``description`` describes."""
    return BenchReadings(record, aperture_of(description))

