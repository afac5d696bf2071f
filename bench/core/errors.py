"""One exception hierarchy for goniobench, rooted in :class:`BenchError`.

The CLI maps :class:`InputError` (and its subclasses) to exit status 2 and any other
:class:`BenchError` to exit status 1. Messages name what is wrong: the field, the plan
point, the byte.
"""

from __future__ import annotations

from typing import Any, Sequence

__all__ = [
    "BenchError",
    "InputError",
    "ConfigError",
    "SpecimenError",
    "GeometryError",
    "PlanError",
    "BudgetError",
    "DeviceError",
    "CommunicationError",
    "DeviceTimeoutError",
    "ChecksumError",
    "ProtocolError",
    "HardwareError",
    "PortGoneError",
    "FaultLatchedError",
    "TransportMismatchError",
    "CalibrationError",
    "CalibrationRefused",
    "StoreError",
    "RunInterrupted",
    "SimulationError",
]


class BenchError(Exception):
    """Root of every error goniobench raises on purpose."""


# --- bad input (exit status 2) -------------------------------------------------------------


class InputError(BenchError, ValueError):
    """Input that can never work: a bad argument, field, file or specification."""


class ConfigError(InputError):
    """A bench config, scene or plan file that is malformed or names unknown things."""


class SpecimenError(InputError):
    """An unknown specimen, a bad parameter, or a wavelength outside its data."""


class GeometryError(InputError):
    """A geometry that is invalid, unreachable, blocks the beam or collides.

    ``geometry`` is the offending geometry (or ``None`` when not applicable).
    """

    def __init__(self, message: str, geometry: Any = None) -> None:
        super().__init__(message)
        self.geometry = geometry


class PlanError(InputError):
    """A plan refused whole before any motion; ``problems`` lists ``(index, point, reason)``."""

    def __init__(self, message: str, problems: Sequence[tuple[int, Any, str]] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems)


class BudgetError(InputError):
    """A ray budget that cannot be met (bad uncertainty/confidence, or too many rays)."""


# --- failures while running (exit status 1) ------------------------------------------------


class DeviceError(BenchError):
    """A device failed while talking to it or while it worked."""


class CommunicationError(DeviceError):
    """No valid reply after the bounded retries (timeout, corrupt packet, checksum)."""


class DeviceTimeoutError(CommunicationError, TimeoutError):
    """The device did not answer within the allotted time."""


class ChecksumError(CommunicationError):
    """A reply arrived but its CRC/checksum or framing was wrong."""


class ProtocolError(DeviceError):
    """The device answered but refused (NAK, exception response) or answered nonsense."""


class HardwareError(DeviceError):
    """The device reports a hardware fault (error bits, alarm); motion is disabled until reset."""

    def __init__(self, message: str, code: int | None = None, flags: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.code = code
        self.flags = list(flags)


class PortGoneError(DeviceError):
    """The port vanished (device unplugged, emulator killed)."""


class FaultLatchedError(DeviceError):
    """A previous fault is latched: no motion command is sent until the caller resets."""


class TransportMismatchError(DeviceError, AssertionError):
    """A scripted transport saw bytes that differ from the recording, or leftovers at close."""


class CalibrationError(BenchError):
    """Calibration impossible (reference at or below dark, saturated, non-positive)."""


class CalibrationRefused(CalibrationError, InputError):
    """A calibration step the plan asks for that the bench cannot take (a dark without a
    switchable light, a stored white that does not match): refused before any motion (exit 2)."""


class StoreError(BenchError):
    """The run store refused an operation (unknown run, schema mismatch, locked)."""


class RunInterrupted(BenchError):
    """A run ended early (Ctrl-C or device fault); the reason is stored with the run."""

    #: True when the user stopped it (Ctrl-C): the CLI then exits 130
    by_user: bool = False

    @classmethod
    def by_the_user(cls, message: str) -> "RunInterrupted":
        """The interruption of a run the user stopped with Ctrl-C."""
        err = cls(message)
        err.by_user = True
        return err


class SimulationError(BenchError):
    """A simulation could not be carried out as specified."""
