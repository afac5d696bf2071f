"""The dynamixel-sdk adapter: :class:`TransportPortHandler`, a ``PortHandler`` whose I/O goes
through a :class:`~drivers.transport.Transport` (blocking reads with the SDK's own deadline).
"""

from __future__ import annotations

import time
from typing import Callable, Sequence

from drivers.transport.base import Transport

try:  # the SDK is a declared dependency, but keep the plain transports importable without it
    from dynamixel_sdk import PortHandler as _SdkPortHandler
except ImportError:  # pragma: no cover
    _SdkPortHandler = object

class TransportPortHandler(_SdkPortHandler):
    """A ``dynamixel_sdk.PortHandler`` that does its I/O through a :class:`Transport`.

    The SDK's receive loop calls ``readPort(k)`` then ``isPacketTimeout()`` until it has a
    packet or the packet deadline passed, busy-polling a non-blocking port. Here ``readPort``
    instead blocks in ``transport.read(k, remaining)`` until the ``k`` bytes or the SDK's own
    deadline; a short read therefore means the deadline was reached, and the next
    ``isPacketTimeout()`` says so at once. With a :class:`ScriptedTransport` (which never
    waits) a missing reply is an instant, deterministic timeout.

    Parameters
    ----------
    transport
        Where the bytes go.
    baudrate
        Used only for the SDK's timeout arithmetic (one of the SDK's fixed rates).
    clock
        Milliseconds clock for the SDK's timeout arithmetic (default wall time, as the SDK).
    """

    def __init__(self, transport: Transport, baudrate: int = 1_000_000,
                 clock: Callable[[], float] | None = None, name: str | None = None) -> None:
        super().__init__(name or repr(transport))
        self.transport = transport
        self._clock = clock or (lambda: time.monotonic() * 1000.0)
        self._expired = False
        self.baudrate = baudrate
        self.tx_time_per_byte = (1000.0 / baudrate) * 10.0
        self.is_open = True

    # -- port lifecycle ---------------------------------------------------------------------
    def openPort(self) -> bool:
        self.is_open = True
        return True

    def closePort(self) -> None:
        self.is_open = False
        self.transport.close()

    def clearPort(self) -> None:
        self.transport.reset_input()

    def setBaudRate(self, baudrate: int) -> bool:
        if self.getCFlagBaud(baudrate) <= 0:
            return False
        self.baudrate = baudrate
        self.tx_time_per_byte = (1000.0 / baudrate) * 10.0
        return True

    def setupPort(self, cflag_baud: int) -> bool:  # never opens a pyserial port itself
        self.is_open = True
        return True

    def getBytesAvailable(self) -> int:
        return int(getattr(self.transport, "in_waiting", 0))

    # -- I/O --------------------------------------------------------------------------------
    def readPort(self, length: int) -> bytes:
        if length <= 0:
            return b""
        remaining_ms = self.packet_timeout - (self.getCurrentTime() - self.packet_start_time)
        data = self.transport.read(length, max(0.0, remaining_ms) / 1000.0)
        if len(data) < length:
            self._expired = True
        return data

    def writePort(self, packet: Sequence[int]) -> int:
        data = bytes(packet)
        self.transport.write(data)
        return len(data)

    # -- timeouts ---------------------------------------------------------------------------
    def setPacketTimeout(self, packet_length: float) -> None:
        self._expired = False
        super().setPacketTimeout(packet_length)

    def setPacketTimeoutMillis(self, msec: float) -> None:
        self._expired = False
        super().setPacketTimeoutMillis(msec)

    def isPacketTimeout(self) -> bool:
        if self._expired:
            self.packet_timeout = 0
            return True
        return bool(super().isPacketTimeout())

    def getCurrentTime(self) -> float:
        return float(self._clock())
