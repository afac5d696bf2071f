"""Return-to-home of the Modbus stage axis (Oriental AZ: ZHOME input, HOME-END output).

Owns :class:`HomingMixin`, the ``home()`` method of :class:`drivers.modbus.ModbusStageAxis`: a
rising edge of ZHOME (bit 4 of the input command 0x007D), then the output status polled until
HOME-END (output bit 4) with neither BUSY nor MOVE, within a bounded time; alarms are
:class:`HardwareError`, no HOME-END in time a STOP and :class:`DeviceTimeoutError` (both latch).
The bits come from the axis' register map.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from bench.core.errors import (
    ChecksumError,
    DeviceError,
    DeviceTimeoutError,
    HardwareError,
    PortGoneError,
    ProtocolError,
)

__all__ = ["HomingMixin"]


class HomingMixin:
    """``home()`` for an axis providing ``status``, ``write_int32``, ``position_deg``, ``stop``,
    ``_check_latch``, ``_raise_alarm``, ``_set_fault``, ``_fault``, ``rmap``, ``config`` and
    ``name``."""

    rmap: Any
    config: Any
    name: str
    _fault: Any

    if TYPE_CHECKING:  # what the axis provides, declared for the type checker only
        def status(self) -> dict[str, Any]: ...
        def write_int32(self, key: str, value: int) -> None: ...
        def position_deg(self) -> float: ...
        def stop(self) -> None: ...
        def _check_latch(self) -> None: ...
        def _raise_alarm(self, st: dict[str, Any], during: str) -> None: ...
        def _set_fault(self, kind: str, message: str) -> None: ...

    def home(self, timeout_s: float | None = None) -> float:
        """Return to home: a rising edge of ZHOME, then wait for HOME-END; return the position.

        Blocks at most ``timeout_s`` (default ``home_timeout_s``) polling the output status.

        Raises
        ------
        FaultLatchedError
            A fault is latched (nothing is sent).
        HardwareError
            The drive is in alarm before or during homing (fault latched).
        DeviceTimeoutError
            HOME-END did not come in time (a STOP is sent, fault latched).
        ProtocolError
            The register map has no ZHOME input or HOME-END output.
        """
        self._check_latch()
        cfg = self.config
        if "ZHOME" not in self.rmap.input_bits or "HOME-END" not in self.rmap.status_bits:
            raise ProtocolError(f"{self.name}: register map {self.rmap.name} has no ZHOME input "
                                f"bit or HOME-END output bit: homing is not available")
        limit = cfg.home_timeout_s if timeout_s is None else float(timeout_s)
        try:
            st = self.status()
            if "ALM" in st["flags"]:
                self._raise_alarm(st, "before homing")
            bit = 1 << self.rmap.input_bits["ZHOME"]
            self.write_int32("input_command", 0)     # make sure the next write is a rising edge
            self.write_int32("input_command", bit)
            self.write_int32("input_command", 0)
            return self._wait_home_end(limit)
        except HardwareError:
            raise
        except (DeviceTimeoutError, ChecksumError, PortGoneError, ProtocolError) as exc:
            if self._fault is None:
                self._set_fault("communication", f"{type(exc).__name__} during homing: {exc}")
            raise

    def _wait_home_end(self, limit: float) -> float:
        cfg = self.config
        deadline = time.monotonic() + limit
        busy = {"BUSY", "MOVE"}
        while True:
            st = self.status()
            flags = set(st["flags"])
            if "ALM" in flags:
                self._raise_alarm(st, "while homing")
            if "HOME-END" in flags and not busy & flags:
                return self.position_deg()
            if time.monotonic() >= deadline:
                try:
                    self.stop()
                except DeviceError:
                    pass
                msg = (f"{self.name}: return to home not finished (no HOME-END) within "
                       f"{limit:.3g} s; status {'|'.join(st['flags'])}")
                self._set_fault("timeout", msg)
                raise DeviceTimeoutError(msg)
            time.sleep(cfg.poll_interval_s)

