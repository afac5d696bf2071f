"""The calibration chain of a run, decided in one place: which white (none, the bench's stored
file, or the standard measured now), which darks, refused or taken.

:func:`decide_calibration` looks at the bench and the plan only (no motion) and either refuses
in one line (:class:`~bench.core.errors.CalibrationRefused`, exit 2) or returns a
:class:`CalibrationChain`; :meth:`CalibrationChain.take` then measures what is to be measured
(the only step that moves) and returns the run's :class:`~bench.core.calibration.Calibration`.
The runner asks once; ``bench white``, ``bench plan`` and the Bluesky detector ask the same.

A white belongs to the body that measured it. Every white (measured now, stored in a file, kept
by a run) records its **origin** (:func:`white_origin`)::

    {"body": "emulated", "bench": "emulated",
     "detector": {"model": "USB2000+", "serial": "EMU00001", "wavelengths_nm": [450, 550, 650],
                  "counts_per_ms": 1500.0}}

and is applied only to readings of the same body and detector (:func:`bench.preflight.check_origin`,
which every check of a stored white calls): counts of
emulated hardware and Monte Carlo counts of the virtual twin differ by the twin's gain, so a
white of one divided into readings of the other is wrong by that factor. No conversion rule is
declared; the twin measures its own standard. The integration time, averages, darks and repeats
must match the plan as before (:func:`bench.preflight.check_white_reference`). Files written
before origins were recorded stay readable; a run refuses them in one line saying how to take
them again.

A white that does not look like the standard is refused (:func:`check_white_level`):

* against the level the description declares: ``[detector] counts_per_ms`` (the emulated body's
  unit without ``[detector]``) and the certificate give the dark-corrected rate of the standard
  at the lamp's peak, ``RESPONSE_GAIN * counts_per_ms * R_w / pi * cos(theta_w)`` per ms. The lamp's
  spectrum is not declared, so a band may read less (the lamp's relative output there) but never
  more: a band above ``1 + DECLARED_HEADROOM`` of it (times ``1 + |lamp_drift| (N - 1)`` for
  ``N`` repeated whites under a declared ``[instrument] lamp_drift``), or a brightest unsaturated
  band below ``DECLARED_FLOOR`` of it (lamp off, arm away from the standard), is refused (the
  upper bound only for a white taken with its dark: without one its counts hold the dark level);
  saturated bands are masked by the calibration and say so themselves;
* against the last accepted white of the same body and detector (``bench white`` compares with the
  file it replaces, else the bench's ``[white] reference_file``): the band-median of the rate
  ratio must be within ``LEVEL_TOLERANCE`` of 1 (a Lambertian 0.8 specimen mounted in place of
  a 0.99 standard reads 0.81) and every band's ratio within ``SHAPE_TOLERANCE`` of that median
  (the spectral shape).

Each bound is widened by ``Z_NOISE`` standard uncertainties of the ratio (normal, two-sided
1e-5 per band), so a good white is refused by noise at a rate below 1e-4 over a 10-band record.

A calibrated plan without darks (``dark = "none"``) on a detector with a dark level
(:func:`dark_level`: a declared ``[detector] dark_counts`` on any body, the virtual body's
``[instrument] dark_counts``, the emulated unit's 1000 counts on the emulated and real bodies
without ``[detector]``) is refused (:func:`check_dark_level`): its readings and its white would
both hold the dark, which does not cancel in their ratio (tens of standard uncertainties at a
specular peak). It is refused rather than corrected: no description declares the dark level
with an uncertainty a budget could carry (the data sheet's number is nominal, the real level
drifts with temperature), and a dark costs one reading with the light off. A white with
saturated bands is not kept as a reference (:func:`check_white_unsaturated`, ``bench white``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

import numpy as np

from bench.builders.detector import RESPONSE_GAIN
from bench.config import Bench
from bench.core.calibration import Calibration
from bench.core.errors import BenchError, CalibrationRefused
from bench.core.roles import Reading
from bench.io.white import WhiteReference, read_white_reference
from bench.plans import Plan
from bench.preflight import (calibration_record, dark_level, check_calibration_steps, check_origin, detector_identity,
                              no_light, white_origin)

log = logging.getLogger(__name__)

__all__ = ["CalibrationChain", "decide_calibration", "acquire_dark", "resumed_calibration", "check_resume_body",
           "stored_white", "white_origin", "dark_level", "check_dark_level", "check_white_unsaturated", "detector_identity", "check_origin", "check_white_level", "expected_white_rate", "previous_white",
           "LEVEL_TOLERANCE", "SHAPE_TOLERANCE", "DECLARED_HEADROOM", "DECLARED_FLOOR", "Z_NOISE"]

#: the band-median ratio of a new white to the last accepted one may differ from 1 by this much
#: (lamp ageing and re-mounting between sessions; a 0.8 specimen in place of a 0.99 standard: 0.19)
LEVEL_TOLERANCE = 0.10
#: every band's ratio may differ from the median ratio by this much (the spectral shape)
SHAPE_TOLERANCE = 0.05
#: a band may read this much above the declared detector's response to the standard (aperture, optics)
DECLARED_HEADROOM = 0.10
#: the brightest band must read at least this fraction of the declared response to the standard
DECLARED_FLOOR = 0.02
#: standard uncertainties of a ratio added to each bound (two-sided normal 1e-5 per band)
Z_NOISE = 4.42


def expected_white_rate(bench: Bench, wavelengths: Any) -> np.ndarray | None:
    """The dark-corrected rate (counts/s) the declared detector reads from the bench's standard at
    the lamp's peak, per wavelength; None when no ``counts_per_ms`` is declared."""
    cpm = detector_identity(bench)["counts_per_ms"]
    if cpm is None:
        return None
    wl = np.asarray(wavelengths, float)
    cos_w = abs(math.cos(math.radians(bench.white.geometry.theta_r)))
    return RESPONSE_GAIN * cpm * 1000.0 * bench.white.rf(wl) / math.pi * cos_w


