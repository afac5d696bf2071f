"""Dynamixel: the packet codec, the bus emulator, and the arm driver (scripted, in-process,
and end to end through the real dynamixel-sdk against the emulator process on a pty).

Re-record the committed session fixture with ``python tests/test_dynamixel.py --record``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupBulkRead, GroupSyncRead, PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.core.errors import (ChecksumError, ConfigError, DeviceTimeoutError, FaultLatchedError,
                               GeometryError, HardwareError, PortGoneError, ProtocolError)
from bench.core.geometry import Geometry
from bench.core.conformance import angular_distance_deg, check_conformance
from drivers.dynamixel import ArmConfig, AxisConfig, DynamixelArm, decode_hardware_error
from drivers.kinematics import JOINTS
from drivers.transport import (
    RecordingTransport,
    ScriptedTransport,
    SerialTransport,
    TransportPortHandler,
    load_fixture,
)
from tests.helpers.clock import FakeClock, WaitingTransport
from virtual.wire.dynamixel_bus import BusControl, start_bus
from virtual.wire.dxl_bus import BusTransport, DynamixelBus
from virtual.wire._dxl_codec import (PacketError, PacketParser, crc16, decode_packet, encode_instruction,
                                    encode_status, stuff, unstuff)

ROOT = Path(__file__).resolve().parents[1]
SESSION_FIXTURE = ROOT / "fixtures" / "dynamixel" / "move_session.jsonl"

AXES: dict[str, dict[str, Any]] = {
    "turntable": {"id": 1, "limits": [-170, 170]},
    "source": {"id": 2, "limits": [0, 85]},
    "detector_azimuth": {"id": 3, "zero_offset": 0, "limits": [0, 359.9]},
    "detector_elevation": {"id": 4, "limits": [0, 85]},
}
EMU_AXES = {j: {"id": a["id"], "zero_offset": a.get("zero_offset", 2048)} for j, a in AXES.items()}


def arm_config(port: str = "", **kw: Any) -> dict[str, Any]:
    return {"port": port, "axes": AXES, "settle_timeout_s": 3.0, "poll_interval_s": 0.005, **kw}


REACHABLE = [Geometry.in_plane(45.0, 45.0), Geometry(45.0, 0.0, 0.0, 0.0),
             Geometry.in_plane(30.0, -10.0), Geometry(60.0, 120.0, 70.0, 10.0)]
UNREACHABLE = [Geometry(95.0, 0.0, 10.0, 0.0),     # source below the specimen plane
               Geometry(30.0, 0.0, 88.0, 180.0),   # detector beyond its joint limit
               Geometry(30.0, 0.0, 31.0, 1.0),     # detector blocks the beam (retro)
               Geometry(30.0, 0.0, 60.0, 0.0)]     # detector hits the source arm


class Spy:
    """Transport wrapper that logs writes (to prove that nothing reached the port)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))
        self.inner.write(data)

    def read(self, n: int, timeout: float) -> bytes:
        return self.inner.read(n, timeout)

    def reset_input(self) -> None:
        self.inner.reset_input()

    def close(self) -> None:
        self.inner.close()


# --- codec ---------------------------------------------------------------------------------


def test_crc_and_reference_vectors() -> None:
    assert crc16(b"123456789") == 0xFEE8
    assert encode_instruction(1, 0x01) == bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
    assert encode_instruction(1, 0x03, bytes.fromhex("74 00 00 02 00 00")) == \
        bytes.fromhex("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")
    assert encode_instruction(1, 0x02, bytes.fromhex("84 00 04 00")) == \
        bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")
    assert encode_instruction(1, 0x03, bytes.fromhex("40 00 01")) == \
        bytes.fromhex("FF FF FD 00 01 06 00 03 40 00 01 DB 66")


