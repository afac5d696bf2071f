"""Request/reply discipline of the Dynamixel driver: late or corrupt statuses, verified motion.

Held to the manual's packet rules (ROBOTIS e-Manual, DYNAMIXEL Protocol 2.0), not to our
emulator: a status answers one request (id, instruction 0x55, parameter length, the ids of a
sync read); late statuses of an aborted SYNC_READ must never be taken for later answers; a
Hardware Error Status is acted on only when two clean reads confirm it; a lost SYNC_WRITE
broadcast is found by reading back and re-sent once; a move that never starts is reported
within ~100 ms.
"""

from __future__ import annotations

from typing import Any

import pytest

from bench.core.errors import (
    BenchError,
    ChecksumError,
    CommunicationError,
    DeviceTimeoutError,
    FaultLatchedError,
    HardwareError,
    ProtocolError,
)
from bench.core.geometry import Geometry
from bench.core.conformance import angular_distance_deg
from drivers.dynamixel import DynamixelArm
from drivers.dynamixel._link import DxlLink, Request, check_status, decode_status
from drivers.transport import ScriptedTransport, TransportPortHandler
from tests.helpers.clock import FakeClock
from virtual.wire._dxl_codec import INST, encode_instruction, encode_status
from virtual.wire.dxl_bus import BusTransport, DynamixelBus

AXES = {"turntable": {"id": 1, "limits": [-170, 170]}, "source": {"id": 2, "limits": [0, 85]},
        "detector_azimuth": {"id": 3, "zero_offset": 0, "limits": [0, 359.9]},
        "detector_elevation": {"id": 4, "limits": [0, 85]}}
MOVES = [Geometry.in_plane(45.0, 45.0), Geometry(45.0, 0.0, 0.0, 0.0),
         Geometry.in_plane(30.0, -10.0), Geometry(60.0, 120.0, 70.0, 10.0)]


def cfg(**kw: Any) -> dict[str, Any]:
    return {"axes": AXES, "settle_timeout_s": 3.0, "poll_interval_s": 0.002, **kw}


def read_instr(dev: int, addr: int, n: int) -> bytes:
    return encode_instruction(dev, INST["read"], bytes([addr & 0xFF, addr >> 8, n & 0xFF, n >> 8]))


# --- the pure check: a status answers exactly one request ----------------------------------------


def test_a_sync_read_status_is_not_the_answer_to_a_one_byte_read() -> None:
    """The observed failure: a 14-byte SYNC_READ status (Moving byte 0x01 first) taken as the
    answer to READ Hardware Error Status (1 byte)."""
    stale = encode_status(1, 0, bytes([1]) + bytes(13))
    with pytest.raises(ProtocolError, match="14 parameter byte.*expected 1"):
        decode_status(stale, Request("read 70", 1, 1))
    assert decode_status(encode_status(1, 0, b"\x00"), Request("read 70", 1, 1)) == (b"\x00", 0)


def test_a_ping_status_is_not_a_read_answer_and_ids_must_match() -> None:
    ping = encode_status(1, 0, bytes([0xFC, 0x03, 0x2A]))  # model 1020: would read as error 0xFC
    with pytest.raises(ProtocolError, match="3 parameter"):
        decode_status(ping, Request("read 70", 1, 1))
    with pytest.raises(ProtocolError, match="from id 2, expected id 1"):
        decode_status(encode_status(2, 0, b"\x00"), Request("read 70", 1, 1))
    instr = read_instr(1, 70, 1)  # an instruction echoed back is not a status
    with pytest.raises((ProtocolError, ChecksumError)):
        decode_status(instr, Request("read 70", 1, 4))


def test_crc_bytes_are_never_data_and_short_frames_are_errors() -> None:
    good = encode_status(1, 0, b"\x10\x20\x30\x40")
    req = Request("read 132", 1, 4)
    assert decode_status(good, req) == (b"\x10\x20\x30\x40", 0)
    for cut in range(1, len(good)):
        with pytest.raises(ChecksumError):
            decode_status(good[:-cut], req)
    bad = bytearray(good)
    bad[-1] ^= 0x5A
    with pytest.raises(ChecksumError, match="CRC"):
        decode_status(bytes(bad), req)
    # a frame whose length field claims fewer parameters: never padded with CRC bytes
    short = encode_status(1, 0, b"\x10\x20")
    with pytest.raises(ProtocolError, match="2 parameter"):
        decode_status(short, req)
    with pytest.raises(ProtocolError):
        check_status(list(short), req)


