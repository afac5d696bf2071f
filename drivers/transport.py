"""Byte transports: a serial port, a scripted replay, a recorder, and an SDK adapter.

A :class:`Transport` moves bytes and nothing else; protocol code sits above it. Four pieces:

``SerialTransport``
    Any pyserial URL (``/dev/ttyUSB0``, a pty slave path, ``loop://``, ``socket://host:port``)
    with exact-length reads against a deadline. A vanished port (``OSError``, ``termios.error``,
    ``serial.SerialException``) becomes :class:`bench.core.errors.PortGoneError`.
``ScriptedTransport``
    Replays recorded ``(sent, reply)`` pairs (the PyMeasure ``expected_protocol`` idea): every
    written byte must equal the recording, else :class:`bench.core.errors.TransportMismatchError`
    names the pair, the first differing byte and both byte strings in hex; bytes left unsent or
    unread at :meth:`ScriptedTransport.close` are a mismatch too. It never waits: a reply shorter
    than asked for behaves as a timeout at once, so scripted tests are fast and deterministic.
``RecordingTransport``
    Wraps a live transport and writes the exchange as a fixture file (format below).
``TransportPortHandler``
    A ``dynamixel_sdk.PortHandler`` whose I/O goes through a Transport, so the SDK's exact bytes
    can be pinned by a ScriptedTransport and its busy-poll becomes a blocking read with a deadline.

Fixture format (JSON lines, ``*.jsonl``)
----------------------------------------
One JSON object per line; blank lines and lines starting with ``#`` are comments. An optional
first object ``{"format": "goniobench-transcript", "version": 1, ...}`` carries metadata (any
extra keys, e.g. ``"note"``). Every other line is one exchange::

    {"sent": "FF FF FD 00 01 03 00 01 19 4E", "reply": "FF FF FD 00 01 07 00 55 00 FC 03 2A 06 C3"}

``sent`` is what the host wrote, ``reply`` every byte the host read before its next write
(``""`` when nothing came back: a broadcast, or a dropped reply). Hex is case-insensitive and
may contain spaces.
"""

from __future__ import annotations

import json
import logging
import os
import select
import time
from pathlib import Path
from typing import Callable, Iterable, Protocol, Sequence, runtime_checkable

import serial

from bench.core.errors import ConfigError, DeviceError, PortGoneError, TransportMismatchError

try:  # the SDK is a declared dependency, but keep the plain transports importable without it
    from dynamixel_sdk import PortHandler as _SdkPortHandler
except ImportError:  # pragma: no cover
    _SdkPortHandler = object  # type: ignore[misc,assignment]

__all__ = [
    "Transport",
    "SerialTransport",
    "ScriptedTransport",
    "RecordingTransport",
    "TransportPortHandler",
    "load_fixture",
    "save_fixture",
    "hexbytes",
]

log = logging.getLogger(__name__)

Pair = tuple[bytes, bytes]

try:
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not POSIX
    _TermiosError = OSError  # type: ignore[misc,assignment]

_GONE = (OSError, _TermiosError, serial.SerialException)


def hexbytes(data: bytes) -> str:
    """``b"\\xff\\x01"`` -> ``"FF 01"`` (the fixture and error-message spelling)."""
    return data.hex(" ").upper()


@runtime_checkable
class Transport(Protocol):
    """What protocol code needs from a byte pipe.

    ``read(n, timeout)`` returns exactly ``n`` bytes, or fewer only when ``timeout`` seconds
    passed first (``timeout=0`` returns what is already there). It never returns more than
    ``n`` bytes and never blocks past the deadline.
    """

    def write(self, data: bytes) -> None: ...

    def read(self, n: int, timeout: float) -> bytes: ...

    def reset_input(self) -> None: ...

    def close(self) -> None: ...