def test_stuffing_examples() -> None:
    assert stuff(bytes.fromhex("03 FF FF FD 01")) == bytes.fromhex("03 FF FF FD FD 01")
    pkt = encode_instruction(7, 0x03, bytes.fromhex("74 00 FF FF FD FF"))
    assert b"\xff\xff\xfd\xfd" in pkt[7:]
    p = decode_packet(pkt)
    assert (p.id, p.instruction, p.params) == (7, 0x03, bytes.fromhex("74 00 FF FF FD FF"))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40), st.integers(0, 0xFD), st.integers(0, 255))
def test_codec_round_trip(params: bytes, dev_id: int, inst: int) -> None:
    assert unstuff(stuff(params)) == params
    pkt = encode_instruction(dev_id, inst, params)
    p = decode_packet(pkt)
    assert (p.id, p.instruction, p.params) == (dev_id, inst, params)
    parser = PacketParser()
    out = []
    for i in range(0, len(pkt), 3):  # arrives in pieces, after some noise
        out += parser.feed((b"\x00\xff" if i == 0 else b"") + pkt[i:i + 3])
    assert [(q.id, q.instruction, q.params) for q in out] == [(dev_id, inst, params)]


def test_decode_rejects_bad_packets() -> None:
    pkt = encode_status(1, 0, b"\x01\x02")
    with pytest.raises(PacketError, match="CRC"):
        decode_packet(pkt[:-1] + bytes([pkt[-1] ^ 1]))
    with pytest.raises(PacketError, match="length"):
        decode_packet(pkt + b"\x00")
    parser = PacketParser()
    bad = pkt[:-1] + bytes([pkt[-1] ^ 1])
    assert [p.data for p in parser.feed(bad + pkt)] == [b"\x01\x02"]
    assert parser.crc_errors == 1


# --- emulator model (in process, through the real SDK) --------------------------------------


def sdk_on(bus: DynamixelBus) -> tuple[TransportPortHandler, Any]:
    return TransportPortHandler(BusTransport(bus)), PacketHandler(2.0)


def test_emulator_ping_read_write_and_eeprom_lock() -> None:
    bus = DynamixelBus((1, 2))
    port, pk = sdk_on(bus)
    assert pk.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    assert pk.ping(port, 9)[1] != COMM_SUCCESS
    assert pk.read2ByteTxRx(port, 2, 0) == (1020, COMM_SUCCESS, 0)
    assert pk.write1ByteTxRx(port, 1, 11, 4) == (COMM_SUCCESS, 0)  # torque off: EEPROM writable
    assert pk.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    assert pk.write1ByteTxRx(port, 1, 11, 3) == (COMM_SUCCESS, 7)  # access error under torque
    assert pk.read1ByteTxRx(port, 1, 11) == (4, COMM_SUCCESS, 0)
    assert pk.write1ByteTxRx(port, 1, 0, 1)[1] == 7  # model number is read-only
    assert pk.write4ByteTxRx(port, 2, 116, 5000) == (COMM_SUCCESS, 6)  # beyond Max Position Limit


def test_emulator_finite_speed_motion_and_moving_flag() -> None:
    clock = FakeClock()
    bus = DynamixelBus((1,), clock=clock)
    port, pk = sdk_on(bus)
    pk.write4ByteTxRx(port, 1, 112, 100)  # 22.9 rpm = 1563.3 ticks/s
    pk.write1ByteTxRx(port, 1, 64, 1)
    pk.write4ByteTxRx(port, 1, 116, 3048)
    clock.sleep(0.5)
    pos, _, _ = pk.read4ByteTxRx(port, 1, 132)
    assert pos == round(2048 + 0.5 * 100 * 0.229 / 60 * 4096)
    assert pk.read1ByteTxRx(port, 1, 122)[0] == 1
    assert pk.read1ByteTxRx(port, 1, 123)[0] & 0x02
    clock.sleep(1.0)
    assert pk.read4ByteTxRx(port, 1, 132)[0] == 3048
    assert pk.read1ByteTxRx(port, 1, 122)[0] == 0
    assert pk.read1ByteTxRx(port, 1, 123)[0] & 0x01