# --- byte-exact: the link discards a mismatched status, waits quiet, flushes, retries ---------


def test_scripted_stale_status_is_discarded_then_retried_byte_exactly() -> None:
    req = read_instr(1, 70, 1)
    stale = encode_status(1, 0, bytes([1]) + bytes(19))   # a late 20-byte sync-read status
    pairs = [(req, stale), (req, encode_status(1, 0, b"\x00"))]
    t = ScriptedTransport(pairs)
    link = DxlLink(TransportPortHandler(t), 1_000_000, retries=2, latency_s=0.001)
    assert link.read(1, 70, 1, "read 70") == (b"\x00", 0)
    assert link.recoveries == 1
    t.close()  # raises on any byte not sent or not read
    assert t.done


def test_scripted_late_statuses_after_corrupt_one_are_swallowed_before_the_retry() -> None:
    """A SYNC_READ of ids 1..4 whose second status is corrupt: the remaining two statuses are
    still on the line; the link reads them away in its quiet wait (never as answers), then the
    retried SYNC_READ gets four fresh statuses."""
    instr = encode_instruction(0xFE, INST["sync_read"], bytes([132, 0, 4, 0, 1, 2, 3, 4]))
    st = [encode_status(i, 0, (1000 + i).to_bytes(4, "little")) for i in (1, 2, 3, 4)]
    bad = bytearray(st[1])
    bad[-1] ^= 0x5A
    pairs = [(instr, st[0] + bytes(bad) + st[2] + st[3]), (instr, b"".join(st))]
    t = ScriptedTransport(pairs)
    link = DxlLink(TransportPortHandler(t), 1_000_000, retries=1, latency_s=0.001)
    got = link.sync_read(132, 4, [1, 2, 3, 4], "sync read 132+4")
    assert {i: int.from_bytes(d, "little") for i, (d, _) in got.items()} == \
        {1: 1001, 2: 1002, 3: 1003, 4: 1004}
    assert link.discarded == len(st[2]) + len(st[3])
    t.close()


def test_sync_read_statuses_must_come_from_the_listed_ids_in_order() -> None:
    instr = encode_instruction(0xFE, INST["sync_read"], bytes([132, 0, 4, 0, 1, 2]))
    st1, st2 = (encode_status(i, 0, bytes(4)) for i in (1, 2))
    t = ScriptedTransport([(instr, st2 + st1), (instr, st1 + st1)])  # wrong order, duplicate
    link = DxlLink(TransportPortHandler(t), 1_000_000, retries=1, latency_s=0.001)
    with pytest.raises(ProtocolError, match="expected id"):
        link.sync_read(132, 4, [1, 2], "sync read")
    t.close()


# --- the arm on the emulator with late replies -------------------------------------------------


def test_late_replies_after_a_corrupt_sync_read_status_never_answer_later_requests() -> None:
    """A noisy bus reproduced: 20 % corrupt statuses, the rest of an aborted SYNC_READ
    arriving 3 ms late. Every call ends in success or a typed error, every reached geometry is
    right, no healthy servo is rebooted and no hardware error is invented."""
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0, seed=3)
    arm = DynamixelArm(cfg(retries=4, latency_s=0.004), transport=BusTransport(bus))
    bus.set_faults(corrupt_rate=0.2, late_s=0.003)
    ok = errors = 0
    for k in range(12):
        g = MOVES[k % len(MOVES)]
        try:
            assert angular_distance_deg(arm.move_to(g), g) < 0.2
            ok += 1
        except BenchError as exc:
            assert not isinstance(exc, HardwareError), exc
            errors += 1
            bus.set_faults(corrupt_rate=0.0)
            arm.reset()
            bus.set_faults(corrupt_rate=0.2)
    assert bus.faults.late > 0 and bus.faults.corrupted > 0
    assert ok >= 8
    assert not any(p.instruction == INST["reboot"] for p in bus.log)
    assert all(s.torque for s in bus.servos.values())
    arm.close()


def test_unconfirmed_hardware_error_is_not_acted_on() -> None:
    """An alert bit plus a single garbled read of address 70 proves nothing: with the second
    clean read at 0 the driver neither switches torque off nor reboots."""
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0)
    arm = DynamixelArm(cfg(), transport=BusTransport(bus))

    class Forge(BusTransport):
        forged = 0

        def write(self, data: bytes) -> None:
            super().write(data)
            if data == read_instr(2, 70, 1) and not Forge.forged:
                Forge.forged += 1
                self._rx[:] = encode_status(2, 0x80, b"\x01")  # out-of-order answer: 0x01

    t = Forge(bus)
    arm2 = DynamixelArm(cfg(), transport=t, connect=False)
    arm2._hardware_fault([2], "test")  # returns: not confirmed
    assert Forge.forged == 1
    assert all(s.torque for s in bus.servos.values())
    assert arm2.fault is None
    assert not any(p.instruction == INST["reboot"] for p in bus.log)
    arm.close()


