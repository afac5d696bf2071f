"""Byte-level I/O of the Ocean driver: deadlines, ACK/NAK, ASCII echo, lines, mode switching.

Owns :class:`OceanLink`, the half of the driver that talks to the transport, per the manual
(Ocean Optics Flame-S manual, "Firmware and Advanced Communications"):

- every read has a deadline; a short read is a retryable :class:`DeviceTimeoutError`;
- ASCII mode: the device echoes each byte it receives, so each byte is written and its echo read
  back before the next (a NAK in place of an echo is the device refusing the command there);
  values it sends end with CR LF (a bare CR is accepted too, once seen it is remembered);
- ``aA`` / ``bB`` are two bare bytes (no CR); ``bB`` from ASCII mode is echoed, then ACKed in
  binary; :meth:`OceanLink.sync_binary` brings a device back from either mode;
- a NAK, a timeout or a corrupt reply is retried a bounded number of times (:meth:`OceanLink.retrying`,
  counted in :attr:`OceanLink.faults`); before each retry :meth:`OceanLink.drain` swallows whatever is still arriving
  (e.g. the device's answers to a refused command's data bytes, which it may take for
  commands) so that no byte of it is read as the answer to the next command.
"""

from __future__ import annotations

import logging
import time
from typing import Any, Callable

from bench.core.errors import (
    ChecksumError,
    CommunicationError,
    DeviceTimeoutError,
    PortGoneError,
    ProtocolError,
)
from drivers._faultlog import FaultLog
from drivers.ocean.codec import ACK, CR, LF, NAK

__all__ = ["OceanLink", "Nak", "Retry"]

log = logging.getLogger(__name__)


class Retry(Exception):
    """A recoverable communication failure (becomes the wrapped error after the retries)."""

    def __init__(self, error: CommunicationError) -> None:
        super().__init__(str(error))
        self.error = error


class Nak(ProtocolError):
    """The device answered NAK (the command is refused or unknown to this unit)."""