# --- serial ports --------------------------------------------------------------------------


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

    Raises
    ------
    PortGoneError
        When the port cannot be opened or vanishes later (read, write, reset).
    """

    def __init__(self, url: str, baudrate: int = 1_000_000, poll_s: float = 0.0005) -> None:
        self.url = url
        self.poll_s = poll_s
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
        deadline = time.monotonic() + max(0.0, timeout)
        buf = bytearray()
        try:
            while True:
                chunk = self._ser.read(n - len(buf))  # timeout=0: whatever is there, at once
                if chunk:
                    buf += chunk
                    if len(buf) >= n:
                        return bytes(buf)
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return bytes(buf)
                if self._fd is not None:
                    r, _, _ = select.select([self._fd], [], [], remaining)
                    if not r:
                        return bytes(buf)
                else:
                    time.sleep(min(self.poll_s, remaining))
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


# --- scripted replay -----------------------------------------------------------------------


class ScriptedTransport:
    """Replay recorded ``(sent, reply)`` pairs; fail on the first byte that differs.

    Writes are compared byte by byte with the ``sent`` side of the current pair (a pair may be
    written in several pieces, and one write may span pairs). When a pair's ``sent`` bytes are
    complete its ``reply`` becomes readable. Reads never wait: a read that asks for more than
    is queued returns what is there (a timeout, instantly).

    Parameters
    ----------
    pairs
        ``[(sent, reply), ...]`` as bytes, e.g. from :func:`load_fixture`.
    strict_unread
        If true (default), reply bytes still unread at :meth:`close` (or discarded by
        :meth:`reset_input`) are a mismatch; the real SDK reads every reply it asks for.

    Attributes
    ----------
    written : list[bytes]
        Every ``write`` call, in order (also after the script ran out).
    index : int
        Index of the pair currently expected.
    """

    def __init__(self, pairs: Iterable[tuple[bytes, bytes]], strict_unread: bool = True) -> None:
        self.pairs: list[Pair] = [(bytes(s), bytes(r)) for s, r in pairs]
        self.strict_unread = strict_unread
        self.written: list[bytes] = []
        self.index = 0
        self._offset = 0  # bytes of pairs[index].sent already matched
        self._rx = bytearray()
        self._failed = False
        self._closed = False
        self._discarded: list[tuple[int, bytes]] = []
        self._queue_replies_without_sent()

    # -- helpers ----------------------------------------------------------------------------
    def _queue_replies_without_sent(self) -> None:
        while self.index < len(self.pairs) and not self.pairs[self.index][0]:
            self._rx += self.pairs[self.index][1]
            self.index += 1

    def _fail(self, message: str) -> TransportMismatchError:
        self._failed = True
        return TransportMismatchError(message)

    @property
    def done(self) -> bool:
        """True when every pair was sent and every reply read."""
        return self.index >= len(self.pairs) and not self._rx and self._offset == 0

    # -- Transport --------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        if self._closed:
            raise PortGoneError("scripted transport is closed")
        data = bytes(data)
        self.written.append(data)
        pos = 0
        while pos < len(data):
            if self.index >= len(self.pairs):
                raise self._fail(
                    f"unexpected write after the last of {len(self.pairs)} recorded pairs: "
                    f"got {hexbytes(data[pos:])}")
            sent, reply = self.pairs[self.index]
            want = sent[self._offset:]
            got = data[pos:pos + len(want)]
            for k, (a, b) in enumerate(zip(want, got)):
                if a != b:
                    at = self._offset + k
                    got_full = sent[:self._offset] + data[pos:pos + len(want)]
                    raise self._fail(
                        f"pair {self.index}: sent byte {at} differs "
                        f"(expected 0x{a:02X}, got 0x{b:02X}); expected {hexbytes(sent)} "
                        f"got {hexbytes(got_full)}")
            pos += len(got)
            self._offset += len(got)
            if self._offset == len(sent):
                self._rx += reply
                self.index += 1
                self._offset = 0
                self._queue_replies_without_sent()

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        if self._closed:
            raise PortGoneError("scripted transport is closed")
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input(self) -> None:
        if self._rx:
            self._discarded.append((self.index, bytes(self._rx)))
            self._rx.clear()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._failed:
            return  # the first mismatch was already raised; do not mask it
        problems: list[str] = []
        if self._offset:
            sent = self.pairs[self.index][0]
            problems.append(f"pair {self.index} only partly sent ({self._offset} of {len(sent)} "
                            f"bytes: {hexbytes(sent)})")
            left = len(self.pairs) - self.index - 1
        else:
            left = len(self.pairs) - self.index
        if left > 0:
            nxt = self.pairs[len(self.pairs) - left][0]
            problems.append(f"{left} recorded pair(s) never sent, next is pair "
                            f"{len(self.pairs) - left}: {hexbytes(nxt)}")
        if self.strict_unread:
            if self._rx:
                problems.append(f"{len(self._rx)} reply byte(s) never read: {hexbytes(bytes(self._rx))}")
            for idx, d in self._discarded:
                problems.append(f"reply bytes discarded unread before pair {idx}: {hexbytes(d)}")
        if problems:
            raise TransportMismatchError("scripted transport closed with leftovers: "
                                         + "; ".join(problems))

    def __repr__(self) -> str:
        return f"ScriptedTransport({len(self.pairs)} pairs, at {self.index})"


# --- recording -----------------------------------------------------------------------------


class RecordingTransport:
    """Pass bytes through to ``inner`` and write the exchange to ``path`` as a fixture.

    A pair is one ``write`` plus every byte read until the next ``write``. The file is written
    at :meth:`close` (and by :meth:`flush`); parent directories are created.

    Parameters
    ----------
    inner
        The live transport.
    path
        Fixture file to write (JSON lines, see the module docstring).
    note
        Free text stored in the header line.
    """

    def __init__(self, inner: Transport, path: str | os.PathLike[str], note: str = "") -> None:
        self.inner = inner
        self.path = Path(path)
        self.note = note
        self.pairs: list[Pair] = []
        self._sent: bytes | None = None
        self._reply = bytearray()
        self._closed = False

    def _finish_pair(self) -> None:
        if self._sent is not None or self._reply:
            self.pairs.append((self._sent or b"", bytes(self._reply)))
        self._sent = None
        self._reply = bytearray()

    def write(self, data: bytes) -> None:
        self._finish_pair()
        self._sent = bytes(data)
        self.inner.write(data)

    def read(self, n: int, timeout: float) -> bytes:
        data = self.inner.read(n, timeout)
        self._reply += data
        return data

    @property
    def in_waiting(self) -> int:
        return int(getattr(self.inner, "in_waiting", 0))

    def reset_input(self) -> None:
        self.inner.reset_input()

    def flush(self) -> list[Pair]:
        """Write the pairs so far to :attr:`path`; return them (including the open pair)."""
        pairs = list(self.pairs)
        if self._sent is not None or self._reply:
            pairs.append((self._sent or b"", bytes(self._reply)))
        save_fixture(self.path, pairs, note=self.note)
        return pairs

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._finish_pair()
        try:
            save_fixture(self.path, self.pairs, note=self.note)
        finally:
            self.inner.close()


def save_fixture(path: str | os.PathLike[str], pairs: Sequence[tuple[bytes, bytes]],
                 note: str = "") -> None:
    """Write ``pairs`` as a JSON-lines fixture (see the module docstring)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    header = {"format": "goniobench-transcript", "version": 1}
    if note:
        header["note"] = note
    lines = [json.dumps(header)]
    lines += [json.dumps({"sent": hexbytes(s), "reply": hexbytes(r)}) for s, r in pairs]
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    os.replace(tmp, p)


