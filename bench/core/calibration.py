"""Calibration: dark subtraction, a white reference of known reflectance factor, BRDF.

Signal model of a detector of fixed aperture looking at a specimen of BRDF ``f`` lit by a beam
of constant power (the same on real, emulated and virtual benches)::

    S = G t f cos(theta_r) + D

with gain ``G``, integration ``t`` and dark ``D``. A white standard of reflectance factor
``R_w`` (Lambertian, so ``f_w = R_w / pi``; e.g. Spectralon) measured at the reference geometry
with viewing angle ``theta_w`` gives ``S_w``. Hence, per wavelength::

    f  = [(S - D) / t] / [(S_w - D_w) / t_w] * (R_w / pi) * cos(theta_w) / cos(theta_r)   (BRDF, 1/sr)
    RF = pi f                              (reflectance factor, the Lambertian comparison)
    DSF = f cos(theta_r)                   (the cosine-corrected "differential scattering function")

Uncertainties add in quadrature in relative terms (signal, dark, reference, reference dark,
and the standard's own ``u(R_w)``). Pixels where the reference is saturated, or at or below its
dark, are *masked and reported*: they are never divided by, and their value is NaN with the
reason in ``mask_reason`` (not a silent NaN).

Repeated white readings (a plan's ``white = "repeated"``): the operator mounts the standard once
and ``N >= 3`` white readings are taken in sequence, lit readings ``j = 0 .. N-1`` of the lamp.
``S_w`` is then their mean (the white at the centroid ``j_c = (N-1)/2``) and the lamp's relative
drift per lit reading is estimated by least squares (:func:`estimate_lamp_drift`): the
band-summed dark-corrected white rate ``y_j = sum_pixels (S_w,j - D_w) / t`` against ``j``,
``delta = b1 / mean(y)`` with ``u(delta) = se(b1) / mean(y)`` (``N - 2`` degrees of freedom; the
mean's own uncertainty enters ``u(delta)`` only at second order and is left out). One relative
slope for the whole band, because the lamp model the description declares and the virtual body
simulates is one number (``[instrument] lamp_drift``), and summing the band gives that number
with the smallest standard error (a lamp whose spectrum drifts, e.g. a halogen cooling, would
need a slope per wavelength: not modelled). With the x's centred, ``b1`` and the mean are uncorrelated,
so the white reference reading and the drift are independent inputs. A reading that is the
``m``-th lit reading since the first white is corrected for the estimated drift (GUM: correct
for known systematic effects)::

    f_corrected = f / (1 + delta (m - j_c))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Mapping

import numpy as np

from bench.core.errors import CalibrationError, ConfigError
from bench.core.geometry import Geometry
from bench.core.roles import Reading

__all__ = ["WhiteStandard", "Calibration", "Calibrated", "LampDrift", "reading_std", "mean_reading", "estimate_lamp_drift"]


@dataclass(frozen=True)
class WhiteStandard:
    """A reflectance standard: reflectance factor (scalar or per wavelength), its standard
    uncertainty, and the geometry it is measured at (default 0/45, the usual Spectralon one)."""

    reflectance_factor: Any = 0.99
    uncertainty: float = 0.005
    geometry: Geometry = field(default_factory=lambda: Geometry(0.0, 0.0, 45.0, 180.0))
    name: str = "Spectralon-like 99%"

    def rf(self, wavelengths: np.ndarray) -> np.ndarray:
        r = self.reflectance_factor
        if isinstance(r, (int, float)):
            return np.full(wavelengths.shape, float(r))
        wl, val = (np.asarray(a, dtype=float) for a in r)
        if wavelengths.min() < wl.min() or wavelengths.max() > wl.max():
            raise CalibrationError(f"white standard {self.name!r} has data for {wl.min():g}..{wl.max():g} nm, "
                                   f"not {wavelengths.min():g}..{wavelengths.max():g} nm")
        return np.interp(wavelengths, wl, val)

    def as_dict(self) -> dict[str, Any]:
        r = self.reflectance_factor
        return {"name": self.name, "reflectance_factor": r if isinstance(r, (int, float)) else [list(r[0]), list(r[1])],
                "uncertainty": self.uncertainty, "geometry": self.geometry.as_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "WhiteStandard":
        r = d.get("reflectance_factor", 0.99)
        if not isinstance(r, (int, float)):
            r = (tuple(r[0]), tuple(r[1]))
        g = d.get("geometry", {"theta_i": 0.0, "phi_i": 0.0, "theta_r": 45.0, "phi_r": 180.0})
        if isinstance(g, Mapping):
            geometry = Geometry(**g)
        elif isinstance(g, (list, tuple)) and len(g) == 4:
            geometry = Geometry(*(float(x) for x in g))
        else:
            raise ConfigError(f"white standard geometry must be [theta_i, phi_i, theta_r, phi_r], got {g!r}")
        return cls(r, float(d.get("uncertainty", 0.005)), geometry, str(d.get("name", "white standard")))


@dataclass(frozen=True)
class Calibrated:
    """Calibrated values per wavelength; masked pixels have NaN values and a reason."""

    wavelengths: np.ndarray
    brdf: np.ndarray
    std: np.ndarray
    reflectance_factor: np.ndarray
    signal: np.ndarray
    dark: np.ndarray
    mask_reason: list[str]

    @property
    def masked(self) -> np.ndarray:
        return np.array([bool(r) for r in self.mask_reason])


def reading_std(r: Reading) -> np.ndarray:
    """Standard uncertainty per pixel of a reading: its own std, else a shot-noise estimate."""
    if r.std is not None:
        return np.asarray(r.std, dtype=float)
    # shot-noise-like fallback: counts are Poisson-ish, averaged over `averages` scans
    return np.sqrt(np.maximum(np.abs(r.signal), 1.0) / max(r.averages, 1))


@dataclass(frozen=True)
class LampDrift:
    """The Type A estimate of the lamp's relative drift per lit reading from repeated whites:
    ``per_lit_reading`` (delta, relative to the white at ``centroid``), its standard uncertainty,
    degrees of freedom (``repeats - 2``) and the lit index ``centroid = (repeats - 1) / 2`` of
    the repeats' mean."""

    per_lit_reading: float
    standard_uncertainty: float
    dof: int
    centroid: float
    repeats: int

    def offset(self, lit_index: int) -> float:
        """Lit readings between the white's centroid and the ``lit_index``-th lit reading."""
        return float(lit_index) - self.centroid

    def factor(self, lit_index: int) -> float:
        """The lamp's output at ``lit_index`` relative to the white's centroid: ``1 + delta d``."""
        return 1.0 + self.per_lit_reading * self.offset(lit_index)

    def as_dict(self) -> dict[str, Any]:
        return {"per_lit_reading": self.per_lit_reading, "standard_uncertainty": self.standard_uncertainty,
                "dof": self.dof, "centroid": self.centroid, "repeats": self.repeats, "type": "A"}


