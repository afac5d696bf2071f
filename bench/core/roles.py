"""The one instrument interface: small typed roles that real and virtual devices both fill.

In the spirit of Bluesky's ``protocols.py``: a device is whatever has the methods of a role
(structural typing), so a third party's driver needs no base class. :mod:`bench.core.conformance`
runs one conformance check on every implementation.

Roles
-----
Instrument        ``describe()``, ``close()``, context manager.
Goniometer        ``check(geometry)`` (raises before any motion), ``move_to(geometry)`` (blocks
                  until settled, returns the geometry read back), ``position()``, ``stop()``.
Spectrometer      ``wavelengths``, ``acquire(integration_s, averages) -> Reading``.
LightSource       ``on()``, ``off()``.
Spectrophotometer ``measure(geometry, wavelengths) -> Spectrum``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol, Self, runtime_checkable

import numpy as np

from bench.core.geometry import CIEGeometry, Geometry
from bench.core.records import Reading, Spectrum

__all__ = [
    "InstrumentInfo",
    "Reading",
    "Spectrum",
    "Instrument",
    "Goniometer",
    "Spectrometer",
    "LightSource",
    "Spectrophotometer",
    "InstrumentBase",
]


@dataclass(frozen=True)
class InstrumentInfo:
    """What an instrument says about itself.

    ``uncertainty`` is the standard uncertainty of one reading in the instrument's unit
    (e.g. 0.005 reflectance units, 0.005 relative for a goniophotometer); ``ranges`` maps a
    quantity (``"theta_i"``, ``"wavelength_nm"``, ``"integration_s"`` ...) to ``(lo, hi)``.
    """

    kind: str
    model: str
    serial: str = ""
    firmware: str = ""
    uncertainty: float | None = None
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "model": self.model, "serial": self.serial,
                "firmware": self.firmware, "uncertainty": self.uncertainty,
                "ranges": {k: list(v) for k, v in self.ranges.items()}, "extra": dict(self.extra)}


@runtime_checkable
class Instrument(Protocol):
    def describe(self) -> InstrumentInfo: ...

    def close(self) -> None: ...

    def __enter__(self) -> Any: ...

    def __exit__(self, *exc: object) -> None: ...


@runtime_checkable
class Goniometer(Instrument, Protocol):
    def check(self, geometry: Geometry) -> None:
        """Raise :class:`bench.core.errors.GeometryError` if unreachable, blocking or colliding."""

    def move_to(self, geometry: Geometry) -> Geometry:
        """Move, block until settled, return the geometry read back from the axes."""

    def position(self) -> Geometry: ...

    def stop(self) -> None: ...


@runtime_checkable
class Spectrometer(Instrument, Protocol):
    @property
    def wavelengths(self) -> np.ndarray: ...

    def acquire(self, integration_s: float, averages: int = 1) -> Reading: ...


@runtime_checkable
class LightSource(Instrument, Protocol):
    def on(self) -> None: ...

    def off(self) -> None: ...


@runtime_checkable
class Spectrophotometer(Instrument, Protocol):
    def measure(self, geometry: str | CIEGeometry, wavelengths: Any) -> Spectrum: ...


class Closing:
    """``with x:`` closes ``x`` on leaving: ``__enter__`` returns it, ``__exit__`` calls its
    ``close()``. The one context-manager plumbing of devices, stores, servers and emulator handles."""

    def close(self) -> None:  # pragma: no cover - trivial default
        pass

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class InstrumentBase(Closing):
    """Context-manager plumbing shared by concrete devices (composition is still preferred)."""