def _unhex(text: str, where: str) -> bytes:
    try:
        return bytes.fromhex(text.replace(" ", "").replace(":", ""))
    except (ValueError, AttributeError) as exc:
        raise ConfigError(f"{where}: not hex bytes: {text!r}") from exc


def load_fixture(path: str | os.PathLike[str]) -> list[Pair]:
    """Read a JSON-lines fixture; return ``[(sent, reply), ...]`` as bytes.

    Raises
    ------
    ConfigError
        If a line is not JSON, lacks ``sent``/``reply`` or holds bad hex (naming the line).
    """
    pairs: list[Pair] = []
    for lineno, line in enumerate(Path(path).read_text(encoding="utf-8").splitlines(), 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        where = f"{path}:{lineno}"
        try:
            obj = json.loads(s)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{where}: not JSON: {exc}") from exc
        if not isinstance(obj, dict):
            raise ConfigError(f"{where}: expected an object")
        if "format" in obj:
            if obj.get("format") != "goniobench-transcript":
                raise ConfigError(f"{where}: unknown fixture format {obj.get('format')!r}")
            continue
        if "sent" not in obj or "reply" not in obj:
            raise ConfigError(f"{where}: needs 'sent' and 'reply'")
        pairs.append((_unhex(obj["sent"], where), _unhex(obj["reply"], where)))
    return pairs


# --- dynamixel-sdk adapter -----------------------------------------------------------------


class TransportPortHandler(_SdkPortHandler):  # type: ignore[misc,valid-type]
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
