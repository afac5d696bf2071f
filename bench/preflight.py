"""Calibration preflight: every calibration step a plan asks for is possible on the bench, or
the run is refused before any motion, in one line naming the step and what is missing.
Repeated whites (``white = "repeated"``) are the same step as one: the standard is mounted once
and read ``white_repeats`` times, which every body can do.

The steps: darks (``dark = "once" | "per-incidence" | "per-point"``) need a light the bench can
switch off (``[light]``, :mod:`bench.builders.light`); a white reference (``white = "once"``)
needs either a stored reading that matches the plan (same standard geometry, integration time,
averages, dark treatment and number of repeated whites: :func:`check_white_reference`) or a bench that can measure its
standard now (a virtual or emulated bench mounts it itself; a real one needs an operator at a
terminal, or ``bench white --yes``). ``dark = "none"`` is taken only when the plan says so, and
the run records it. A stored white is taken only on the body and detector that measured it
(:func:`check_origin`; :mod:`bench.calibration_chain` decides the chain and says why).
"""

from __future__ import annotations

import math
import sys
from typing import Any, Mapping

import numpy as np

from bench.builders.instrument import instrument_effects
from bench.builders.detector import (RESPONSE_GAIN, DetectorTable, check_integration, described_bands,
                                     detector_settings)
from bench.config import Bench
from bench.core.errors import CalibrationRefused
from bench.core.parsing import parse_wavelengths
from bench.io.white import WhiteReference
from bench.plans import Plan

__all__ = ["check_calibration_steps", "check_white_reference", "check_origin", "white_origin", "detector_identity", "dark_step", "calibration_record", "no_light"]

_DARK_STEP = {"once": "a dark", "per-incidence": "darks per incidence", "per-point": "darks per point"}
_GEOMETRY_KEYS = ("theta_i", "phi_i", "theta_r", "phi_r")
#: spectrometers set their integration in whole milliseconds (the Ocean protocol's ``I`` command):
#: a white taken with ``--integration-s 0.03862`` holds 0.039 s, as the plan's readings will; a
#: stored white within half of it of the plan's integration is the plan's (calibration divides rates)
INTEGRATION_RESOLUTION_S = 0.001


def dark_step(dark: str) -> str:
    """How a refusal names the plan's dark step."""
    return _DARK_STEP.get(dark, f"dark = {dark!r}")


def no_light(bench: Bench, plan: Plan) -> CalibrationRefused:
    """The refusal of a plan's darks on a bench that cannot switch its light off; it suggests a
    plan without darks only where one would be taken (an uncalibrated plan, or a detector
    without a dark level)."""
    fix = "add [light] kind = \"spectrometer-lamp\" to the bench file"
    level = dark_level(bench)
    if plan.white == "none" or level == 0:
        fix += ", or set dark = \"none\" in the plan"
    else:
        fix += f" (a calibrated plan without darks is refused: the detector's dark level, {level:g} counts, does not cancel)"
    return CalibrationRefused(f"plan {plan.name!r} asks for {dark_step(plan.dark)}; bench {bench.name!r} declares no "
                              f"switchable light or shutter: {fix}")


def dark_level(bench: Bench) -> float:
    """The dark level (counts per scan) of ``bench``'s detector: a declared ``[detector]``'s (every
    body); else the virtual body's ``[instrument] dark_counts`` (0 undeclared: the bare twin), the
    emulated and real bodies' the emulated unit's (its data sheet's, :class:`DetectorTable`)."""
    d = bench.config
    det = detector_settings(d)
    if det is not None:
        return float(det.dark_counts)
    if bench.kind == "virtual":
        effects = instrument_effects(d.get("instrument"))
        return 0.0 if effects is None else float(effects.dark_counts)
    return float(DetectorTable().dark_counts)




