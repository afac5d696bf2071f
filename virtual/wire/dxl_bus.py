"""The Dynamixel bus emulator proper: servos on one line, fault injection, in-process transports.

Owns :class:`DynamixelBus` (routes instructions: ping, read, write, reboot, sync read/write,
bulk read/write; fault injection on status packets), :class:`BusTransport` (a bus as an
in-process byte transport) and :class:`PtyBusThread` (a bus served on a pty from a thread).
"""

from __future__ import annotations

import os
import random
import select
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

from virtual.wire._dxl_codec import BROADCAST_ID, ERR, INST, Packet, PacketParser, encode_status
from virtual.wire._dxl_servo import TICKS_PER_REV, Servo
from virtual.wire._pty import close_quietly, open_pty, write_all



@dataclass
class Faults:
    """Fault injection on status packets (replies)."""

    drop_next: int = 0
    corrupt_next: int = 0
    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    delay_s: float = 0.0
    hang: bool = False
    #: after a corrupted status, the statuses that follow it in the same reply (the rest of a
    #: SYNC_READ) reach the host this much later, as through a USB adapter's latency timer;
    #: a host that re-sends at once then reads them as answers to its next request
    late_s: float = 0.0
    #: the next n broadcast SYNC_WRITE / BULK_WRITE packets are lost on the line (no servo
    #: takes them; a broadcast has no status, so the host cannot see it)
    drop_broadcast_next: int = 0
    #: probability that a status of an earlier request (the last one sent) reaches the host again
    #: just before a reply: a late or foreign status the host must discard (soak)
    stale_rate: float = 0.0
    dropped: int = 0
    corrupted: int = 0
    late: int = 0
    dropped_broadcasts: int = 0
    stale: int = 0


@dataclass
class AxisMap:
    """Ticks -> joint degrees for the ``joints`` field of the state (same meaning as the driver)."""

    id: int
    zero_offset: int = 2048
    direction: int = 1
    gear_ratio: float = 1.0

    def degrees(self, ticks: int) -> float:
        return (ticks - self.zero_offset) * self.direction * 360.0 / (TICKS_PER_REV * self.gear_ratio)


