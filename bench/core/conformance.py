"""A reusable conformance checker for any implementation of the instrument roles.

Run it in your own tests, for your own driver::

    from bench.core.conformance import check_conformance
    roles = check_conformance(my_device, reachable=[...], unreachable=[...])

Every check raises :class:`ConformanceError` (an ``AssertionError``) naming the role, the call
and what was wrong. The same checks run on the virtual devices, the emulated bench and real
drivers, so "it works on the simulator" means the same thing as "it works on the bench".
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Sequence

import numpy as np

from bench.core.errors import GeometryError, InputError
from bench.core.geometry import Geometry
from bench.core.roles import (
    Goniometer,
    Instrument,
    InstrumentInfo,
    LightSource,
    Reading,
    Spectrometer,
    Spectrophotometer,
    Spectrum,
)

__all__ = [
    "ConformanceError",
    "check_instrument",
    "check_goniometer",
    "check_spectrometer",
    "check_light_source",
    "check_spectrophotometer",
    "check_conformance",
    "angular_distance_deg",
]


class ConformanceError(AssertionError):
    """An implementation does not behave as its role requires."""


def _require(cond: bool, role: str, what: str) -> None:
    if not cond:
        raise ConformanceError(f"[{role}] {what}")


def angular_distance_deg(a: Geometry, b: Geometry) -> float:
    """Largest angle (degrees) between the incident and between the viewing directions."""
    def ang(u: np.ndarray, v: np.ndarray) -> float:
        return math.degrees(math.atan2(np.linalg.norm(np.cross(u, v)), float(np.dot(u, v))))
    return max(ang(a.incident, b.incident), ang(a.view, b.view))


def check_instrument(dev: Any) -> InstrumentInfo:
    _require(isinstance(dev, Instrument), "Instrument",
             f"{type(dev).__name__} lacks describe/close/__enter__/__exit__")
    info = dev.describe()
    _require(isinstance(info, InstrumentInfo), "Instrument", "describe() must return InstrumentInfo")
    _require(bool(info.kind) and bool(info.model), "Instrument", "describe() needs kind and model")
    if info.uncertainty is not None:
        _require(math.isfinite(info.uncertainty) and info.uncertainty >= 0, "Instrument",
                 f"uncertainty must be finite and >= 0, got {info.uncertainty}")
    for name, rng in info.ranges.items():
        _require(len(rng) == 2 and rng[0] <= rng[1], "Instrument", f"range {name} = {rng} is not (lo, hi)")
    return info


def check_goniometer(
    gonio: Any,
    reachable: Sequence[Geometry],
    unreachable: Sequence[Geometry] = (),
    tol_deg: float = 0.5,
) -> None:
    """Reachable geometries pass ``check`` and are reached (read back within ``tol_deg``);
    unreachable ones raise :class:`GeometryError` from ``check`` and from ``move_to`` and
    leave the position untouched."""
    role = "Goniometer"
    _require(isinstance(gonio, Goniometer), role, f"{type(gonio).__name__} lacks the Goniometer methods")
    _require(len(reachable) > 0, role, "give at least one reachable geometry to test")
    for g in reachable:
        gonio.check(g)
        reached = gonio.move_to(g)
        _require(isinstance(reached, Geometry), role, f"move_to({g}) must return a Geometry")
        d = angular_distance_deg(reached, g)
        _require(d <= tol_deg, role, f"move_to({g}) reached {reached}, {d:.3g} deg away (tol {tol_deg})")
        pos = gonio.position()
        _require(angular_distance_deg(pos, reached) <= tol_deg, role,
                 f"position() {pos} differs from the geometry move_to returned {reached}")
    before = gonio.position()
    for g in unreachable:
        for call in (gonio.check, gonio.move_to):
            try:
                call(g)
            except GeometryError as exc:
                _require(str(exc) != "", role, "GeometryError must say what is wrong")
            else:
                raise ConformanceError(f"[{role}] {call.__name__}({g}) accepted an unreachable geometry")
        after = gonio.position()
        _require(angular_distance_deg(before, after) <= tol_deg, role,
                 f"refused move to {g} changed the position from {before} to {after}")
    gonio.stop()


def check_spectrometer(spec: Any, integration_s: float = 0.01, averages: int = 2) -> Reading:
    role = "Spectrometer"
    _require(isinstance(spec, Spectrometer), role, f"{type(spec).__name__} lacks the Spectrometer methods")
    wl = np.asarray(spec.wavelengths, dtype=float)
    _require(wl.ndim == 1 and wl.size > 0, role, "wavelengths must be a non-empty 1-D array")
    _require(bool(np.all(np.isfinite(wl))) and bool(np.all(np.diff(wl) > 0)), role,
             "wavelengths must be finite and strictly increasing")
    r = spec.acquire(integration_s, averages)
    _require(isinstance(r, Reading), role, "acquire() must return a Reading")
    _require(r.signal.shape == wl.shape, role, f"signal shape {r.signal.shape} != wavelengths {wl.shape}")
    _require(r.saturated.shape == wl.shape and r.saturated.dtype == bool, role,
             "saturated must be a bool array per wavelength")
    _require(r.averages == averages, role, f"asked for {averages} averages, reading says {r.averages}")
    _require(math.isclose(r.integration_s, integration_s, rel_tol=0.05, abs_tol=2e-5), role,
             f"asked for {integration_s} s integration, reading says {r.integration_s}")
    _require(bool(np.all(np.isfinite(r.signal))), role, "signal must be finite")
    for bad in ((0.0, 1), (-1.0, 1), (integration_s, 0)):
        try:
            spec.acquire(*bad)
        except InputError:
            pass
        else:
            raise ConformanceError(f"[{role}] acquire{bad} must raise InputError")
    return r


def check_light_source(src: Any) -> None:
    role = "LightSource"
    _require(isinstance(src, LightSource), role, f"{type(src).__name__} lacks on/off")
    src.on()
    src.off()


def check_spectrophotometer(sp: Any, geometry: str = "8/d",
                            wavelengths: Iterable[float] = (450.0, 550.0, 650.0)) -> Spectrum:
    role = "Spectrophotometer"
    _require(isinstance(sp, Spectrophotometer), role, f"{type(sp).__name__} lacks measure()")
    wl = np.asarray(list(wavelengths), dtype=float)
    s = sp.measure(geometry, wl)
    _require(isinstance(s, Spectrum), role, "measure() must return a Spectrum")
    _require(np.allclose(s.wavelengths, wl), role, "spectrum wavelengths differ from the request")
    for name in ("reflectance", "transmittance"):
        v = np.asarray(getattr(s, name))
        ci = np.asarray(getattr(s, name + "_ci"))
        _require(v.shape == wl.shape and ci.shape == wl.shape + (2,), role, f"{name} shape is wrong")
        _require(bool(np.all((v >= 0) & (v <= 1))), role, f"{name} outside [0, 1]: {v}")
        _require(bool(np.all((ci[:, 0] <= v) & (v <= ci[:, 1]))), role, f"{name} outside its own interval")
    _require(bool(np.all(s.reflectance + s.transmittance <= 1 + 1e-12)), role, "R + T exceeds 1")
    try:
        sp.measure("not-a-geometry", wl)
    except GeometryError:
        pass
    else:
        raise ConformanceError(f"[{role}] measure('not-a-geometry') must raise GeometryError")
    return s


def check_conformance(dev: Any, **kwargs: Any) -> list[str]:
    """Run every role check ``dev`` qualifies for; return the roles checked.

    Keyword arguments go to the role checks: ``reachable``, ``unreachable``, ``tol_deg``
    (goniometer), ``integration_s``, ``averages`` (spectrometer), ``geometry``, ``wavelengths``
    (spectrophotometer).
    """
    check_instrument(dev)
    roles = ["Instrument"]

    def pick(*names: str) -> dict[str, Any]:
        return {k: kwargs[k] for k in names if k in kwargs}

    if isinstance(dev, Goniometer):
        if "reachable" not in kwargs:
            raise ConformanceError("[Goniometer] pass reachable=[...] geometries to check a goniometer")
        check_goniometer(dev, **pick("reachable", "unreachable", "tol_deg"))
        roles.append("Goniometer")
    if isinstance(dev, Spectrometer):
        check_spectrometer(dev, **pick("integration_s", "averages"))
        roles.append("Spectrometer")
    if isinstance(dev, LightSource):
        check_light_source(dev)
        roles.append("LightSource")
    if isinstance(dev, Spectrophotometer):
        check_spectrophotometer(dev, **pick("geometry", "wavelengths"))
        roles.append("Spectrophotometer")
    with dev as entered:
        _require(entered is not None, "Instrument", "__enter__ must return the device")
    return roles
