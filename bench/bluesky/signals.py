"""Signals that say which hardware they stand for.

The devices keep their values in ophyd-async soft signals (the driver calls run on the bench's
worker, not in the signal), but a soft backend names every data key ``soft://NAME``: a Bluesky
user (and a Tiled catalog) then cannot tell the emulated spectrometer's spectrum from a number a
script made up. :class:`HardwareBackend` is a soft backend whose ``source`` is the instrument:
``BODY://BENCH/ROLE/MODEL/SERIAL#NAME`` (:func:`hardware_source`), e.g.
``emulated://emulated/spectrometer/USB2000+/EMU00001#spectrometer-spectrum``.
"""

from __future__ import annotations

from typing import Any, Callable

from ophyd_async.core import SignalR, SignalRW, SoftSignalBackend

from bench.core.errors import BenchError
from bench.core.records import hardware_name

__all__ = ["HardwareBackend", "hardware_source", "hw_signal_r", "hw_signal_rw"]

def hardware_source(bench: Any, role: str) -> str:
    """``BODY://BENCH/ROLE/MODEL/SERIAL`` of the bench's ``role`` (its ``describe()``; a part it
    cannot describe is named by the role alone): :func:`bench.core.records.hardware_name`."""
    model = serial = None
    try:
        info = getattr(bench, role).describe()
        model, serial = info.model, info.serial
    except (BenchError, OSError, AttributeError):  # a name only: the device reports its own faults
        pass
    return hardware_name(bench.kind, bench.name, role, model, serial)


class HardwareBackend(SoftSignalBackend):
    """A :class:`~ophyd_async.core.SoftSignalBackend` whose data keys name ``hardware``."""

    def __init__(self, datatype: Any, initial_value: Any = None, units: str | None = None,
                 precision: int | None = None, *, hardware: str, getter: Any = None, setter: Any = None) -> None:
        super().__init__(datatype, initial_value, units, precision, getter=getter, setter=setter)
        self.hardware = hardware

    def source(self, name: str, read: bool) -> str:
        return f"{self.hardware}#{name}"


def hw_signal_r(datatype: Any, initial_value: Any, hardware: str, units: str | None = None,
                precision: int | None = None) -> tuple[SignalR, Callable[[Any], None]]:
    """A read-only signal of ``hardware`` and the callable that sets its value."""
    backend = HardwareBackend(datatype, initial_value, units, precision, hardware=hardware)
    return SignalR(backend), backend.set_value


def hw_signal_rw(datatype: Any, initial_value: Any, hardware: str, units: str | None = None,
                 precision: int | None = None, getter: Any = None, setter: Any = None) -> SignalRW:
    """A read-write signal of ``hardware`` (``getter`` / ``setter`` as ``soft_signal_rw``'s)."""
    return SignalRW(HardwareBackend(datatype, initial_value, units, precision, hardware=hardware, getter=getter,
                                    setter=setter))