def test_emulator_hardware_error_alert_and_reboot() -> None:
    bus = DynamixelBus((1, 2))
    port, pk = sdk_on(bus)
    pk.write1ByteTxRx(port, 1, 64, 1)
    bus.hardware_error(1, 1 << 5)
    v, comm, err = pk.read1ByteTxRx(port, 1, 70)
    assert (v, comm) == (0x20, COMM_SUCCESS) and err & 0x80
    assert pk.read1ByteTxRx(port, 1, 64)[0] == 0  # torque off
    assert pk.ping(port, 2)[2] == 0
    assert pk.reboot(port, 1) == (COMM_SUCCESS, 0)
    assert pk.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)


def test_emulator_sync_and_bulk_read() -> None:
    bus = DynamixelBus((1, 2, 3), positions={1: 100, 2: 200, 3: 300})
    port, pk = sdk_on(bus)
    g = GroupSyncRead(port, pk, 132, 4)
    for i in (3, 1):
        g.addParam(i)
    assert g.txRxPacket() == COMM_SUCCESS
    assert (g.getData(1, 132, 4), g.getData(3, 132, 4)) == (100, 300)
    b = GroupBulkRead(port, pk)
    b.addParam(2, 132, 4)
    b.addParam(1, 0, 2)
    assert b.txRxPacket() == COMM_SUCCESS
    assert (b.getData(2, 132, 4), b.getData(1, 0, 2)) == (200, 1020)


# --- driver config -------------------------------------------------------------------------


def test_config_from_dict_and_errors() -> None:
    cfg = ArmConfig.from_dict(arm_config("loop://"))
    assert [a.joint for a in cfg.axis_list()] == list(JOINTS)
    assert cfg.kinematics.limits["turntable"] == (-170.0, 170.0)
    ax = cfg.axes["detector_azimuth"]
    assert ax.to_ticks(90.0) == 1024 and ax.to_degrees(1024) == 90.0
    geared = AxisConfig("turntable", 1, direction=-1, gear_ratio=3.0, operating_mode=4)
    assert geared.to_ticks(10.0) == 2048 - round(10 * 3 * 4096 / 360)
    with pytest.raises(ConfigError, match="missing joint"):
        ArmConfig.from_dict({"axes": {"turntable": {"id": 1}}})
    with pytest.raises(ConfigError, match="distinct"):
        ArmConfig.from_dict({"axes": {j: {"id": 1} for j in JOINTS}})
    with pytest.raises(ConfigError, match="unknown key"):
        ArmConfig.from_dict({"axes": {**AXES, "source": {"id": 2, "speed": 3}}})
    with pytest.raises(ConfigError, match="outside 0..4095"):
        ArmConfig.from_dict({"axes": {**AXES, "turntable": {"id": 1, "limits": [-180, 180]}}})
    # without explicit limits, mode 3 narrows the kinematics limits to the tick range
    plain = ArmConfig.from_dict({"axes": {j: {"id": i} for i, j in enumerate(JOINTS, 1)}})
    assert plain.kinematics.limits["turntable"] == (-180.0, 2047 * 360 / 4096)
    assert plain.kinematics.limits["source"] == (0.0, 85.0)
    with pytest.raises(ConfigError, match="operating_mode"):
        ArmConfig.from_dict({"axes": {**AXES, "source": {"id": 2, "operating_mode": 1}}})
    with pytest.raises(ConfigError, match="arm config: unknown key 'speed'"):
        ArmConfig.from_dict({**arm_config(), "speed": 1})
    with pytest.raises(ConfigError, match="arm config: key retries: input should be greater than or equal to 0"):
        ArmConfig.from_dict({**arm_config(), "retries": -1})
    with pytest.raises(ConfigError, match="arm config: key tolerance_deg: expected a finite number"):
        ArmConfig.from_dict({**arm_config(), "tolerance_deg": float("nan")})
    with pytest.raises(ConfigError, match=r"arm config: key external\[0\]: input should be 'turntable'"):
        ArmConfig.from_dict({**arm_config(), "external": ["elbow"]})
    assert decode_hardware_error(0x24) == ["overheating", "overload"]


