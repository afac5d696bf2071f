"""A pyserial port as a :class:`~drivers.transport.Transport`: exact-length reads against a
deadline; a vanished port becomes :class:`bench.core.errors.PortGoneError`.
"""

from __future__ import annotations

import logging
import select
import time
from typing import Callable

import serial

from bench.core.errors import DeviceError, PortGoneError
from drivers.transport.base import _GONE

log = logging.getLogger(__name__)

class SerialTransport:
    """A pyserial port (device path, pty, ``loop://``, ``socket://``) as a :class:`Transport`.

    Parameters
    ----------
    url
        Anything ``serial.serial_for_url`` opens.
    baudrate
        Line rate (a pty ignores it).
    poll_s
        Poll interval for ports without a selectable file descriptor (``loop://``).
    clock, sleep
        Time source and sleep of the read deadline on such ports (tests pass fake ones).

    Raises
    ------
    PortGoneError
        When the port cannot be opened or vanishes later (read, write, reset).
    """

    def __init__(self, url: str, baudrate: int = 1_000_000, poll_s: float = 0.0005, *,
                 clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        self.url = url
        self.poll_s = poll_s
        self._clock, self._sleep = clock, sleep
        try:
            self._ser = serial.serial_for_url(url, baudrate=baudrate, timeout=0, write_timeout=2.0)
        except _GONE as exc:
            raise PortGoneError(f"cannot open port {url!r}: {exc}") from exc
        try:
            self._fd: int | None = self._ser.fileno()
        except Exception:  # loop://, socket:// have no selectable fd through pyserial
            self._fd = None
        self._closed = False

    @property
    def in_waiting(self) -> int:
        try:
            return int(self._ser.in_waiting)
        except _GONE as exc:
            raise self._gone("in_waiting", exc) from exc

    def _gone(self, what: str, exc: BaseException) -> PortGoneError:
        return PortGoneError(f"port {self.url!r} vanished during {what}: {exc}")

    def write(self, data: bytes) -> None:
        if self._closed:
            raise PortGoneError(f"port {self.url!r} is closed")
        try:
            n = self._ser.write(bytes(data))
            self._ser.flush()
        except serial.SerialTimeoutException as exc:
            raise PortGoneError(f"write to {self.url!r} timed out (port stuck): {exc}") from exc
        except _GONE as exc:
            raise self._gone("write", exc) from exc
        if n is not None and n != len(data):
            raise DeviceError(f"short write on {self.url!r}: {n} of {len(data)} bytes")

    def read(self, n: int, timeout: float) -> bytes:
        if self._closed:
            raise PortGoneError(f"port {self.url!r} is closed")
        if n <= 0:
            return b""
        deadline = self._clock() + max(0.0, timeout)
        buf = bytearray()
        try:
            while True:
                chunk = self._ser.read(n - len(buf))  # timeout=0: whatever is there, at once
                if chunk:
                    buf += chunk
                    if len(buf) >= n:
                        return bytes(buf)
                remaining = deadline - self._clock()
                if remaining <= 0:
                    return bytes(buf)
                if self._fd is not None:
                    r, _, _ = select.select([self._fd], [], [], remaining)
                    if not r:
                        return bytes(buf)
                else:
                    self._sleep(min(self.poll_s, remaining))
        except _GONE as exc:
            raise self._gone("read", exc) from exc

    def reset_input(self) -> None:
        try:
            self._ser.reset_input_buffer()
        except _GONE as exc:
            raise self._gone("reset_input", exc) from exc

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._ser.close()
        except _GONE:  # closing a dead port is fine
            pass

    def __repr__(self) -> str:
        return f"SerialTransport({self.url!r})"
