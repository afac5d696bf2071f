"""Connections of the Modbus stage driver: :class:`TransportModbusClient` (a pymodbus RTU
client whose bytes go through a :class:`drivers.transport.Transport`: pymodbus frames, the
transport only moves bytes), :func:`check_reply` (a reply answers THIS request: device id,
function code, register count / echoed address; pymodbus itself checks only the device id),
the pure :func:`decode_rtu_reply` (bytes -> checked reply, for tests and fuzzing) and
:func:`port_open_hint` (the accurate cause when a serial port cannot be opened, e.g. a
pseudo-terminal refusing even parity).
"""

from __future__ import annotations

import os
import struct
import time
from typing import Any, Callable

import serial
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerRTU, FramerType
from pymodbus.pdu import DecodePDU

from bench.core.errors import ChecksumError, ProtocolError

class TransportModbusClient(ModbusSerialClient):
    """A pymodbus RTU client whose bytes go through a :class:`drivers.transport.Transport`.

    pymodbus builds and parses the frames (CRC included); the transport only moves bytes, so
    a ``ScriptedTransport`` pins the exact bytes on the wire and a ``RecordingTransport``
    records them.
    """

    def __init__(self, transport: Any, *, timeout: float = 0.5, retries: int = 0,
                 trace_packet: Callable[[bool, bytes], bytes] | None = None) -> None:
        super().__init__("transport://", framer=FramerType.RTU, timeout=timeout,
                         retries=retries, trace_packet=trace_packet)
        self._transport = transport
        self.socket = None

    def connect(self) -> bool:
        self.socket = self._transport
        return True

    def close(self) -> None:
        # pymodbus calls this after errors; the transport stays open (its owner closes it)
        self.socket = None

    def is_socket_open(self) -> bool:
        return self.socket is not None

    def _in_waiting(self) -> int:
        return int(getattr(self._transport, "in_waiting", 0))

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        if not request:
            return 0
        if self._in_waiting():
            self._transport.reset_input()
        self._transport.write(request)
        return len(request)

    def recv(self, size: int | None) -> bytes:
        timeout = self.comm_params.timeout_connect or 0.5
        if size is not None:
            return self._transport.read(size, timeout)
        first = self._transport.read(1, timeout)
        if not first:
            return b""
        # the rest of a frame follows within a few character times; take what is there
        rest = b""
        deadline = time.monotonic() + 0.02
        while True:
            n = self._in_waiting()
            if n:
                rest += self._transport.read(n, 0)
                deadline = time.monotonic() + 0.005
            elif time.monotonic() >= deadline:
                break
            else:
                time.sleep(0.0005)
        return first + rest


def probe_serial_open(port: str, baudrate: int, parity: str, bytesize: int,
                      stopbits: int) -> BaseException | None:
    """Open ``port`` as pymodbus does (exclusive, same settings) and close it again; return the
    exception that says why it fails (pymodbus only logs it), or None when it opens."""
    try:
        s = serial.serial_for_url(port, baudrate=baudrate, parity=parity, bytesize=bytesize,
                                  stopbits=stopbits, timeout=0, exclusive=True)
    except Exception as exc:  # pyserial raises termios.error, OSError, SerialException
        return exc
    s.close()
    return None


def port_open_hint(port: str, parity: str, exc: BaseException | None) -> str:
    """The accurate cause when a serial port cannot be opened or configured.

    Linux pseudo-terminals refuse parity (``tcsetattr`` with PARENB fails with EINVAL), while a
    real USB-RS485 adapter accepts the AZ default of even parity: say which it is.
    """
    text = str(exc or "")
    einval = "(22," in text or "Errno 22" in text or "Invalid argument" in text
    if einval:
        pty = os.path.realpath(port).startswith("/dev/pts/") or _is_pty(port)
        if pty and parity != "N":
            return (f" (EINVAL from tcsetattr: {port} is a pseudo-terminal, and Linux ptys refuse "
                    f"parity {parity!r}; use parity = \"N\" for an emulator on a pty — a real "
                    f"USB-RS485 adapter accepts even parity)")
        return (f" (EINVAL from tcsetattr: the port refused the serial settings "
                f"{parity!r} parity / baud rate; check them against the adapter)")
    return (" (is the port open elsewhere? axes on one RS-485 line must share one client: "
            "ModbusStageAxis(client=...))")


def _is_pty(port: str) -> bool:
    try:
        st = os.stat(port)
    except OSError:
        return False
    return os.major(st.st_rdev) in range(136, 144)  # Unix98 pty slaves


def check_reply(resp: Any, fc: int, device_id: int, address: int, count: int) -> None:
    """Check that ``resp`` (a pymodbus PDU) answers the request ``fc`` at ``address`` for
    ``count`` registers of ``device_id``; an exception response passes (the caller raises it).

    Raises
    ------
    ProtocolError
        Another device, another function, another register count or address: the answer to
        some other request, never to be used as this one's.
    """
    dev = getattr(resp, "dev_id", None)
    if dev != device_id:
        raise ProtocolError(f"reply from device {dev}, expected device {device_id}")
    rfc = getattr(resp, "function_code", None)
    if rfc == (fc | 0x80):
        return
    if rfc != fc:
        raise ProtocolError(f"reply with function code {rfc}, expected {fc}")
    if fc == 3:
        regs = getattr(resp, "registers", None)
        if not isinstance(regs, list) or len(regs) != count:
            n = len(regs) if isinstance(regs, list) else None
            raise ProtocolError(f"read reply carries {n} register(s), expected {count}")
    elif fc == 16:
        if getattr(resp, "address", None) != address or getattr(resp, "count", None) != count:
            raise ProtocolError(f"write reply echoes address {getattr(resp, 'address', None)}, "
                                f"count {getattr(resp, 'count', None)}; expected {address}, {count}")


def decode_rtu_reply(frame: bytes, fc: int, device_id: int, address: int, count: int) -> Any:
    """Decode one RTU reply frame with pymodbus's framer and check it against the request.

    Pure (no I/O). Returns the pymodbus PDU.

    Raises
    ------
    ChecksumError
        No valid frame (CRC, length, undecodable PDU).
    ProtocolError
        A valid frame that does not answer this request (see :func:`check_reply`).
    """
    framer = FramerRTU(DecodePDU(False))
    try:
        _, pdu = framer.handleFrame(bytes(frame), 0, 0)
    except (ModbusException, ValueError, IndexError, struct.error) as exc:
        raise ChecksumError(f"undecodable RTU reply {bytes(frame[:16]).hex(' ')}: {exc}") from None
    if pdu is None:
        raise ChecksumError(f"no valid RTU reply frame in {len(frame)} byte(s)")
    check_reply(pdu, fc, device_id, address, count)
    return pdu