# --- driver against the in-process bus (fast, deterministic faults) ---------------------------


@pytest.fixture
def bus() -> DynamixelBus:
    return DynamixelBus((1, 2, 3, 4), time_scale=50.0, axes=EMU_AXES)


def make_arm(bus: DynamixelBus, **kw: Any) -> tuple[DynamixelArm, Spy]:
    spy = Spy(BusTransport(bus))
    return DynamixelArm(arm_config(**kw), transport=spy), spy


def test_connect_writes_eeprom_only_with_torque_off(bus: DynamixelBus) -> None:
    bus.servos[2].table[11] = 4  # wrong operating mode, and torque on
    bus.servos[2].table[64] = 1
    arm, _ = make_arm(bus)
    writes = [(p.id, p.params[0]) for p in bus.log if p.instruction == 0x03]
    # servo 3's limits (0..4095 ticks) and mode already match: its one EEPROM write is the
    # Return Delay Time (9) the emulator powers up without (0, the config says 500 us)
    assert [a for pid, a in writes if pid == 3 and a < 64] == [9]
    for i in (1, 2, 4):
        mine = [addr for pid, addr in writes if pid == i]
        eeprom = [k for k, a in enumerate(mine) if a < 64]
        assert eeprom, f"servo {i}: no EEPROM write"
        torque_off = mine.index(64)
        assert all(k > torque_off for k in eeprom)
        assert mine[-1] == 64  # torque on last
    assert all(s.table[64] == 1 and s.table[11] == 3 for s in bus.servos.values())
    assert bus.servos[1].get(52, 4) == round(2048 - 170 * 4096 / 360)
    arm.close()


def test_move_and_readback(bus: DynamixelBus) -> None:
    arm, _ = make_arm(bus)
    g = Geometry(45.0, 30.0, 30.0, 200.0)
    reached = arm.move_to(g)
    assert angular_distance_deg(reached, g) < 0.1
    assert bus.state()["joints"]["source"] == pytest.approx(45.0, abs=0.09)
    assert angular_distance_deg(arm.position(), reached) < 1e-9
    arm.stop()
    arm.close()
    arm.close()


def test_bad_geometry_refused_before_any_byte(bus: DynamixelBus) -> None:
    arm, spy = make_arm(bus)
    n = len(spy.written)
    for g, rule in zip(UNREACHABLE, ("source_hemisphere", "joint_limit", "beam_block", "arm_collision")):
        for call in (arm.check, arm.move_to):
            with pytest.raises(GeometryError) as ei:
                call(g)
            assert ei.value.geometry is g and str(ei.value).startswith(rule), str(ei.value)
    assert len(spy.written) == n
    assert arm.fault is None  # bad input is not a device fault
    arm.close()


@pytest.mark.parametrize("fault, counted", [({"drop_next": 2}, ("dropped", 2)), ({"corrupt_next": 1}, ("corrupted", 1))])
def test_a_dropped_or_corrupt_reply_is_retried(bus: DynamixelBus, fault: dict, counted: tuple) -> None:
    arm, _ = make_arm(bus)
    bus.set_faults(**fault)
    arm.move_to(REACHABLE[0])
    assert getattr(bus.faults, counted[0]) == counted[1]
    arm.close()