def _rate(cal: Calibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    net, u, reasons = cal.reference_rate()
    return net, u, np.array([not r for r in reasons]) & (net > 0)


def check_white_level(where: str, cal: Calibration, bench: Bench, previous: Calibration | None = None,
                      previous_where: str = "the last accepted white") -> None:
    """Refuse (one line) a white that does not look like the standard (module docstring): its
    rate against the declared detector's response to the certificate, and against ``previous``
    (the last accepted white of the same body and detector; its level and spectral shape)."""
    net, u, ok = _rate(cal)
    wl = np.asarray(cal.white.wavelengths, float)
    expected = expected_white_rate(bench, wl)
    unsaturated = ~np.asarray(cal.white.saturated, bool)  # a saturated band is masked, and says so itself
    if expected is not None and unsaturated.any():
        # a declared lamp drift may brighten the k-th lit white reading by |drift| k
        drift = abs(float((bench.config.get("instrument") or {}).get("lamp_drift", 0.0)))
        headroom = (1.0 + DECLARED_HEADROOM) * (1.0 + drift * (cal.n_whites - 1))
        r, u_r = net / expected, u / expected
        # a white without its dark holds the detector's dark level too: only its light is bounded
        over = np.flatnonzero((r - Z_NOISE * u_r > headroom) & unsaturated) if cal.white_dark is not None else []
        if len(over):
            i = int(over[np.argmax(r[over])])
            raise CalibrationRefused(
                f"{where} reads {r[i]:.2f} x the declared detector's response to the standard at {wl[i]:g} nm "
                f"(counts_per_ms and the certificate's {bench.white.rf(wl)[i]:g}): more than the standard can "
                f"give; mount the white standard and take it again (or correct [detector] counts_per_ms)")
        top = int(np.argmax(np.where(unsaturated, r + Z_NOISE * u_r, -np.inf)))
        if r[top] + Z_NOISE * u_r[top] < DECLARED_FLOOR:
            level = max(float(r[top]), 0.0)
            raise CalibrationRefused(
                f"{where}: its brightest band reads {level:.3f} x the declared detector's response to the "
                f"standard (at least {DECLARED_FLOOR:g} expected): lamp off, the arm away from the standard or "
                f"no standard mounted; mount it and take it again")
    if previous is None:
        return
    if (previous.white_dark is None) != (cal.white_dark is None) or previous.white.signal.shape != net.shape:
        log.info("%s: not compared with %s (one has a dark, the other none)", where, previous_where)
        return
    pnet, pu, pok = _rate(previous)
    both = ok & pok
    if not both.any():
        return
    ratio = np.where(both, net / np.where(pnet > 0, pnet, 1.0), np.nan)
    u_ratio = np.abs(ratio) * np.hypot(u / np.where(net > 0, net, 1.0), pu / np.where(pnet > 0, pnet, 1.0))
    level = float(np.nanmedian(ratio))
    u_level = float(np.nanmedian(u_ratio))
    if abs(level - 1.0) - Z_NOISE * u_level > LEVEL_TOLERANCE:
        raise CalibrationRefused(
            f"{where} reads {level:.3f} x {previous_where} (within {LEVEL_TOLERANCE:.0%} expected): not the "
            f"standard that was accepted (a specimen mounted?) or the lamp changed; mount the white standard and "
            f"take it again")
    dev = np.abs(ratio / level - 1.0) - Z_NOISE * u_ratio / level
    if np.nanmax(dev) > SHAPE_TOLERANCE:
        i = int(np.nanargmax(dev))
        raise CalibrationRefused(
            f"{where}: its spectral shape differs from {previous_where} by {ratio[i] / level - 1:+.1%} at "
            f"{wl[i]:g} nm (within {SHAPE_TOLERANCE:.0%} expected): not the accepted standard; mount it and take "
            f"it again")


def stored_white(bench: Bench) -> WhiteReference | None:
    """The white reference file the bench's ``[white] reference_file`` names (a relative path is
    taken from the current directory), or None."""
    path = (bench.config.get("white") or {}).get("reference_file")
    return read_white_reference(path) if path else None


def previous_white(bench: Bench, *candidates: Any) -> tuple[Calibration, str] | None:
    """The last accepted white of ``bench``'s body and detector, to compare a new one with: the
    first of ``candidates`` (paths, e.g. the file ``bench white`` replaces) and the bench's
    ``[white] reference_file`` that is readable and of the same origin; None without one."""
    paths = [c for c in candidates if c] + [(bench.config.get("white") or {}).get("reference_file")]
    for path in paths:
        if not path:
            continue
        try:
            ref = read_white_reference(path)
            check_origin(f"white reference {path}", ref.origin, bench)
            return ref.calibration(bench.white), f"the accepted white {path}"
        except BenchError as exc:  # not comparable: the next candidate, or none
            log.info("%s: not compared with it (%s)", path, exc)
    return None


@dataclass(frozen=True)
class CalibrationChain:
    """What a plan's calibration will be on a bench, decided before any motion: ``source`` is
    ``"none"`` (``white = "none"``), ``"file"`` (the stored ``reference``, already checked against
    the bench's body, detector and the plan) or ``"measured"`` (the standard read now)."""

    bench: Bench
    plan: Plan
    source: str
    reference: WhiteReference | None = None

    def take(self) -> Calibration | None:
        """The calibration: the stored one, or the dark (when the plan takes darks) and the
        standard measured now, checked to look like the standard (:func:`check_white_level`)."""
        bench, plan = self.bench, self.plan
        if self.source == "none":
            return None
        if self.reference is not None:
            return self.reference.calibration(bench.white)
        dark = acquire_dark(bench, plan) if plan.dark != "none" else None
        origin = white_origin(bench)
        if plan.white == "repeated":
            cal = Calibration.from_repeats(bench.white, bench.white_readings(plan.integration_s, plan.averages,
                                                                            plan.white_repeats), dark, origin=origin)
        else:
            cal = Calibration(bench.white, bench.measure_white(plan.integration_s, plan.averages), dark,
                              origin=origin)
        check_white_level(f"the white measured on bench {bench.name!r}", cal, bench)
        return cal

    def provenance(self) -> dict[str, Any] | None:
        """What a run records about its stored reference (None without one)."""
        return None if self.reference is None else self.reference.provenance()

    def record(self, cal: Calibration | None) -> dict[str, Any]:
        """The run's ``calibration_steps``: the plan's steps, where the white came from and its origin."""
        out = calibration_record(self.plan, self.reference, cal)
        origin = getattr(cal, "origin", None)
        out["white_body"] = None if origin is None else origin.get("body")
        return out


def acquire_dark(bench: Bench, plan: Plan) -> Reading:
    """A reading with the light off (never silently skipped: a bench without a switchable light
    cannot take one, and says so)."""
    if bench.light is None:
        raise no_light(bench, plan)
    bench.light.off()
    try:
        return bench.spectrometer.acquire(plan.integration_s, plan.averages)
    finally:
        bench.light.on()


def check_dark_level(bench: Bench, plan: Plan) -> None:
    """Refuse (one line) a calibrated plan that takes no dark on a detector with a dark level
    (module docstring). A plan without white stores no values (its readings are raw counts)."""
    if plan.dark != "none" or plan.white == "none":
        return
    level = dark_level(bench)
    if level > 0:
        raise CalibrationRefused(
            f"plan {plan.name!r} takes no dark, but the detector of bench {bench.name!r} reads a dark level of "
            f"{level:g} counts: its readings would be offset by it; use dark = \"once\" or \"per-incidence\""
            + (" (bench white --dark once)" if plan.name == "white" else ""))


def check_white_unsaturated(where: str, cal: Calibration) -> None:
    """Refuse (one line) a white with saturated bands as a stored reference: every reading a run
    calibrates with it would be masked in those bands."""
    sat = np.asarray(cal.white.saturated, bool)
    if sat.any():
        wl = np.asarray(cal.white.wavelengths, float)
        raise CalibrationRefused(
            f"{where} is saturated in {int(sat.sum())} of {sat.size} bands (first at {wl[sat][0]:g} nm) at "
            f"integration_s = {cal.white.integration_s:g}: take it again with a shorter integration")


def decide_calibration(bench: Bench, plan: Plan, use_reference_file: bool = True) -> CalibrationChain:
    """Decide the plan's calibration chain on ``bench`` before any motion, or refuse it in one line
    (a bad or foreign white file, a step the bench cannot take, no dark on a detector with a dark
    level, a white that does not look like the standard).
    ``use_reference_file=False``: measure the standard now even when the bench names a file
    (``bench white``)."""
    ref = stored_white(bench) if plan.white != "none" and use_reference_file else None
    # darks, light, operator; the file's origin (another body's white is never divided into these
    # readings) and its settings against the plan's
    check_calibration_steps(bench, plan, ref)
    check_dark_level(bench, plan)
    if ref is not None:
        check_white_level(f"white reference {ref.path}", ref.calibration(bench.white), bench)
    source = "none" if plan.white == "none" else ("file" if ref is not None else "measured")
    return CalibrationChain(bench, plan, source, ref)


def check_resume_body(run_id: str, info: Mapping[str, Any], body: str) -> None:
    """Refuse (one line) to resume run ``run_id`` (``info``: its store record) on ``body`` when its
    white was measured on another body (its calibration's origin, else the body the run started
    on); from the record alone, before anything is opened."""
    if not info.get("calibration"):
        return
    origin = info["calibration"].get("origin")
    held = origin.get("body") if isinstance(origin, Mapping) else (info.get("meta") or {}).get("bench_kind")
    if held is not None and held != body:
        raise CalibrationRefused(f"run {run_id} was calibrated on the {held} body; resuming it on the {body} body "
                                 f"would divide that white into another body's readings: resume it with --body {held}")


def resumed_calibration(bench: Bench, plan: Plan, run_id: str, info: Mapping[str, Any]) -> Calibration | None:
    """The calibration an interrupted run (``info``: its store record) keeps, checked before any
    motion: it was measured on the body that resumes it, and the plan's remaining steps (darks)
    can be taken."""
    cal = Calibration.from_dict(info["calibration"]) if info.get("calibration") else None
    check_resume_body(run_id, info, bench.kind)
    check_dark_level(bench, plan)
    if cal is not None and cal.origin is not None:
        check_origin(f"the white of run {run_id}", cal.origin, bench)
    check_calibration_steps(bench, plan if cal is None else replace(plan, white="none"), None)
    return cal