def test_confirmed_hardware_error_reads_twice_then_acts() -> None:
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0)
    arm = DynamixelArm(cfg(), transport=BusTransport(bus))
    bus.hardware_error(2, 1 << 5)
    n = len(bus.log)
    with pytest.raises(HardwareError, match="overload"):
        arm.position()
    reads70 = [p for p in bus.log[n:] if p.instruction == INST["read"] and p.id == 2
               and p.params[:2] == bytes([70, 0])]
    assert len(reads70) == 2
    arm.reset()
    assert [p.id for p in bus.log if p.instruction == INST["reboot"]] == [2]
    arm.close()


# --- verified motion: a goal taken but never reached -----------------------------------------------


def _faked(**config: Any) -> tuple[DynamixelBus, DynamixelArm, FakeClock]:
    """Bus and arm on one fake clock: the servos move, and the arm waits, only in its time."""
    clock = FakeClock()
    bus = DynamixelBus((1, 2, 3, 4), clock=clock, time_scale=50.0)
    arm = DynamixelArm(cfg(**config), transport=BusTransport(bus), clock=clock, sleep=clock.sleep)
    return bus, arm, clock


def _move_seconds(drop: int) -> float:
    """Fake seconds the arm takes for MOVES[0] when the first ``drop`` sync writes are lost."""
    bus, arm, clock = _faked(settle_timeout_s=20.0)
    n, start = len(bus.log), clock.now
    bus.set_faults(drop_broadcast_next=drop)
    assert angular_distance_deg(arm.move_to(MOVES[0]), MOVES[0]) < 0.2
    writes = [p for p in bus.log[n:] if p.instruction == INST["sync_write"]]
    assert len(writes) == 1 + drop and writes[0].params == writes[-1].params
    assert bus.faults.dropped_broadcasts == drop
    arm.close()
    return clock.now - start


def test_lost_sync_write_is_read_back_and_resent_once() -> None:
    # the re-send follows the first read-back at once: the move takes what it takes without the
    # loss (in the fake time both servos and arm share), not a timeout more
    assert _move_seconds(1) <= _move_seconds(0) + cfg()["poll_interval_s"]


def test_twice_lost_sync_write_is_a_fault_long_before_the_settle_timeout() -> None:
    bus, arm, clock = _faked(settle_timeout_s=20.0)
    bus.set_faults(drop_broadcast_next=2)
    with pytest.raises(CommunicationError, match="did not land.*after 2 sends"):
        arm.move_to(MOVES[1])
    assert clock.elapsed <= cfg()["poll_interval_s"]  # decided by the two read-backs, no waiting
    with pytest.raises(FaultLatchedError):
        arm.move_to(MOVES[1])
    arm.reset()
    assert angular_distance_deg(arm.move_to(MOVES[1]), MOVES[1]) < 0.2
    arm.close()


def test_a_move_that_never_starts_is_reported_in_about_100_ms() -> None:
    bus, arm, clock = _faked(settle_timeout_s=20.0)
    bus.servos[1].put("torque_enable", 0)  # takes the goal, never moves
    with pytest.raises(DeviceTimeoutError, match="did not start moving within 0.1 s"):
        arm.move_to(Geometry(45.0, 90.0, 30.0, 180.0))
    # the start window (0.1 s) and at most one poll more, in the arm's own time
    assert 0.1 < clock.elapsed <= 0.1 + cfg()["poll_interval_s"] + 1e-9
    arm.close()


def test_e2e_late_statuses_on_the_pty_emulator() -> None:
    from virtual.wire.dynamixel_bus import BusControl, start_bus

    with start_bus(time_scale=8.0) as emu, BusControl(emu.control) as ctl:
        arm = DynamixelArm(cfg(port=emu.port, retries=4))
        ctl.faults(corrupt_next=1, late_s=0.004)
        g = arm.position()  # the first SYNC_READ: status 1 corrupt, 2..4 late
        assert ctl.faults()["faults"]["late"] == 3
        assert angular_distance_deg(arm.move_to(MOVES[0]), MOVES[0]) < 0.2
        assert g is not None
        arm.close()