def test_no_reply_is_a_timeout_then_latched() -> None:
    clock = FakeClock()
    bus = DynamixelBus((1, 2, 3, 4), clock=clock, time_scale=50.0, axes=EMU_AXES)
    wire = WaitingTransport(BusTransport(bus), clock)  # a silent line waits out each read's timeout
    spy = Spy(wire)
    arm = DynamixelArm(arm_config(retries=2), transport=spy, clock=clock, sleep=clock.sleep)
    bus.set_faults(hang=True)
    start = clock.now
    with pytest.raises(DeviceTimeoutError, match="after 3 attempt"):
        arm.move_to(REACHABLE[0])
    # three attempts, each waiting out the SDK's packet timeout of the sync read (35.24 ms at
    # 1 Mbaud) and then one quiet-bus window (17.74 ms): bounded, and nothing else waited for
    assert wire.waits == pytest.approx([0.03524, 0.01774] * 3)
    assert clock.now - start == pytest.approx(sum(wire.waits))
    n = len(spy.written)
    with pytest.raises(FaultLatchedError, match="reset"):
        arm.move_to(REACHABLE[1])
    arm.stop()
    assert len(spy.written) == n
    bus.clear_faults()
    arm.reset()
    arm.move_to(REACHABLE[1])
    arm.close()


def test_every_reply_corrupt_is_a_checksum_error(bus: DynamixelBus) -> None:
    arm, _ = make_arm(bus)
    bus.set_faults(corrupt_rate=1.0)
    with pytest.raises(ChecksumError, match="corrupt"):
        arm.move_to(REACHABLE[1])
    with pytest.raises(FaultLatchedError):
        arm.move_to(REACHABLE[1])
    arm.close()


def test_overload_torque_off_latch_and_reset(bus: DynamixelBus) -> None:
    arm, spy = make_arm(bus)
    arm.move_to(REACHABLE[0])
    bus.hardware_error(2, 1 << 5, on_goal=True)  # the source servo overloads as it starts
    with pytest.raises(HardwareError) as ei:
        arm.move_to(REACHABLE[1])
    assert ei.value.flags == ["overload"] and ei.value.code == 0x20
    assert "servo 2 (source)" in str(ei.value)
    assert all(s.table[64] == 0 for s in bus.servos.values())  # torque off everywhere
    n = len(spy.written)
    with pytest.raises(FaultLatchedError, match="HardwareError"):
        arm.move_to(REACHABLE[2])
    arm.stop()
    assert len(spy.written) == n  # no motion byte after the fault
    arm.position()  # reading is still allowed
    arm.reset()  # reboots servo 2, re-applies settings, torque on
    assert bus.servos[2].hardware_error == 0
    reached = arm.move_to(REACHABLE[2])
    assert angular_distance_deg(reached, REACHABLE[2]) < 0.2
    arm.close()


def test_hardware_error_at_connect(bus: DynamixelBus) -> None:
    bus.hardware_error(4, 1 << 2)
    with pytest.raises(HardwareError, match="overheating"):
        make_arm(bus)
    arm = DynamixelArm(arm_config(), transport=BusTransport(bus), connect=False)
    arm.reset()
    arm.move_to(REACHABLE[0])
    arm.close()


def _faked(**kw: Any) -> tuple[DynamixelBus, DynamixelArm, FakeClock]:
    """Bus and arm on one fake clock: the servos move, and the arm waits, only in its time."""
    clock = FakeClock()
    bus = DynamixelBus((1, 2, 3, 4), clock=clock, time_scale=50.0, axes=EMU_AXES)
    return bus, DynamixelArm(arm_config(**kw), transport=BusTransport(bus), clock=clock, sleep=clock.sleep), clock


def test_move_that_never_starts_is_reported_within_100_ms() -> None:
    """A servo that takes its goal but never moves (torque silently off) is
    reported by the start window (~100 ms), not after the whole settle timeout."""
    bus, arm, clock = _faked(settle_timeout_s=20.0)
    bus.servos[3].table[64] = 0  # torque silently off: the axis will never arrive
    with pytest.raises(DeviceTimeoutError, match=r"servo\(s\) 3 \(detector_azimuth\) did not start"):
        arm.move_to(REACHABLE[2])  # needs the detector azimuth (servo 3) to move
    assert 0.1 < clock.elapsed <= 0.1 + arm.config.poll_interval_s + 1e-9  # the window and one poll
    arm.close()