def mean_reading(readings: Any) -> Reading:
    """The mean of repeated readings of one thing: signal averaged, std ``sqrt(sum u_j^2) / N``,
    saturated where any repeat is, timestamp of the first."""
    rs = list(readings)
    if not rs:
        raise CalibrationError("no readings to average")
    if any(r.signal.shape != rs[0].signal.shape for r in rs):
        raise CalibrationError("repeated white readings have different pixel counts")
    n = len(rs)
    signal = np.mean([np.asarray(r.signal, float) for r in rs], axis=0)
    std = np.sqrt(np.sum([reading_std(r) ** 2 for r in rs], axis=0)) / n
    saturated = np.any([np.asarray(r.saturated, bool) for r in rs], axis=0)
    first = rs[0]
    return Reading(wavelengths=np.asarray(first.wavelengths, float), signal=signal, saturated=saturated,
                   integration_s=first.integration_s, averages=first.averages, timestamp=first.timestamp,
                   dark=first.dark, std=std)


def estimate_lamp_drift(repeats: Any, dark: Reading | None, ok: np.ndarray | None = None) -> LampDrift:
    """Least-squares slope of the band-summed white rate against the lit index (module
    docstring), over the pixels ``ok`` (default: every pixel). Needs at least 3 repeats."""
    rs = list(repeats)
    n = len(rs)
    if n < 3:
        raise CalibrationError(f"a lamp drift estimate needs at least 3 repeated white readings, got {n}")
    d = np.zeros_like(np.asarray(rs[0].signal, float)) if dark is None else np.asarray(dark.signal, float)
    keep = np.ones(d.shape, bool) if ok is None else np.asarray(ok, bool)
    if not keep.any():
        raise CalibrationError("no usable pixel in the repeated white readings to estimate the lamp drift")
    y = np.array([float(np.sum((np.asarray(r.signal, float) - d)[keep])) / r.integration_s for r in rs])
    x = np.arange(n, dtype=float)
    y_mean = float(y.mean())
    if not y_mean > 0:
        raise CalibrationError("the repeated white readings are at or below their dark: no lamp drift estimate")
    # numpy's least squares; cov=True scales the covariance by the residuals over n - 2 dof
    coef, cov = np.polyfit(x, y, 1, cov=True)
    b1, se_b1 = float(coef[0]), math.sqrt(max(float(cov[0, 0]), 0.0))
    return LampDrift(b1 / y_mean, se_b1 / y_mean, n - 2, float(x.mean()), n)