class OceanLink:
    """Reads, writes and retries on one transport (see the module docstring); ``clock`` is the
    time source of every deadline (default wall time; tests pass a fake one)."""

    def __init__(self, transport: Any, name: str, timeout_s: float, retries: int,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.t = transport
        self._clock = clock
        self.name = name
        self.timeout_s = timeout_s
        self.retries = retries
        self.mode = "binary"
        self._rx = bytearray()
        self._lf: bool | None = None   # do value lines end CR LF (True) or CR (False)?
        self.closed = False
        self.faults = FaultLog()

    # -- reads -------------------------------------------------------------------------------
    def deadline(self, extra_s: float = 0.0) -> float:
        return self._clock() + self.timeout_s + extra_s

    def read_exact(self, n: int, deadline: float, what: str) -> bytes:
        data = bytes(self._rx[:n])
        del self._rx[:n]
        if len(data) < n:
            data += self.t.read(n - len(data), max(0.0, deadline - self._clock()))
        if len(data) < n:
            raise Retry(DeviceTimeoutError(
                f"{self.name}: {what}: got {len(data)} of {n} byte(s) before the deadline"
                + (f" ({data.hex(' ')})" if data else "")))
        return data

    def _fill(self, deadline: float, what: str) -> None:
        avail = int(getattr(self.t, "in_waiting", 0) or 0)
        chunk = self.t.read(max(1, avail), max(0.0, deadline - self._clock()))
        if not chunk:
            raise Retry(DeviceTimeoutError(f"{self.name}: {what}: no complete reply before the "
                                           f"deadline"))
        self._rx += chunk

    def read_line(self, deadline: float, what: str, limit: int = 4096) -> bytes:
        """A value or text line ending CR LF (or CR alone); returns it without the ending."""
        while True:
            i = self._rx.find(CR)
            if 0 <= i <= limit:
                break
            if len(self._rx) > limit:
                raise Retry(ChecksumError(f"{self.name}: {what}: no CR within {limit} bytes"))
            self._fill(deadline, what)
        line = bytes(self._rx[:i])
        del self._rx[:i + 1]
        if not self._rx and self._lf is not False:
            # CR LF is the manual's ending: wait for the LF (briefly while unsure)
            wait = deadline if self._lf else min(deadline, self._clock() + 0.05)
            try:
                self._fill(wait, what)
            except Retry:
                if self._lf:
                    raise
        if self._rx[:1] == bytes([LF]):
            del self._rx[:1]
            self._lf = True
        elif self._lf is None:
            self._lf = False
        return line

    def drain(self, quiet_s: float = 0.02, limit_s: float = 0.25) -> bytes:
        """Swallow what is still arriving until the line is quiet; flush; return what came."""
        got = bytearray(self._rx)
        self._rx.clear()
        end = self._clock() + limit_s
        last = self._clock()
        while self._clock() < end and self._clock() - last < quiet_s:
            n = int(getattr(self.t, "in_waiting", 0) or 0)
            chunk = self.t.read(max(1, n), min(quiet_s, max(0.0, end - self._clock())))
            if chunk:
                got += chunk
                last = self._clock()
        self.t.reset_input()
        if got:
            log.debug("%s: drained %d byte(s): %s", self.name, len(got), bytes(got[:32]).hex(" "))
        return bytes(got)

    # -- writes ------------------------------------------------------------------------------
    def send(self, cmd: bytes, deadline: float, what: str) -> None:
        """Write a command; in ASCII mode byte by byte, each echo read back before the next."""
        stale = bytes(self._rx)
        self._rx.clear()
        n = int(getattr(self.t, "in_waiting", 0) or 0)
        if n:
            stale += self.t.read(n, 0)
        if stale:  # a late reply to an earlier command must not be taken for this one's
            log.warning("%s: discarding %d stale byte(s) before %s: %s", self.name, len(stale),
                        what, stale[:32].hex(" "))
        if self.mode != "ascii":
            self.t.write(cmd)
            return
        for b in cmd:
            self.t.write(bytes([b]))
            echo = self.read_exact(1, deadline, f"{what} (echo)")[0]
            if echo == b:
                continue
            if echo == NAK:
                raise Nak(f"{self.name}: NAK to {what}")
            raise Retry(ChecksumError(f"{self.name}: {what}: echo 0x{echo:02X} differs from "
                                      f"the byte sent 0x{b:02X}"))

    def expect_ack(self, deadline: float, what: str) -> None:
        b = self.read_exact(1, deadline, what)[0]
        if b == NAK:
            raise Nak(f"{self.name}: NAK to {what}")
        if b != ACK:
            raise Retry(ChecksumError(f"{self.name}: {what}: expected ACK/NAK, got 0x{b:02X}"))

    def retrying(self, what: str, fn: Callable[[], Any]) -> Any:
        """``fn()`` with at most :attr:`retries` more attempts after a timeout, a corrupt reply or
        a NAK (a line glitch can turn a good command into an unknown one); before each retry the
        line is drained until quiet, so no late byte is taken for the next answer. A fault that
        persists is raised typed, naming the device, the command and the bytes."""
        last: CommunicationError | ProtocolError | None = None
        failures = 0
        for attempt in range(self.retries + 1):
            if self.closed:
                raise PortGoneError(f"{self.name}: closed")
            try:
                out = fn()
            except (Retry, Nak) as r:
                last = r.error if isinstance(r, Retry) else r
                failures += 1
                kind = "nak" if isinstance(r, Nak) else ("timeout" if isinstance(last, DeviceTimeoutError)
                                                        else "corrupt")
                self.faults.attempt_failed(kind, attempt < self.retries)
                log.warning("%s: %s failed (attempt %d of %d): %s", self.name, what, attempt + 1,
                            self.retries + 1, last)
                late = self.drain()  # and answers to data bytes the device may have taken for commands
                if late:
                    last = type(last)(f"{last} (then {len(late)} late byte(s): {late[:16].hex(' ')})")
                continue
            self.faults.finished(failures, True)
            return out
        assert last is not None
        self.faults.finished(failures, False)
        raise type(last)(f"{last} [after {self.retries + 1} attempt(s)]") from None

    # -- modes -------------------------------------------------------------------------------
    def sync_binary(self) -> str:
        """Bring the device into binary mode from either mode with a bare ``bB``; return the
        mode it was found in (``"ascii"``, ``"binary"``)."""
        what = "mode switch 'bB'"
        found = {"mode": "binary"}

        def once() -> None:
            self.drain(quiet_s=0.01, limit_s=0.05)
            deadline = self.deadline()
            self.t.write(b"b")
            first = self.read_exact(1, deadline, what) if self._peek_echo(deadline) else b""
            if first == b"b":   # ASCII mode: echoes each byte, ACKs in binary after the B
                self.t.write(b"B")
                if self.read_exact(1, deadline, what) != b"B":
                    raise Retry(ChecksumError(f"{self.name}: {what}: bad echo"))
                found["mode"] = "ascii"
            elif first:
                raise Retry(ChecksumError(f"{self.name}: {what}: got 0x{first[0]:02X} after 'b'"))
            else:
                self.t.write(b"B")
            self.mode = "binary"
            self.expect_ack(deadline, what)

        self.retrying(what, once)
        return found["mode"]

    def _peek_echo(self, deadline: float) -> bool:
        """After the first byte of ``bB``: is an echo arriving (ASCII mode)? A binary-mode
        device stays silent until the command is complete."""
        if self._rx:
            return True
        wait = min(deadline, self._clock() + 0.05)
        chunk = self.t.read(1, max(0.0, wait - self._clock()))
        self._rx += chunk
        return bool(chunk)

    def to_ascii(self) -> None:
        """``aA`` (bare) from binary mode: ACK, then the device is in ASCII mode."""
        what = "mode switch 'aA'"

        def once() -> None:
            deadline = self.deadline()
            self.t.write(b"aA")
            self.expect_ack(deadline, what)

        self.retrying(what, once)
        self.mode = "ascii"

    def to_binary(self) -> None:
        """``bB`` (bare) from ASCII mode: echoed byte by byte, then ACK in binary."""
        what = "mode switch 'bB'"

        def once() -> None:
            deadline = self.deadline()
            self.send(b"bB", deadline, what)
            self.expect_ack(deadline, what)

        self.retrying(what, once)
        self.mode = "binary"
