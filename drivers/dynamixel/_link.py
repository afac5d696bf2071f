"""Request/reply discipline of the Dynamixel driver on a half-duplex Protocol 2.0 bus.

dynamixel-sdk builds, stuffs, checksums and frames the packets (``PacketHandler.txPacket`` /
``rxPacket``); this module decides which received status is the answer to which request, as the
manual's packet rules require (ROBOTIS e-Manual, DYNAMIXEL Protocol 2.0):

- every status is checked against its request: the id (and, for a sync read, each listed id in
  order, each exactly once), the status instruction 0x55, and the parameter length (a READ of
  L bytes answers exactly L bytes; a PING 3; a WRITE or REBOOT 0). Anything else is not the
  answer: :func:`check_status` raises :class:`ProtocolError` and no byte of it is used as data;
- after a timeout, a corrupt reply or a mismatch the bus may still carry late statuses (e.g. the
  rest of an aborted SYNC_READ), so before any retry :class:`DxlLink` waits until the line has
  been quiet for the return delay plus the transmit time of the longest outstanding status at
  the port's baud rate, then flushes the input;
- a well-framed status answering another request (a late one) is discarded while the awaited
  one is listened for (:data:`MAX_DISCARDS`), and bytes waiting before a transaction are
  dropped, so a stale status neither fails nor poisons an attempt;
- retries are bounded (counted in :attr:`DxlLink.faults`); after them the last failure is raised as a typed error
  (:class:`DeviceTimeoutError`, :class:`ChecksumError`, :class:`ProtocolError`).

:func:`decode_status` is the pure codec (raw frame bytes -> parameters and error byte, checked
against the request) used for tests and fuzzing; the live path uses the SDK's framing and the
same :func:`check_status`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable, Sequence, TypeVar

from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler

from bench.core.errors import (
    ChecksumError,
    CommunicationError,
    DeviceTimeoutError,
    ProtocolError,
)
from drivers._faultlog import FaultLog
from drivers.transport import TransportPortHandler

__all__ = ["Request", "check_status", "decode_status", "DxlLink", "STATUS_INSTRUCTION",
           "BROADCAST_ID", "INST_PING", "INST_READ", "INST_WRITE", "INST_REBOOT",
           "INST_SYNC_READ", "INST_SYNC_WRITE"]

log = logging.getLogger(__name__)
_T = TypeVar("_T")

# Protocol 2.0 instruction codes (e-manual)
INST_PING, INST_READ, INST_WRITE, INST_REBOOT = 0x01, 0x02, 0x03, 0x08
INST_SYNC_READ, INST_SYNC_WRITE = 0x82, 0x83
STATUS_INSTRUCTION = 0x55
BROADCAST_ID = 0xFE
_STATUS_OVERHEAD = 11  # header 4, id, len 2, inst, err, crc 2
_HEADER = b"\xff\xff\xfd\x00"
_PING_REPLY_LEN = 3  # model number (2) + firmware version (1)
#: statuses answering another request skipped while one is awaited (then the attempt fails)
MAX_DISCARDS = 8


def _hex(data: Sequence[int], limit: int = 24) -> str:
    """The bytes of a reply as hex (the first ``limit``), for error messages."""
    b = bytes(data)
    return (b[:limit].hex(" ") + (f" ... ({len(b)} bytes)" if len(b) > limit else "")) if b else "no bytes"


@dataclass(frozen=True)
class Request:
    """What a status packet must look like to answer one request: id and parameter length."""

    what: str
    dxl_id: int
    reply_len: int


def check_status(packet: Sequence[int], req: Request) -> tuple[bytes, int]:
    """Check an unstuffed, CRC-checked status packet against ``req``; return (params, error).

    Raises
    ------
    ProtocolError
        The packet is not a status (instruction != 0x55), comes from another id, or carries a
        parameter count other than the requested one (it answers some other request).
    """
    pkt = bytes(packet)
    if len(pkt) < _STATUS_OVERHEAD or pkt[:4] != _HEADER:
        raise ProtocolError(f"{req.what}: {len(pkt)}-byte reply is not a status packet")
    length = pkt[5] | pkt[6] << 8
    if length < 4 or len(pkt) < length + 7:  # the SDK's unstuffing leaves spare tail bytes
        raise ProtocolError(f"{req.what}: status length field {length} does not match its "
                            f"{len(pkt)} bytes")
    pkt = pkt[:length + 7]
    if pkt[7] != STATUS_INSTRUCTION:
        raise ProtocolError(f"{req.what}: packet instruction 0x{pkt[7]:02X} is not a status (0x55)")
    if pkt[4] != req.dxl_id:
        raise ProtocolError(f"{req.what}: status from id {pkt[4]}, expected id {req.dxl_id}")
    n = length - 4
    if n != req.reply_len:
        raise ProtocolError(f"{req.what}: status of id {pkt[4]} carries {n} parameter byte(s), "
                            f"expected {req.reply_len} (an answer to another request)")
    return pkt[9:9 + n], pkt[8]


_PH = PacketHandler(2.0)


def decode_status(frame: bytes, req: Request) -> tuple[bytes, int]:
    """Decode one raw (stuffed) status frame and check it against ``req``.

    Pure: no I/O. ``frame`` must be exactly one packet.

    Raises
    ------
    ChecksumError
        Not a framed packet (header, length) or wrong CRC.
    ProtocolError
        A valid packet that does not answer ``req`` (see :func:`check_status`).
    """
    raw = bytes(frame)
    if len(raw) < _STATUS_OVERHEAD or raw[:4] != _HEADER:
        raise ChecksumError(f"{req.what}: no status header in {len(raw)} byte(s)")
    length = raw[5] | raw[6] << 8
    if len(raw) != length + 7 or length < 3:
        raise ChecksumError(f"{req.what}: length field {length} does not frame {len(raw)} bytes")
    crc = raw[-2] | raw[-1] << 8
    if _PH.updateCRC(0, list(raw), len(raw) - 2) != crc:
        raise ChecksumError(f"{req.what}: status CRC mismatch")
    pkt = list(raw)
    pkt = _PH.removeStuffing(pkt)
    length = pkt[5] | pkt[6] << 8
    return check_status(pkt[:length + 7], req)


class _Failure(Exception):
    """Internal: one failed attempt (timeout, corrupt, mismatch) to be retried after quiet."""

    def __init__(self, error: CommunicationError | ProtocolError, outstanding: int, kind: str = "timeout") -> None:
        super().__init__(str(error))
        self.error = error
        self.outstanding = outstanding
        self.kind = kind  # the FaultLog kind: timeout, corrupt, foreign, transmit


class DxlLink:
    """Transactions on one bus with bounded retries and quiet-bus recovery.

    Parameters
    ----------
    port
        The SDK port handler (its transport does the I/O).
    baudrate
        Line rate, for the transmit time of outstanding statuses.
    retries
        Extra attempts after a failed one.
    return_delay_s
        The servos' Return Delay Time (default 250 x 2 us).
    latency_s
        Host-side delivery latency added to the quiet window (a USB-serial adapter holds bytes
        up to its latency timer: 16 ms on an FTDI by default, the SDK's own figure).
    name
        Used in messages.
    clock, sleep
        Time source and sleep of the quiet-bus wait (default wall time; tests pass fake ones).
    """

    def __init__(self, port: TransportPortHandler, baudrate: int, retries: int,
                 return_delay_s: float = 500e-6, latency_s: float = 0.016,
                 name: str = "dynamixel", *, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.port = port
        self._clock, self._sleep = clock, sleep
        self.ph = _PH
        self.byte_s = 10.0 / float(baudrate)
        self.retries = retries
        self.return_delay_s = return_delay_s
        self.latency_s = latency_s
        self.name = name
        self.discarded = 0       # late bytes swallowed while waiting for quiet (diagnostics)
        self.recoveries = 0      # quiet-and-flush recoveries done
        self.faults = FaultLog()

    # -- quiet bus ---------------------------------------------------------------------------
    def quiet(self, outstanding_bytes: int) -> None:
        """Wait until nothing has arrived for return delay + the outstanding statuses' transmit
        time + the host latency (bounded), swallow what came, then flush the input."""
        t, clock = self.port.transport, self._clock
        window = self.return_delay_s + outstanding_bytes * self.byte_s + self.latency_s
        give_up = clock() + 10 * window + 0.2  # a babbling line still ends the wait
        last = clock()
        while True:
            now = clock()
            left = window - (now - last)
            if left <= 0 or now >= give_up:
                break
            got = t.read(max(1, int(getattr(t, "in_waiting", 0) or 0)), left)
            if got:
                self.discarded += len(got)
                last = clock()
            elif clock() - now < left / 2:  # a transport that never waits (scripted replay)
                self._sleep(min(left, 0.0005))
        t.reset_input()
        self.recoveries += 1

    # -- one attempt -------------------------------------------------------------------------
    def _tx(self, txpacket: list[int], what: str) -> None:
        self.port.is_using = False
        comm = self.ph.txPacket(self.port, txpacket)
        self.port.is_using = False
        if comm != COMM_SUCCESS:
            raise _Failure(CommunicationError(f"{self.name}: {what}: transmit failed "
                                              f"({self.ph.getTxRxResult(comm)})"), 0, "transmit")

    def _rx(self, req: Request, outstanding: int) -> tuple[bytes, int]:
        """The status answering ``req``. A well-framed status answering another request (another
        id, another parameter length: a late status of an earlier attempt or transaction) is
        discarded and the wait goes on, at most :data:`MAX_DISCARDS` times, so a stale status
        never costs (or poisons) an attempt; a timeout or a corrupt frame fails the attempt."""
        size = _STATUS_OVERHEAD + req.reply_len
        last: ProtocolError | None = None
        for k in range(MAX_DISCARDS + 1):
            rx, comm = self.ph.rxPacket(self.port, False)
            self.port.is_using = False
            if comm == COMM_RX_TIMEOUT and last is not None:  # only statuses answering something else came
                raise _Failure(ProtocolError(f"{self.name}: no reply to {req.what} after {k} discarded "
                                             f"status(es) answering another request (last: {last})"),
                               outstanding, "timeout")  # the awaited status was lost
            if comm == COMM_RX_TIMEOUT:
                raise _Failure(DeviceTimeoutError(f"{self.name}: no reply to {req.what}"), outstanding, "timeout")
            if comm != COMM_SUCCESS:
                kind = "corrupt reply (CRC/framing)" if comm == COMM_RX_CORRUPT else \
                    self.ph.getTxRxResult(comm)
                raise _Failure(ChecksumError(f"{self.name}: {kind} to {req.what}: {_hex(rx)}"), outstanding,
                               "corrupt")
            try:
                return check_status(rx, req)
            except ProtocolError as exc:
                self.faults.discarded += 1
                last = ProtocolError(f"{self.name}: {exc}: {_hex(rx)}")
                log.debug("%s: discarded a status that does not answer %s: %s", self.name, req.what, last)
                self.port.setPacketTimeout(size)  # listen again for the awaited status
        assert last is not None
        raise _Failure(last, outstanding, "foreign")

    def _drain_stale(self) -> None:
        """Before a transaction: bytes already waiting answer no request of it; drop them."""
        t = self.port.transport
        n = int(getattr(t, "in_waiting", 0) or 0)
        if n > 0:
            self.discarded += len(t.read(n, 0))
            self.faults.discarded += 1
            t.reset_input()

    @staticmethod
    def _packet(dxl_id: int, instruction: int, params: Sequence[int]) -> list[int]:
        p = list(params)
        pkt = [0] * (10 + len(p))
        pkt[4] = dxl_id
        pkt[5], pkt[6] = (len(p) + 3) & 0xFF, (len(p) + 3) >> 8
        pkt[7] = instruction
        pkt[8:8 + len(p)] = p
        return pkt

    def _retrying(self, what: str, attempt: Callable[[], _T]) -> _T:
        """``attempt()`` with at most :attr:`retries` more after a failed one, each after a quiet
        bus (:meth:`quiet`), so a retry does not inherit the failed attempt's late statuses;
        counted in :attr:`faults`. A fault that persists is raised typed, naming device,
        transaction and bytes."""
        last: _Failure | None = None
        self._drain_stale()
        for n in range(self.retries + 1):
            try:
                out = attempt()
            except _Failure as f:
                last = f
                self.faults.attempt_failed(f.kind, n < self.retries)
                log.debug("%s: %s attempt %d: %s", self.name, what, n + 1, f.error)
                self.quiet(f.outstanding)
                continue
            self.faults.finished(n, True)
            return out
        assert last is not None
        self.faults.finished(self.retries + 1, False)
        err = last.error
        raise type(err)(f"{err} after {self.retries + 1} attempt(s)") from None

    # -- transactions ------------------------------------------------------------------------
    def transact(self, dxl_id: int, instruction: int, params: Sequence[int], reply_len: int,
                 what: str) -> tuple[bytes, int]:
        """One instruction to one servo and its status: ``(parameters, error byte)``."""
        req = Request(what, dxl_id, reply_len)
        size = _STATUS_OVERHEAD + reply_len

        def attempt() -> tuple[bytes, int]:
            self._tx(self._packet(dxl_id, instruction, params), what)
            self.port.setPacketTimeout(size)
            return self._rx(req, size)
        return self._retrying(what, attempt)

    def ping(self, dxl_id: int, what: str) -> tuple[int, int]:
        """PING: ``(model number, error byte)``."""
        data, err = self.transact(dxl_id, INST_PING, (), _PING_REPLY_LEN, what)
        return data[0] | data[1] << 8, err

    def read(self, dxl_id: int, addr: int, size: int, what: str) -> tuple[bytes, int]:
        """READ ``size`` bytes at ``addr``: ``(data, error byte)``."""
        return self.transact(dxl_id, INST_READ, (addr & 0xFF, addr >> 8, size & 0xFF, size >> 8),
                             size, what)

    def write(self, dxl_id: int, addr: int, data: bytes, what: str) -> int:
        """WRITE ``data`` at ``addr``: the status error byte."""
        return self.transact(dxl_id, INST_WRITE, (addr & 0xFF, addr >> 8, *data), 0, what)[1]

    def reboot(self, dxl_id: int, what: str) -> int:
        return self.transact(dxl_id, INST_REBOOT, (), 0, what)[1]

    def sync_read(self, addr: int, size: int, ids: Sequence[int],
                  what: str) -> dict[int, tuple[bytes, int]]:
        """SYNC_READ: one status per listed id, in list order, each ``size`` bytes."""
        ids = list(ids)
        per = _STATUS_OVERHEAD + size

        def attempt() -> dict[int, tuple[bytes, int]]:
            self._tx(self._packet(BROADCAST_ID, INST_SYNC_READ,
                                  (addr & 0xFF, addr >> 8, size & 0xFF, size >> 8, *ids)), what)
            self.port.setPacketTimeout(per * len(ids))
            out: dict[int, tuple[bytes, int]] = {}
            for k, i in enumerate(ids):
                out[i] = self._rx(Request(f"{what} (id {i})", i, size), per * (len(ids) - k))
            return out
        return self._retrying(what, attempt)

    def sync_write(self, addr: int, size: int, values: dict[int, bytes], what: str) -> None:
        """SYNC_WRITE (broadcast): no status comes back; the caller verifies by reading back."""
        body: list[int] = []
        for i, data in values.items():
            if len(data) != size:
                raise ValueError(f"sync write of {size} bytes got {len(data)} for id {i}")
            body += [i, *data]

        def attempt() -> None:
            self._tx(self._packet(BROADCAST_ID, INST_SYNC_WRITE,
                                  (addr & 0xFF, addr >> 8, size & 0xFF, size >> 8, *body)), what)
        self._retrying(what, attempt)