def detector_identity(bench: Bench) -> dict[str, Any]:
    """The detector a white is read with: model, serial, the wavelengths of its values and the
    declared ``counts_per_ms`` (without ``[detector]``: the emulated unit's own; on the virtual
    body its goniophotometer's gain in the same unit, ``gain / (RESPONSE_GAIN * 1000)``, as
    :func:`bench.builders.detector.virtual_gain` inverts; None on a real body that declares none)."""
    info = bench.spectrometer.describe()
    det = detector_settings(bench.config)
    if det is None and bench.kind == "emulated":
        det = DetectorTable()  # the emulator's unit: the table's defaults are its own
    cpm = None if det is None else float(det.counts_per_ms)
    gain = getattr(bench.spectrometer, "gain", None) if bench.kind == "virtual" else None
    if isinstance(gain, (int, float)) and gain > 0:  # the twin's response, declared or its default
        cpm = float(gain) / (RESPONSE_GAIN * 1000.0)
    wl = getattr(bench.spectrometer, "wavelengths", None)
    if wl is None:  # a bench that is its description only (planning): the bands it declares, if any
        bands = described_bands(bench.config)
        wl = None if bands is None else parse_wavelengths(bands[0])
    return {"model": str(info.model), "serial": str(info.serial),
            "wavelengths_nm": None if wl is None else [float(w) for w in np.asarray(wl, float)],
            "counts_per_ms": cpm}


def white_origin(bench: Bench) -> dict[str, Any]:
    """The origin a white measured on ``bench`` now records (module docstring)."""
    return {"body": bench.kind, "bench": bench.name, "detector": detector_identity(bench)}


def _retake(bench: Bench) -> str:
    return f"`bench white --bench BENCH.toml --body {bench.kind} --out FILE --force`"


def check_origin(where: str, origin: Mapping[str, Any] | None, bench: Bench) -> None:
    """Refuse (one line) a white whose origin is unknown, another body's, or another detector's."""
    if not isinstance(origin, Mapping) or not isinstance(origin.get("detector"), Mapping):
        raise CalibrationRefused(f"{where} records no body or detector (written before goniobench recorded them): "
                                 f"take it again on this bench with {_retake(bench)}")
    body = origin.get("body")
    if body != bench.kind:
        hint = ("the virtual body measures its own standard: remove [white] reference_file (no operator is "
                "needed)" if bench.kind == "virtual" else f"take one on this body with {_retake(bench)}")
        raise CalibrationRefused(f"{where} was measured on the {body} body; bench {bench.name!r} runs on the "
                                 f"{bench.kind} body and a white is applied only to readings of the body that "
                                 f"measured it: {hint}")
    held, now = origin["detector"], detector_identity(bench)
    wl_held, wl_now = [float(w) for w in held.get("wavelengths_nm") or []], now["wavelengths_nm"]
    if wl_now is not None and (len(wl_held) != len(wl_now) or not np.allclose(wl_held, wl_now, atol=1e-6)):
        span = lambda w: f"{len(w)} at {w[0]:g}..{w[-1]:g} nm" if w else "none"  # noqa: E731
        raise CalibrationRefused(f"{where} holds wavelengths {span(wl_held)}; the detector of bench {bench.name!r} "
                                 f"reads {span(wl_now)}: take it again with {_retake(bench)}")
    opened = bool(now["serial"])  # a described bench (planning) has not read its unit's serial yet
    same_unit = held.get("model") == now["model"] and (bench.kind == "virtual" or held.get("serial") == now["serial"])
    if opened and not same_unit:  # a virtual detector's serial names its seed: any seed reads the same twin
        raise CalibrationRefused(f"{where} was read with detector {held.get('model')} #{held.get('serial')}; bench "
                                 f"{bench.name!r} reads with {now['model']} #{now['serial']}: take it again with "
                                 f"{_retake(bench)}")
    cpm = held.get("counts_per_ms")
    if cpm is not None and now["counts_per_ms"] is not None and not math.isclose(cpm, now["counts_per_ms"],
                                                                                rel_tol=1e-9):
        raise CalibrationRefused(f"{where} was read with [detector] counts_per_ms = {cpm:g}; bench {bench.name!r} "
                                 f"declares {now['counts_per_ms']:g}: take it again with {_retake(bench)}")