@dataclass(frozen=True)
class Calibration:
    """A white reference (with its dark) that turns readings into BRDF. ``white_repeats``: the
    repeated white readings ``white`` is the mean of (:meth:`from_repeats`), empty for one.
    ``origin``: what measured the white (body, bench, detector identity; see
    :mod:`bench.calibration_chain`), None when not recorded (an older white)."""

    standard: WhiteStandard
    white: Reading
    white_dark: Reading | None = None
    white_repeats: tuple[Reading, ...] = ()
    origin: Mapping[str, Any] | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.white_dark is not None and self.white_dark.signal.shape != self.white.signal.shape:
            raise CalibrationError("white reference and its dark have different pixel counts")
        if self.white_repeats and len(self.white_repeats) < 3:
            raise CalibrationError(f"repeated white readings must be at least 3, got {len(self.white_repeats)}")

    @classmethod
    def from_repeats(cls, standard: WhiteStandard, repeats: Any, dark: Reading | None = None,
                     origin: Mapping[str, Any] | None = None) -> "Calibration":
        """The calibration of ``N >= 3`` white readings taken in sequence: the white is their mean."""
        rs = tuple(repeats)
        return cls(standard, mean_reading(rs), dark, rs, origin)

    @property
    def n_whites(self) -> int:
        """How many lit white readings the calibration took (1, or the repeats)."""
        return len(self.white_repeats) or 1

    @cached_property
    def lamp_drift(self) -> LampDrift | None:
        """The Type A lamp drift estimate of the repeats (None without repeats), over the pixels
        the reference does not mask."""
        if not self.white_repeats:
            return None
        ok = np.array([not r for r in self.reference_rate()[2]])
        return estimate_lamp_drift(self.white_repeats, self.white_dark, ok)

    def reference_rate(self) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Dark-corrected reference counts per second, their std, and per-pixel mask reasons."""
        w = self.white
        d = self.white_dark.signal if self.white_dark is not None else np.zeros_like(w.signal)
        ud = reading_std(self.white_dark) if self.white_dark is not None else np.zeros_like(w.signal)
        net = (w.signal - d) / w.integration_s
        u = np.sqrt(reading_std(w) ** 2 + ud**2) / w.integration_s
        reasons = []
        for i in range(net.size):
            if w.saturated[i]:
                reasons.append("white reference saturated")
            elif not net[i] > 0:
                reasons.append("white reference at or below dark")
            else:
                reasons.append("")
        return net, u, reasons

    def apply(self, reading: Reading, geometry: Geometry, dark: Reading | None = None,
              lit_index: int | None = None) -> Calibrated:
        """Calibrate one reading taken at ``geometry`` (dark subtracted when given). With repeated
        whites and ``lit_index`` (the reading is the ``lit_index``-th lit reading since the first
        white) the value is corrected for the estimated lamp drift and its std carries the
        estimate's uncertainty (module docstring)."""
        if reading.signal.shape != self.white.signal.shape:
            raise CalibrationError(f"reading has {reading.signal.size} pixels, the white reference "
                                   f"{self.white.signal.size}")
        cos_r = abs(math.cos(math.radians(geometry.theta_r)))
        if cos_r < 1e-12:
            raise CalibrationError(f"{geometry}: viewing at the horizon, BRDF is undefined (cos theta_r = 0)")
        ref, u_ref, reasons = self.reference_rate()
        d = dark.signal if dark is not None else np.zeros_like(reading.signal)
        ud = reading_std(dark) if dark is not None else np.zeros_like(reading.signal)
        net = (reading.signal - d) / reading.integration_s
        u_net = np.sqrt(reading_std(reading) ** 2 + ud**2) / reading.integration_s
        rf_w = self.standard.rf(np.asarray(reading.wavelengths, dtype=float))
        cos_w = abs(math.cos(math.radians(self.standard.geometry.theta_r)))
        ok = np.array([not r for r in reasons])
        for i, sat in enumerate(reading.saturated):
            if sat and ok[i]:
                reasons[i] = "signal saturated"
                ok[i] = False
        brdf = np.full(net.shape, np.nan)
        std = np.full(net.shape, np.nan)
        scale = rf_w / math.pi * cos_w / cos_r
        brdf[ok] = net[ok] / ref[ok] * scale[ok]
        rel2 = np.zeros(net.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            rel2[ok] = ((u_ref[ok] / ref[ok]) ** 2 + (self.standard.uncertainty / rf_w[ok]) ** 2)
            signal_term = np.where(ok, u_net * ref**-1 * scale, 0.0)
        std[ok] = np.sqrt(signal_term[ok] ** 2 + brdf[ok] ** 2 * rel2[ok])
        drift = self.lamp_drift
        if drift is not None and lit_index is not None:
            factor = drift.factor(lit_index)
            u_rel = abs(drift.offset(lit_index)) * drift.standard_uncertainty / factor
            brdf, std = brdf / factor, np.hypot(std / factor, brdf / factor * u_rel)
        return Calibrated(wavelengths=np.asarray(reading.wavelengths, dtype=float), brdf=brdf, std=std,
                          reflectance_factor=brdf * math.pi, signal=reading.signal, dark=d, mask_reason=reasons)

    def as_dict(self) -> dict[str, Any]:
        def r(x: Reading | None) -> Any:
            if x is None:
                return None
            return {"wavelengths": x.wavelengths.tolist(), "signal": x.signal.tolist(),
                    "saturated": x.saturated.tolist(), "integration_s": x.integration_s,
                    "averages": x.averages, "std": None if x.std is None else np.asarray(x.std).tolist(),
                    "timestamp": x.timestamp}
        out = {"standard": self.standard.as_dict(), "white": r(self.white), "white_dark": r(self.white_dark)}
        if self.white_repeats:  # only then: a single white's dict is as before
            out["white_repeats"] = [r(x) for x in self.white_repeats]
        if self.origin is not None:  # only then: an older calibration's dict is as before
            out["origin"] = dict(self.origin)
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Calibration":
        def r(x: Any) -> Reading | None:
            if x is None:
                return None
            return Reading(wavelengths=np.asarray(x["wavelengths"], float), signal=np.asarray(x["signal"], float),
                           saturated=np.asarray(x["saturated"], bool), integration_s=float(x["integration_s"]),
                           averages=int(x["averages"]), timestamp=float(x.get("timestamp", 0.0)),
                           std=None if x.get("std") is None else np.asarray(x["std"], float))
        white = r(d["white"])
        assert white is not None
        repeats = tuple(r(x) for x in d.get("white_repeats") or ())
        origin = d.get("origin")
        return cls(WhiteStandard.from_dict(d["standard"]), white, r(d.get("white_dark")),
                   tuple(x for x in repeats if x is not None), dict(origin) if isinstance(origin, Mapping) else None)