def test_settle_timeout() -> None:
    bus, arm, clock = _faked(settle_timeout_s=0.2)
    bus.servos[3].put("profile_velocity", 1)  # moves, but far too slowly to arrive in time
    bus.servos[3].time_scale = 1.0
    with pytest.raises(DeviceTimeoutError, match="did not settle"):
        arm.move_to(REACHABLE[2])
    assert 0.2 < clock.elapsed <= 0.2 + arm.config.poll_interval_s + 1e-9  # the timeout and one poll
    arm.close()


def test_wrong_model_is_a_protocol_error(bus: DynamixelBus) -> None:
    with pytest.raises(ProtocolError, match="model 1020, expected 1060"):
        make_arm(bus, model_number=1060)


def test_fault_latch_proved_by_a_scripted_replay(bus: DynamixelBus, tmp_path: Path) -> None:
    """Record a session that ends in an overload, replay it byte-exactly: after the
    HardwareError a motion command writes nothing (the script has no pair left for it)."""
    path = tmp_path / "overload.jsonl"

    def session(transport: Any, on_record: Any = None) -> None:
        arm = DynamixelArm(arm_config(), transport=transport, sleep=lambda s: None)
        arm.move_to(REACHABLE[0])
        if on_record:
            on_record()
        with pytest.raises(HardwareError):
            arm.move_to(REACHABLE[1])
        with pytest.raises(FaultLatchedError):
            arm.move_to(REACHABLE[2])
        arm.stop()
        arm.close()

    session(RecordingTransport(BusTransport(bus), path),
            on_record=lambda: bus.hardware_error(1, 1 << 5))
    pairs = load_fixture(path)
    replay = ScriptedTransport(pairs)
    session(replay)  # close() raises on any extra or missing byte
    assert replay.done and len(replay.written) == len(pairs)


# --- the committed, recorded session fixture -------------------------------------------------

SESSION_MOVES = [Geometry(45.0, 0.0, 30.0, 180.0), Geometry(30.0, 90.0, 50.0, 300.0)]


def run_session(arm: DynamixelArm) -> list[Geometry]:
    out = [arm.position()]
    for g in SESSION_MOVES:
        out.append(arm.move_to(g))
    out.append(arm.position())
    arm.stop()
    return out


def record_session_fixture(path: Path = SESSION_FIXTURE) -> None:
    """Record connect + two moves + position + stop against the emulator process."""
    with start_bus(time_scale=2.0) as emu:
        rec = RecordingTransport(SerialTransport(emu.port), path,
                                 note="DynamixelArm session against virtual.wire.dynamixel_bus "
                                      "(4 XM430, time_scale 2): connect, move_to x2, position, stop; "
                                      "config tests/test_dynamixel.py arm_config()")
        arm = DynamixelArm(arm_config(), transport=rec)
        run_session(arm)
        arm.close()


def test_recorded_session_replays_byte_exactly() -> None:
    pairs = load_fixture(SESSION_FIXTURE)
    st_ = ScriptedTransport(pairs)
    arm = DynamixelArm(arm_config(), transport=st_, sleep=lambda s: None)
    out = run_session(arm)
    arm.close()  # raises TransportMismatchError on leftovers
    assert st_.done
    for got, want in zip(out[1:3], SESSION_MOVES):
        assert angular_distance_deg(got, want) < 0.1
    # the moves went out as one sync write (0x83) of Goal Position (116) for 4 servos
    syncs = [s for s, _ in pairs if s[7] == 0x83 and s[8:10] == b"\x74\x00"]
    assert len(syncs) == 3 and all(s[10:12] == b"\x04\x00" for s in syncs)
    # the other sync writes set Status Return Level (68) on open, one servo each
    levels = [s for s, _ in pairs if s[7] == 0x83 and s[8:10] != b"\x74\x00"]
    assert len(levels) == 4 and all(s[8:10] == b"\x44\x00" for s in levels)