class DynamixelBus:
    """Several servos on one Protocol 2.0 line: bytes in, reply bytes out.

    Parameters
    ----------
    ids
        Servo IDs on the bus.
    positions
        Initial present positions (ticks) per ID (default 2048).
    clock, time_scale
        Passed to every :class:`Servo`.
    seed
        Seed for the random fault rates.
    axes
        Optional ``{name: {"id", "zero_offset", "direction", "gear_ratio"}}`` for :meth:`state`.
    """

    def __init__(self, ids: Iterable[int] = (1, 2, 3, 4), positions: Mapping[int, int] | None = None,
                 clock: Callable[[], float] = time.monotonic, time_scale: float = 1.0,
                 seed: int | None = 0, axes: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        positions = positions or {}
        self.clock = clock
        self.servos: dict[int, Servo] = {
            i: Servo(i, positions.get(i, 2048), clock=clock, time_scale=time_scale) for i in ids}
        self.parser = PacketParser()
        self.faults = Faults()
        self.rng = random.Random(seed)
        self.axes = {k: AxisMap(**dict(v)) for k, v in (axes or {}).items()}
        self.log: list[Packet] = []  # instructions received (bounded)
        self.later: list[tuple[float, bytes]] = []  # (release time, bytes) held back by late_s
        self._last_status = b""  # the status sent last: what a stale_rate fault sends again

    # -- control ----------------------------------------------------------------------------
    def set_faults(self, **kw: Any) -> None:
        for k, v in kw.items():
            if not hasattr(self.faults, k) or k in ("dropped", "corrupted", "late", "dropped_broadcasts", "stale"):
                raise KeyError(f"unknown fault {k!r}")
            setattr(self.faults, k, type(getattr(self.faults, k))(v))

    def clear_faults(self) -> None:
        self.faults = Faults()
        self.later.clear()

    def hardware_error(self, dev_id: int, bits: int, on_goal: bool = False) -> None:
        s = self.servos[dev_id]
        if on_goal:
            s.hw_error_on_goal |= bits
        else:
            s.set_hardware_error(bits)

    def state(self) -> dict[str, Any]:
        servos = {str(i): s.snapshot() for i, s in self.servos.items()}
        joints = {}
        for name, ax in self.axes.items():
            if ax.id in self.servos:
                joints[name] = ax.degrees(self.servos[ax.id].value("present_position", signed=True))
        return {"t": self.clock(), "servos": servos, "joints": joints}

    # -- protocol ---------------------------------------------------------------------------
    def handle(self, data: bytes) -> bytes:
        """Feed received bytes; return the reply bytes due now (possibly several status
        packets). Replies held back by the ``late_s`` fault wait in :attr:`later` until
        :meth:`take_due` releases them."""
        out = bytearray()
        for pkt in self.parser.feed(data):
            self.log.append(pkt)
            del self.log[:-1000]
            if pkt.id == BROADCAST_ID and pkt.instruction in (INST["sync_write"], INST["bulk_write"]) \
                    and self.faults.drop_broadcast_next > 0:
                self.faults.drop_broadcast_next -= 1
                self.faults.dropped_broadcasts += 1
                continue
            held = False
            for reply in self.execute(pkt):
                before = self.faults.corrupted
                injected = self._inject(reply)
                if held:
                    self.later.append((time.monotonic() + self.faults.late_s, injected))
                    self.faults.late += 1
                elif self.later:  # the line still carries late statuses: these come after them
                    self.later.append((max(t for t, _ in self.later), injected))
                else:
                    out += injected
                held = held or (self.faults.late_s > 0 and self.faults.corrupted > before)
        return bytes(out)

    def next_due(self) -> float | None:
        """Monotonic time of the next held-back reply, or None."""
        return min((t for t, _ in self.later), default=None)

    def take_due(self, now: float | None = None) -> bytes:
        """The held-back reply bytes whose time has come (in order)."""
        now = time.monotonic() if now is None else now
        due = [b for t, b in self.later if t <= now]
        self.later = [(t, b) for t, b in self.later if t > now]
        return b"".join(due)

    def _inject(self, reply: bytes) -> bytes:
        f = self.faults
        if f.hang:
            return b""
        stale, self._last_status = self._last_status, reply
        if stale and f.stale_rate and self.rng.random() < f.stale_rate:
            f.stale += 1
            return stale + self._inject_one(reply)
        return self._inject_one(reply)

    def _inject_one(self, reply: bytes) -> bytes:
        f = self.faults
        if f.drop_next > 0 or (f.drop_rate and self.rng.random() < f.drop_rate):
            f.drop_next = max(0, f.drop_next - 1)
            f.dropped += 1
            return b""
        if f.corrupt_next > 0 or (f.corrupt_rate and self.rng.random() < f.corrupt_rate):
            f.corrupt_next = max(0, f.corrupt_next - 1)
            f.corrupted += 1
            b = bytearray(reply)
            b[-1] ^= 0x5A  # CRC high byte: framing intact, checksum wrong
            return bytes(b)
        return reply

    def execute(self, pkt: Packet) -> list[bytes]:
        """Status packets answering one instruction packet (in bus order)."""
        i, p = pkt.instruction, pkt.params
        targets = list(self.servos) if pkt.id == BROADCAST_ID else [pkt.id] if pkt.id in self.servos else []
        reply_ok = pkt.id != BROADCAST_ID
        if i == INST["ping"]:
            out = []
            for t in targets:
                s = self.servos[t]
                out.append(encode_status(t, s.status_error(), s.value("model_number").to_bytes(2, "little")
                                           + bytes([s.value("firmware_version")])))
            return out
        if i == INST["read"]:
            if not targets or not reply_ok or self.servos[pkt.id].value("status_return_level") < 1:
                return []
            s = self.servos[pkt.id]
            if len(p) != 4:
                return [encode_status(pkt.id, s.status_error(ERR["data_length"]))]
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            err, data = s.read(addr, n)
            return [encode_status(pkt.id, s.status_error(err), data)]
        if i == INST["write"]:
            out = []
            for t in targets:
                s = self.servos[t]
                answers = s.value("status_return_level") >= 2  # the level before this write
                err = s.write(p[0] | p[1] << 8, p[2:]) if len(p) > 2 else ERR["data_length"]
                if reply_ok and answers:
                    out.append(encode_status(t, s.status_error(err)))
            return out
        if i == INST["reboot"]:
            out = []
            for t in targets:
                answers = self.servos[t].value("status_return_level") >= 2
                self.servos[t].reboot()
                if reply_ok and answers:
                    out.append(encode_status(t, self.servos[t].status_error()))
            return out
        if i == INST["sync_read"] and pkt.id == BROADCAST_ID and len(p) >= 4:
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            out = []
            for t in p[4:]:
                if t in self.servos and self.servos[t].value("status_return_level") >= 1:
                    s = self.servos[t]
                    err, data = s.read(addr, n)
                    out.append(encode_status(t, s.status_error(err), data))
            return out
        if i == INST["sync_write"] and pkt.id == BROADCAST_ID and len(p) >= 4:
            addr, n = p[0] | p[1] << 8, p[2] | p[3] << 8
            body = p[4:]
            for k in range(0, len(body) - n, n + 1):
                t = body[k]
                if t in self.servos:
                    self.servos[t].write(addr, body[k + 1:k + 1 + n])
            return []
        if i == INST["bulk_read"] and pkt.id == BROADCAST_ID:
            out = []
            for k in range(0, len(p) - 4, 5):
                t, addr, n = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
                if t in self.servos:
                    s = self.servos[t]
                    err, data = s.read(addr, n)
                    out.append(encode_status(t, s.status_error(err), data))
            return out
        if i == INST["bulk_write"] and pkt.id == BROADCAST_ID:
            k = 0
            while k + 5 <= len(p):
                t, addr, n = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
                if t in self.servos:
                    self.servos[t].write(addr, p[k + 5:k + 5 + n])
                k += 5 + n
            return []
        if reply_ok and targets:
            return [encode_status(pkt.id, self.servos[pkt.id].status_error(ERR["instruction"]))]
        return []


class BusTransport:
    """An in-process :class:`DynamixelBus` as a byte transport (``write``/``read``/...).

    Replies are available as soon as the instruction is written; ``read`` waits only for
    replies held back by the ``late_s`` fault (up to its timeout), so a dropped reply is an
    instant timeout. ``reset_input`` drops only what has arrived: held-back replies still
    arrive later, as on a real line. For fast unit tests; timing-faithful tests use the process
    emulator on a pty.
    """

    def __init__(self, bus: DynamixelBus) -> None:
        self.bus = bus
        self._rx = bytearray()
        self.closed = False
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        if self.closed:
            raise OSError(5, "bus transport closed")
        self.written.append(bytes(data))
        self._rx += self.bus.handle(bytes(data))

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        if self.closed:
            raise OSError(5, "bus transport closed")
        self._rx += self.bus.take_due()
        if len(self._rx) < n and self.bus.later:
            end = time.monotonic() + timeout
            while len(self._rx) < n and self.bus.later and time.monotonic() < end:
                nxt = self.bus.next_due() or end
                time.sleep(max(0.0, min(nxt, end) - time.monotonic()))
                self._rx += self.bus.take_due()
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    @property
    def in_waiting(self) -> int:
        self._rx += self.bus.take_due()
        return len(self._rx)

    def reset_input(self) -> None:
        self._rx += self.bus.take_due()
        self._rx.clear()

    def close(self) -> None:
        self.closed = True


class PtyBusThread:
    """Thread mode: serve a :class:`DynamixelBus` on a fresh pty from a thread of this process.

    Convenient when a test wants the bus object itself at hand (``.bus``: faults, hardware
    errors, state). Timing is worse than the process mode (the SDK's busy-poll competes for
    the GIL), so prefer :func:`start_bus` for timing-sensitive work. :meth:`kill` closes the
    master side: the port vanishes as if the device were unplugged.
    """

    def __init__(self, bus: DynamixelBus) -> None:
        import threading

        self.bus = bus
        self._master, self._slave, self.port = open_pty()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"dxl-bus {self.port}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                due = self.bus.next_due()
                wait = 0.05 if due is None else max(0.0, min(0.05, due - time.monotonic()))
                r, _, _ = select.select([self._master], [], [], wait)
                if not r:
                    with self._lock:
                        late = self.bus.take_due()
                    if late:
                        write_all(self._master, late)
                    continue
                data = os.read(self._master, 4096)
            except BlockingIOError:
                continue
            except (OSError, ValueError):
                return
            with self._lock:
                reply = self.bus.handle(data)
            if reply:
                if self.bus.faults.delay_s:
                    time.sleep(self.bus.faults.delay_s)
                try:
                    write_all(self._master, reply)
                except OSError:
                    return

    def state(self) -> dict[str, Any]:
        with self._lock:
            return self.bus.state()

    def kill(self) -> None:
        """Close the pty (both sides held here): the client's port vanishes."""
        self._stop.set()
        self._thread.join(timeout=2)
        close_quietly((self._master, self._slave))

    close = kill

    def __enter__(self) -> "PtyBusThread":
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()
