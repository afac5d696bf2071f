"""Exposure planned, not discovered: the counts each reading of a plan will hold, predicted from
the bench description before any motion, so that a plan that would saturate the detector is
refused in one line naming the point, and the plan's expected uncertainty follows its
integration time, averages and the detector's full scale.

The prediction reads what the description declares, the same on every body:

* the detector (``[detector]``, :mod:`bench.builders.detector`; undeclared, the emulated unit's
  defaults, which are the table's): ``counts_per_ms`` at the lamp's peak for a reflected
  fraction of 1, dark level, read noise, ``saturation_counts``;
* the optics: the reflected fraction a detector cone sees is ``RESPONSE_GAIN mean_cone(f cos)``
  (:func:`bench.core.geometry.cone_cos_weights` over the :func:`declared_aperture`), as the
  emulator and the virtual body's detector read it;
* what is mounted: the ``[specimen]`` model at every plan point (when the description names one
  with a density) and the ``[white]`` standard at its geometry (when the plan measures a white).

One scan at a reading then holds ``dark + lamp counts_per_ms t_ms fraction`` counts, taken at
the lamp's peak (the bands lie at or below it: the prediction errs towards full scale) plus the
emulated detector's dark current. It is refused when the brightest scan's mean plus
``MARGIN_SD`` standard deviations (read noise and shot noise, the emulated detector's
``counts_per_electron``) reaches ``saturation_counts``: below that, a reading saturates with a
probability under 3e-7 per pixel. A description without physical detector (a plain virtual one:
no ``[detector]``, ``[emulated]``, ``[arm]`` and ``kind = "virtual"``) has no full scale:
nothing is predicted.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np

from bench.builders.detector import RESPONSE_GAIN, DetectorTable, detector_settings
from bench.builders.instrument import declared_aperture
from bench.core.calibration import WhiteStandard
from bench.core.errors import PlanError
from bench.core.geometry import Geometry, cone_cos_weights
from bench.core.parsing import parse_wavelengths
from bench.plans import Plan
from virtual.specimens import parse_specimen
from virtual.wire.ocean_model import SpectrometerConfig

__all__ = ["Exposure", "predict_exposure", "check_exposure", "resolve_integration", "unsaturated", "MARGIN_SD",
           "has_full_scale"]

log = logging.getLogger(__name__)

#: standard deviations of a scan's counts kept below full scale (one-sided 3e-7 per pixel)
MARGIN_SD = 5.0
_EMULATED = SpectrometerConfig()


@dataclass(frozen=True)
class Exposure:
    """The predicted counts of a plan's readings (one scan, at the lamp's peak)."""

    full_scale: float
    brightest: str  # which reading: "point 12 (theta_i, phi_i, theta_r, phi_r)" or "the white standard"
    brightest_rate: float  # its signal, counts per second of integration
    relative_noise: float  # the median plan point's relative standard deviation of one reading
    integration_s: float
    averages: int
    dark_counts: float
    read_noise: float

    def counts(self, integration_s: float | None = None) -> tuple[float, float]:
        """Mean and standard deviation (counts) of the brightest scan at ``integration_s``
        (default: the plan's)."""
        t = self.integration_s if integration_s is None else integration_s
        signal = self.brightest_rate * t
        return _dark(t, self.dark_counts) + signal, _sd(signal, self.read_noise)

    def saturates_at(self, integration_s: float) -> bool:
        mean, sd = self.counts(integration_s)
        return mean + MARGIN_SD * sd >= self.full_scale

    @property
    def saturates(self) -> bool:
        return self.saturates_at(self.integration_s)

    def longest_integration(self) -> float:
        """The longest integration time (s) at which the brightest scan keeps its margin."""
        lo, hi = 0.0, self.integration_s
        if not self.saturates_at(hi):
            return hi
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if self.saturates_at(mid) else (mid, hi)
        return lo

    def as_dict(self) -> dict[str, Any]:
        mean, sd = self.counts()
        return {"full_scale": self.full_scale, "brightest": self.brightest, "brightest_counts": mean,
                "brightest_sd": sd, "margin_sd": MARGIN_SD, "fraction_of_full_scale": mean / self.full_scale,
                "saturates": self.saturates, "longest_integration_s": self.longest_integration(),
                "relative_noise_per_reading": self.relative_noise}

    def refusal(self, plan_name: str, bench_name: str) -> str:
        mean, sd = self.counts()
        return (f"plan {plan_name!r} would saturate the detector of bench {bench_name!r}: {self.brightest} is "
                f"predicted at {mean:.0f} +- {sd:.0f} counts per scan vs full scale {self.full_scale:.0f} "
                f"({mean / self.full_scale:.0%}) at integration_s = {self.integration_s:g}: integrate at most "
                f"{self.longest_integration():.3g} s (and average more scans for the same noise)")


def has_full_scale(d: Mapping[str, Any]) -> bool:
    """Whether description ``d`` has a physical detector with a full scale (see the module docstring)."""
    return (str(d.get("kind", "virtual")) != "virtual" or any(k in d for k in ("detector", "emulated", "arm")))


def _dark(integration_s: float, dark_counts: float = 0.0) -> float:
    return dark_counts + _EMULATED.dark_counts_per_s * integration_s


def _sd(signal: float, read_noise: float) -> float:
    return math.sqrt(read_noise**2 + _EMULATED.counts_per_electron * max(signal, 0.0))


def _fractions(d: Mapping[str, Any], geometries: Sequence[Geometry], wavelengths: np.ndarray) -> np.ndarray | None:
    """``RESPONSE_GAIN mean_cone(f cos)`` of the described specimen at each geometry (the
    largest over ``wavelengths``), or None when the description names no specimen with a density."""
    spec_text = (d.get("specimen") or {}).get("spec")
    if not spec_text:
        return None
    spec = parse_specimen(spec_text)
    if not getattr(spec, "has_density", False):
        log.info("exposure: specimen %s has no density; predicted from the white standard only", spec_text)
        return None
    aperture = declared_aperture(d)
    out = np.empty(len(geometries))
    for k, g in enumerate(geometries):
        dirs, w_cos = cone_cos_weights(g.view, aperture)
        out[k] = max(float(w_cos @ np.asarray(spec.bsdf(g.incident, dirs, float(w)), dtype=float))
                     for w in wavelengths)
    return RESPONSE_GAIN * out


def predict_exposure(plan: Plan, d: Mapping[str, Any], white: bool | None = None) -> Exposure | None:
    """The predicted exposure of ``plan`` on description ``d`` (None without a full scale).
    ``white``: whether the run measures the white standard now (default: the plan asks for one
    and the description names no stored reading)."""
    if not has_full_scale(d):
        return None
    det = detector_settings(d) or DetectorTable()
    if white is None:
        white = plan.white != "none" and not (d.get("white") or {}).get("reference_file")
    bands = d.get("bands") or d.get("emulated") or {}
    centres = bands.get("centres", bands.get("bands", "450:650:100"))
    wavelengths = np.asarray(parse_wavelengths(centres), dtype=float)
    labelled: list[tuple[str, float]] = []
    fractions = _fractions(d, plan.points, wavelengths)
    if fractions is not None:
        labelled += [(f"point {i} ({g.theta_i:g}, {g.phi_i:g}, {g.theta_r:g}, {g.phi_r:g})", float(f))
                     for i, (g, f) in enumerate(zip(plan.points, fractions))]
    if white:
        std = WhiteStandard.from_dict(d.get("white", {}))
        rf = std.reflectance_factor
        peak_rf = float(rf) if isinstance(rf, (int, float)) else float(np.max(np.asarray(rf[1], dtype=float)))
        _, w_cos = cone_cos_weights(std.geometry.view, declared_aperture(d))
        labelled.append(("the white standard", RESPONSE_GAIN * peak_rf / math.pi * float(w_cos.sum())))
    if not labelled:
        return None
    rates = [(what, det.counts_per_ms * 1000.0 * f) for what, f in labelled]  # counts per s
    what, rate = max(rates, key=lambda s: s[1])
    point_rates = [r for w, r in rates if w.startswith("point")] or [rate]
    typical = float(np.median(point_rates)) * float(plan.integration_s)
    relative = _sd(typical, det.read_noise) / typical if typical > 0 else math.inf
    return Exposure(float(det.saturation_counts), what, rate, relative, float(plan.integration_s),
                    int(plan.averages), float(det.dark_counts), float(det.read_noise))


def check_exposure(plan: Plan, d: Mapping[str, Any], white: bool | None = None) -> Exposure | None:
    """Raise :class:`PlanError` (one line naming the reading, its predicted counts and the full
    scale) when ``plan`` would saturate the detector of description ``d``; else its exposure."""
    e = predict_exposure(plan, d, white)
    if e is not None and e.saturates:
        raise PlanError(e.refusal(plan.name, str(d.get("name", "bench"))))
    return e


def resolve_integration(plan: Plan, d: Mapping[str, Any]) -> Plan:
    """``plan`` with ``integration_s = "auto"`` resolved on description ``d``: the longest
    integration the declared detector takes (``[detector] integration_s``) at which the brightest
    predicted scan keeps its margin below full scale, two significant digits, rounded down;
    recorded in the plan's source, so the run (and its resume) keep the number. A plan with a
    number is returned as it is. Refused (one line) on a description without full scale, or
    when even the detector's shortest integration saturates."""
    if not plan.integration_auto:
        return plan
    bench = str(d.get("name", "bench"))
    if not has_full_scale(d):
        raise PlanError(f"plan {plan.name!r} asks for integration_s = \"auto\"; bench {bench!r} has no detector with a "
                        f"full scale to choose it from (declare [detector]): give integration_s in seconds")
    lo, hi = (detector_settings(d) or DetectorTable()).integration_s
    e = predict_exposure(replace(plan, integration_s=float(hi), integration_auto=False), d)
    if e is None:
        raise PlanError(f"plan {plan.name!r} asks for integration_s = \"auto\"; bench {bench!r} names no specimen "
                        f"model with a density and the plan takes no white: nothing to predict the counts from")
    longest = e.longest_integration()
    t = min(float(hi), _floor_2_digits(longest))
    if t < lo or longest <= 0:
        raise PlanError(f"plan {plan.name!r}: even the detector's shortest integration ({lo:g} s) would saturate "
                        f"on {e.brightest} (bench {bench!r})")
    log.info("plan %s: integration_s = %g s chosen (auto; the brightest reading %s)", plan.name, t, e.brightest)
    return replace(plan, integration_s=t, integration_auto=False, source={**dict(plan.source), "integration_s": t})


def starting_integration(d: Mapping[str, Any], preferred: float = 0.1) -> float:
    """The integration time (s) a detector device starts with before anyone sets one:
    ``preferred``, or the longest below it (two significant digits, rounded down) at which the
    white standard it measures first keeps its margin below full scale -- so a Bluesky plan run
    with the defaults is not refused for a number nobody chose."""
    plan = Plan(name="defaults", kind="list", points=(), integration_s=float(preferred), averages=1, dark="once",
                white="once")
    e = predict_exposure(plan, d, white=True)
    if e is None or not e.saturates:
        return float(preferred)
    return min(float(preferred), _floor_2_digits(e.longest_integration()))


def _floor_2_digits(x: float) -> float:
    if x <= 0:
        return 0.0
    digits = 1 - math.floor(math.log10(x))
    return round(math.floor(x * 10.0**digits + 1e-9) / 10.0**digits, digits)


def unsaturated(points: Sequence[Geometry], d: Mapping[str, Any], integration_s: float) -> list[Geometry]:
    """The ``points`` whose predicted scan on description ``d`` keeps its margin below full scale
    at ``integration_s`` (every point on a description without full scale, or without a specimen
    model to predict from): what a designed plan may choose among."""
    if not points or not has_full_scale(d):
        return list(points)
    bands = d.get("bands") or d.get("emulated") or {}
    wavelengths = np.asarray(parse_wavelengths(bands.get("centres", bands.get("bands", "450:650:100"))), dtype=float)
    fractions = _fractions(d, points, wavelengths)
    if fractions is None:
        return list(points)
    det = detector_settings(d) or DetectorTable()
    keep = []
    for g, f in zip(points, fractions):
        signal = det.counts_per_ms * 1000.0 * float(f) * integration_s
        mean = _dark(integration_s, float(det.dark_counts)) + signal
        if mean + MARGIN_SD * _sd(signal, float(det.read_noise)) < det.saturation_counts:
            keep.append(g)
    return keep