def check_white_reference(ref: WhiteReference, bench: Bench, integration_s: float, averages: int,
                          dark: str, repeats: int = 1) -> None:
    """Refuse a stored white reading that does not match the run: measured on another body or
    detector (:func:`check_origin`), taken at another geometry than
    the bench's ``[white]`` standard, with another integration time (beyond half the detectors'
    millisecond step, :data:`INTEGRATION_RESOLUTION_S`) or number of averages, with
    a dark where the plan takes none (or none where it takes darks), or with another number of
    repeated white readings than the plan's (``repeats``: 1 for ``white = "once"``)."""
    where = f"white reference {ref.path or '(stored reading)'}"
    check_origin(where, ref.origin, bench)  # another body's or detector's white is never taken
    g = ref.standard.get("geometry") if isinstance(ref.standard, Mapping) else None
    if not isinstance(g, Mapping) or any(k not in g for k in _GEOMETRY_KEYS):
        raise CalibrationRefused(f"{where} records no geometry: take it again with `bench white`")
    want = bench.white.geometry.as_dict()
    for k in _GEOMETRY_KEYS:
        if abs(float(g[k]) - float(want[k])) > 1e-6:
            raise CalibrationRefused(f"{where} was taken at {k} = {float(g[k]):g} deg; bench {bench.name!r} "
                                   f"[white] geometry has {k} = {float(want[k]):g} deg")
    if abs(ref.white.integration_s - integration_s) > INTEGRATION_RESOLUTION_S / 2 + 1e-9 * integration_s:
        raise CalibrationRefused(f"{where} was taken with integration_s = {ref.white.integration_s:g} s; the plan "
                               f"integrates {integration_s:g} s: take it again with --integration-s {integration_s:g}")
    if ref.white.averages != averages:
        raise CalibrationRefused(f"{where} averages {ref.white.averages} scans; the plan averages {averages}: "
                               f"take it again with --averages {averages}")
    held = len(ref.repeats) or 1
    if held != repeats:
        want = f"white = \"repeated\" with white_repeats = {repeats}" if repeats > 1 else "white = \"once\""
        raise CalibrationRefused(f"{where} holds {held} white reading(s); the plan asks for {want}: take it again "
                                 f"with --repeats {repeats}")
    if dark != "none" and ref.dark is None:
        raise CalibrationRefused(f"{where} has no dark; the plan asks for {dark_step(dark)}: take it again on a bench "
                               f"with a switchable light, or set dark = \"none\" in the plan")
    if dark == "none" and ref.dark is not None:
        raise CalibrationRefused(f"{where} is dark-subtracted; the plan takes no dark (dark = \"none\"): "
                               f"take it again with `bench white --dark none`, or ask the plan for darks")


def check_calibration_steps(bench: Bench, plan: Plan, ref: WhiteReference | None) -> None:
    """Raise :class:`CalibrationRefused` (one line) unless every calibration step of ``plan`` can be
    taken on ``bench``, with ``ref`` the bench's stored white reading (or None); a
    :class:`PlanError` when a declared ``[detector]`` cannot integrate as long as the plan asks.
    Call it before any motion."""
    check_integration(bench.config, plan.integration_s, f"plan {plan.name!r}")
    if plan.dark != "none" and bench.light is None:
        raise no_light(bench, plan)
    if plan.white == "none":
        return
    if ref is not None:
        check_white_reference(ref, bench, plan.integration_s, plan.averages, plan.dark, plan.n_whites)
    elif bench.white_needs_operator and not bench.operator_confirmed and not sys.stdin.isatty():
        repeats = f" --repeats {plan.white_repeats}" if plan.white == "repeated" else ""
        raise CalibrationRefused(
            f"plan {plan.name!r} asks for a white reference; bench {bench.name!r} names no stored reading "
            f"([white] reference_file) and no operator at a terminal can mount the standard: mount it, run "
            f"`bench white --bench B --out FILE --yes --integration-s {plan.integration_s:g} --averages "
            f"{plan.averages}{repeats}`, then set [white] reference_file = \"FILE\"; or set white = \"none\" in the plan")


def calibration_record(plan: Plan, ref: WhiteReference | None, cal: Any = None) -> dict[str, Any]:
    """What a run records about the calibration steps it took (also when it took none); with
    repeated whites also ``white_repeats`` and ``lamp_drift``, the Type A estimate of ``cal``
    (:class:`~bench.core.calibration.LampDrift`)."""
    out = {"dark": plan.dark, "white": plan.white, "averages": plan.averages, "integration_s": plan.integration_s,
           "white_source": "none" if plan.white == "none" else ("file" if ref is not None else "measured")}
    if plan.white == "repeated":
        drift = getattr(cal, "lamp_drift", None)
        out["white_repeats"] = plan.white_repeats
        out["lamp_drift"] = None if drift is None else drift.as_dict()
    return out