# --- end to end: the real SDK against the emulator process on a pty -----------------------------


@pytest.fixture
def emulator() -> Iterator[Any]:
    emu = start_bus(time_scale=4.0, axes=EMU_AXES)
    try:
        yield emu
    finally:
        emu.close()


def test_e2e_conformance(emulator: Any) -> None:
    arm = DynamixelArm(arm_config(emulator.port))
    try:
        roles = check_conformance(arm, reachable=REACHABLE, unreachable=UNREACHABLE, tol_deg=0.2)
        assert roles == ["Instrument", "Goniometer"]
    finally:
        arm.close()


def test_e2e_joint_state_hook(emulator: Any) -> None:
    arm = DynamixelArm(arm_config(emulator.port))
    arm.move_to(Geometry(40.0, 20.0, 25.0, 250.0))
    with BusControl(emulator.control) as ctl:
        joints = ctl.joints()
    for name, v in arm.joints().as_dict().items():
        assert joints[name] == pytest.approx(v, abs=1e-9)
    arm.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_dropped_and_corrupt_replies(emulator: Any) -> None:
    arm = DynamixelArm(arm_config(emulator.port, retries=2))
    with BusControl(emulator.control) as ctl:
        ctl.faults(drop_next=1, corrupt_next=1)
        arm.move_to(REACHABLE[0])  # retried
        assert ctl.faults()["faults"]["dropped"] == 1
        ctl.faults(corrupt_rate=1.0)
        with pytest.raises(ChecksumError):
            arm.move_to(REACHABLE[1])
        with pytest.raises(FaultLatchedError):
            arm.move_to(REACHABLE[1])
        ctl.clear()
        arm.reset()  # latched by the checksum error
        arm.move_to(REACHABLE[1])
    arm.close()


def test_e2e_overload(emulator: Any) -> None:
    spy = Spy(SerialTransport(emulator.port))
    arm = DynamixelArm(arm_config(emulator.port), transport=spy)
    arm.move_to(REACHABLE[0])
    with BusControl(emulator.control) as ctl:
        ctl.hardware_error(3, 1 << 5)
        with pytest.raises(HardwareError) as ei:
            arm.move_to(REACHABLE[1])
        assert ei.value.flags == ["overload"]
        assert all(s["torque"] == 0 for s in ctl.state()["servos"].values())
        n = len(spy.written)
        with pytest.raises(FaultLatchedError):
            arm.move_to(REACHABLE[1])
        arm.stop()
        assert len(spy.written) == n
        arm.reset()
        assert angular_distance_deg(arm.move_to(REACHABLE[1]), REACHABLE[1]) < 0.2
        assert ctl.state()["servos"]["3"]["hardware_error"] == 0
    arm.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_killed_emulator(emulator: Any) -> None:
    arm = DynamixelArm(arm_config(emulator.port))
    arm.move_to(REACHABLE[0])
    emulator.kill()
    with pytest.raises((PortGoneError, DeviceTimeoutError)):
        arm.move_to(REACHABLE[1])
    with pytest.raises(FaultLatchedError):
        arm.move_to(REACHABLE[1])
    arm.close()


def _silent_bus(emulator: Any) -> None:
    with BusControl(emulator.control) as ctl:
        ctl.faults(hang=True)


def _death_by_control(emulator: Any) -> None:
    with BusControl(emulator.control) as ctl:
        ctl.die()
    emulator.proc.wait(timeout=3)


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
@pytest.mark.parametrize("silence, call, raised", [
    # the bus stops answering: the driver's read times out, it does not wait forever
    (_silent_bus, lambda arm: arm.move_to(REACHABLE[0]), DeviceTimeoutError),
    # the emulator exits when told to: the port is gone (or, first, silent)
    (_death_by_control, lambda arm: arm.position(), (PortGoneError, DeviceTimeoutError)),
], ids=["silent-bus", "death-by-control"])
def test_e2e_a_line_that_stops_answering_raises_a_typed_error(emulator: Any, silence: Callable[[Any], None],
                                                              call: Callable[[DynamixelArm], object],
                                                              raised: Any) -> None:
    arm = DynamixelArm(arm_config(emulator.port))
    silence(emulator)
    with pytest.raises(raised):
        call(arm)
    arm.close()


def test_default_axes_reach_the_specular_direction() -> None:
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0)
    cfg = {"axes": {j: {"id": i} for i, j in enumerate(JOINTS, 1)}, "poll_interval_s": 0.002}
    arm = DynamixelArm(cfg, transport=BusTransport(bus))
    g = Geometry.in_plane(45.0, 45.0, phi_i=180.0)  # detector azimuth 180 = tick -180 deg
    assert angular_distance_deg(arm.move_to(g), g) < 0.1
    arm.close()


def test_emulator_exits_when_its_parent_dies() -> None:
    import os
    import subprocess

    code = ("import os, sys; from virtual.wire.dynamixel_bus import start_bus; "
            "e = start_bus(); print(e.pid, flush=True); os._exit(0)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=20)
    pid = int(out.stdout.split()[0])
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    os.kill(pid, 9)
    pytest.fail("an orphaned emulator kept running")


def test_record_against_the_emulator_then_replay(emulator: Any, tmp_path: Path) -> None:
    """RecordingTransport over a live pty session yields a fixture that replays byte-exactly."""
    path = tmp_path / "live.jsonl"
    arm = DynamixelArm(arm_config(emulator.port),
                       transport=RecordingTransport(SerialTransport(emulator.port), path))
    live = run_session(arm)
    arm.close()
    replay = ScriptedTransport(load_fixture(path))
    arm = DynamixelArm(arm_config(), transport=replay, sleep=lambda s: None)
    assert run_session(arm) == live
    arm.close()
    assert replay.done


def test_thread_mode_pty() -> None:
    from virtual.wire.dxl_bus import PtyBusThread

    with PtyBusThread(DynamixelBus((1, 2, 3, 4), time_scale=20.0, axes=EMU_AXES)) as srv:
        arm = DynamixelArm(arm_config(srv.port))
        g = Geometry.in_plane(50.0, 20.0)
        assert angular_distance_deg(arm.move_to(g), g) < 0.1
        assert srv.state()["joints"]["source"] == pytest.approx(50.0, abs=0.09)
        srv.bus.hardware_error(4, 1 << 4)
        with pytest.raises(HardwareError, match="electrical_shock"):
            arm.position()
        srv.kill()
        with pytest.raises(PortGoneError):
            arm.reset()
        arm.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_late_replies_time_out_and_leave_no_stale_bytes(emulator: Any) -> None:
    """Replies later than the SDK's packet timeout count as timeouts; once the bus is prompt
    again the stale late bytes (dropped before each send) do not confuse the next exchange."""
    arm = DynamixelArm(arm_config(emulator.port, retries=1))
    with BusControl(emulator.control) as ctl:
        # far beyond the SDK's 2 * 16 ms + 2 ms, so that even on a loaded machine the late
        # reply to one attempt cannot land inside the next attempt's window
        ctl.faults(delay_s=0.5)
        with pytest.raises(DeviceTimeoutError):
            arm.position()
        ctl.clear()  # answered after the emulator has sent both late replies
    time.sleep(0.05)
    arm.reset()
    g = Geometry.in_plane(20.0, 40.0)
    assert angular_distance_deg(arm.move_to(g), g) < 0.1
    arm.close()


if __name__ == "__main__":
    if "--record" in sys.argv:
        record_session_fixture()
        print(f"recorded {SESSION_FIXTURE} ({len(load_fixture(SESSION_FIXTURE))} pairs)")
