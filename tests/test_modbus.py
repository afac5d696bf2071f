"""Modbus stage axis: byte-exact framing, recorded-session replay, emulator end to end, faults.

Fixtures in ``fixtures/modbus/`` were recorded from the emulator with
``python tests/test_modbus.py --record`` (RTU on a pty, through a RecordingTransport).
"""

from __future__ import annotations

import math
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # for `python tests/test_modbus.py --record`
    sys.path.insert(0, str(ROOT))

from pymodbus.client import ModbusSerialClient  # noqa: E402
from pymodbus.framer import FramerRTU  # noqa: E402
from pymodbus.pdu import DecodePDU  # noqa: E402
from pymodbus.pdu.register_message import ReadHoldingRegistersRequest, WriteMultipleRegistersRequest  # noqa: E402

from bench.core.errors import (ChecksumError, ConfigError, DeviceTimeoutError, FaultLatchedError,  # noqa: E402
                               GeometryError, HardwareError, PortGoneError, ProtocolError,
                               TransportMismatchError)
from bench.core.conformance import check_conformance  # noqa: E402
from drivers.modbus import AxisConfig, ModbusStageAxis, StageAxis, TransportModbusClient  # noqa: E402
from drivers.registers import load_register_map  # noqa: E402
from drivers.transport import (  # noqa: E402
    RecordingTransport,
    ScriptedTransport,
    SerialTransport,
    load_fixture,
)
from tests.helpers.clock import FakeClock, WaitingTransport  # noqa: E402
from virtual.wire.modbus_stage import StageEmulator  # noqa: E402

FIX = ROOT / "fixtures" / "modbus"
READ_FEEDBACK = bytes.fromhex("01 03 01 20 00 02 C4 3D")
WRITE_M1000 = bytes.fromhex("01 10 18 02 00 02 04 FF FF FC 18 99 58")
#: axis settings used for the recordings and the replays (they must match)
AXIS = dict(steps_per_rev=1000, gear_ratio=10.0, speed=720.0, limits=(-170.0, 170.0),
            timeout_s=0.3, retries=1, poll_interval_s=0.01, parity="N")


def crc(frame: bytes) -> bytes:
    return FramerRTU.compute_CRC(frame).to_bytes(2, "big")


def rtu(hexstr: str) -> bytes:
    body = bytes.fromhex(hexstr)
    return body + crc(body)


# --- byte-exact framing: the reference test vectors -----------------------------------------


def test_pymodbus_rtu_framer_builds_the_reference_vectors() -> None:
    framer = FramerRTU(DecodePDU(False))
    read = ReadHoldingRegistersRequest(address=0x0120, count=2, dev_id=1)
    write = WriteMultipleRegistersRequest(address=0x1802, registers=[0xFFFF, 0xFC18], dev_id=1)
    assert framer.buildFrame(read) == READ_FEEDBACK
    assert framer.buildFrame(write) == WRITE_M1000


def test_pymodbus_client_sends_the_reference_vectors_over_a_scripted_transport() -> None:
    script = ScriptedTransport([
        (READ_FEEDBACK, rtu("01 03 04 FF FF FC 18")),
        (WRITE_M1000, rtu("01 10 18 02 00 02")),
    ])
    client = TransportModbusClient(script, timeout=0.2)
    regs = client.read_holding_registers(0x0120, count=2, device_id=1).registers
    assert client.convert_from_registers(regs, data_type=client.DATATYPE.INT32) == -1000
    words = client.convert_to_registers(-1000, data_type=client.DATATYPE.INT32)
    assert not client.write_registers(0x1802, words, device_id=1).isError()
    script.close()  # no leftovers
    assert script.written == [READ_FEEDBACK, WRITE_M1000]


def test_driver_produces_the_reference_vectors() -> None:
    script = ScriptedTransport([
        (READ_FEEDBACK, rtu("01 03 04 00 00 03 E8")),
        (WRITE_M1000, rtu("01 10 18 02 00 02")),
    ])
    axis = ModbusStageAxis(transport=script, steps_per_rev=1000, gear_ratio=1.0)
    assert axis.read_int32("feedback_position") == 1000
    axis._write(0x1802, axis.rmap.to_words(-1000))
    axis.close()  # closes the script: raises on leftovers


def test_scripted_mismatch_is_caught() -> None:
    script = ScriptedTransport([(READ_FEEDBACK, rtu("01 03 04 00 00 03 E8"))])
    axis = ModbusStageAxis(transport=script, device_id=2)
    with pytest.raises(TransportMismatchError, match="pair 0"):
        axis.position_deg()


def test_exception_response_names_function_address_and_code() -> None:
    req = rtu("01 03 03 00 00 02")
    script = ScriptedTransport([(req, rtu("01 83 02"))])
    axis = ModbusStageAxis(transport=script)
    with pytest.raises(ProtocolError) as ei:
        axis._read(0x0300, 2)
    msg = str(ei.value)
    assert "0x03" in msg and "0x0300" in msg and "code 2" in msg and "ILLEGAL DATA ADDRESS" in msg
    axis.close()


def test_missing_reply_is_a_bounded_timeout() -> None:
    clock = FakeClock()  # a silent line: each read waits out its whole timeout, in fake time
    line = WaitingTransport(ScriptedTransport([(READ_FEEDBACK, b""), (READ_FEEDBACK, b"")]), clock)
    axis = ModbusStageAxis(transport=line, retries=1, timeout_s=0.2, retry_delay_s=0.0)
    with pytest.raises(DeviceTimeoutError, match="2 attempt"):
        axis.position_deg()
    assert line.waits == [0.2, 0.2]  # two attempts, each waiting the configured timeout once
    axis.close()


def test_garbled_reply_is_a_checksum_error() -> None:
    bad = bytearray(rtu("01 03 04 00 00 03 E8"))
    bad[4] ^= 0xFF
    script = ScriptedTransport([(READ_FEEDBACK, bytes(bad)), (READ_FEEDBACK, bytes(bad))])
    axis = ModbusStageAxis(transport=script, retries=1, timeout_s=0.2, retry_delay_s=0.0)
    with pytest.raises(ChecksumError):
        axis.position_deg()
    axis.close()


# --- register map and conversions -------------------------------------------------------------


def test_register_map_is_data() -> None:
    rmap = load_register_map("oriental_az")
    assert rmap.addr("feedback_position") == 0x120
    assert rmap.direct_block == (0x58, 16)
    assert rmap.status_bits["IN-POS"] == 14 and rmap.input_bits["ALM-RST"] == 7
    assert rmap.to_words(-1000) == [0xFFFF, 0xFC18] and rmap.from_words([0xFFFF, 0xFC18]) == -1000
    assert rmap.alarm_name(0x30) == "overload"
    d = {"name": "other", "registers": dict(rmap.registers, feedback_position=0x200),
         "input_bits": dict(rmap.input_bits), "status_bits": dict(rmap.status_bits)}
    assert load_register_map(d).addr("feedback_position") == 0x200
    with pytest.raises(ConfigError, match="lacks"):
        load_register_map({"name": "x", "registers": {}, "input_bits": {}, "status_bits": {}})
    for bad, message in (({"word_order": "middle"}, "key word_order: input should be 'big' or 'little'"),
                         ({"input_bits": dict(rmap.input_bits, START=40)}, "key input_bits.START: .* less than or equal to 31 .got 40"),
                         ({"registers": dict(rmap.registers, direct_type=7)}, "must be consecutive 32-bit slots"),
                         ({"alarms": {"zz": "x"}}, "alarm codes are integers"),
                         ({"wordorder": "big"}, "unknown key 'wordorder'; did you mean 'word_order'")):
        with pytest.raises(ConfigError, match=f"^register map: .*{message}"):
            load_register_map({**d, **bad})
    with pytest.raises(ConfigError, match="no register map"):
        load_register_map("no_such_drive")


def test_conversion_and_limits() -> None:
    cfg = AxisConfig(steps_per_rev=1000, gear_ratio=18.0, limits=(-90.0, 90.0))
    assert cfg.steps_per_unit == pytest.approx(50.0)
    axis = ModbusStageAxis(transport=ScriptedTransport([]), config=cfg)
    assert axis.to_steps(45.0) == 2250 and axis.to_units(2250) == pytest.approx(45.0)
    for bad in (91.0, -90.5, math.nan, math.inf):
        with pytest.raises(GeometryError):
            axis.move_to_deg(bad)  # refused before any byte is sent
    with pytest.raises(ConfigError, match="unknown"):
        ModbusStageAxis(transport=ScriptedTransport([]), speeed=3)
    with pytest.raises(ConfigError):
        AxisConfig(gear_ratio=0)
    axis.close()


# --- recorded sessions replayed ---------------------------------------------------------------


def test_replay_recorded_move_session() -> None:
    pairs = load_fixture(FIX / "az_move_rtu.jsonl")
    script = ScriptedTransport(pairs)
    axis = ModbusStageAxis(transport=script, **AXIS)
    assert axis.position_deg() == pytest.approx(0.0)
    assert axis.move_to_deg(45.0) == pytest.approx(45.0, abs=0.05)
    assert axis.move_to_deg(-30.0) == pytest.approx(-30.0, abs=0.05)
    assert axis.position_deg() == pytest.approx(-30.0, abs=0.05)
    axis.stop()
    axis.close()
    # the first move starts with one FC16 write of the whole direct-data block
    writes = [s for s, _ in pairs if s[1] == 0x10 and s[2:4] == b"\x00\x58"]
    assert len(writes) == 2
    assert writes[0][6] == 32  # 16 registers, 32 bytes
    # position slot (3rd 32-bit value): 45 deg x 1000 steps x 10 / 360 deg = 1250 steps
    assert writes[0][7 + 8:7 + 12] == (1250).to_bytes(4, "big", signed=True)
    assert writes[1][7 + 8:7 + 12] == (-833).to_bytes(4, "big", signed=True)


def test_replay_recorded_fault_session() -> None:
    script = ScriptedTransport(load_fixture(FIX / "az_faults_rtu.jsonl"))
    axis = ModbusStageAxis(transport=script, **AXIS)
    # 1: a dropped reply, retried; 2: a corrupted reply (CRC), retried
    assert axis.position_deg() == pytest.approx(0.0)
    assert axis.position_deg() == pytest.approx(0.0)
    # 3: an exception response
    with pytest.raises(ProtocolError, match="code 2"):
        axis._read(0x0300, 2)
    # 4: an alarm present before the move: HardwareError, nothing triggered, fault latched
    with pytest.raises(HardwareError) as ei:
        axis.move_to_deg(20.0)
    assert ei.value.code == 0x30
    with pytest.raises(FaultLatchedError):
        axis.move_to_deg(20.0)  # no bytes: the script would fail on any write
    axis.reset_alarm()
    assert axis.move_to_deg(20.0) == pytest.approx(20.0, abs=0.05)
    axis.close()


# --- end to end against the emulator ----------------------------------------------------------


@pytest.fixture(scope="module", params=["tcp", "rtu"])
def emu(request: pytest.FixtureRequest):
    with StageEmulator.start(request.param) as e:
        yield e


@pytest.fixture()
def axis(emu: StageEmulator):
    emu.clear_faults()
    a = ModbusStageAxis(emu.url, **AXIS)
    if a.status()["alarm"]:
        a.reset_alarm()
    yield a
    a.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_move_reads_back_and_takes_time(axis: ModbusStageAxis, emu: StageEmulator) -> None:
    start = axis.position_deg()
    target = 90.0 if abs(start - 90.0) > 10 else -90.0
    t0 = time.monotonic()
    reached = axis.move_to_deg(target)
    dt = time.monotonic() - t0
    assert reached == pytest.approx(target, abs=0.05)
    assert axis.position_deg() == pytest.approx(reached, abs=1e-9)
    # finite speed: |target - start| at 720 deg/s
    assert dt >= 0.8 * abs(target - start) / 720.0
    st = axis.status()
    assert "IN-POS" in st["flags"] and "READY" in st["flags"] and "MOVE" not in st["flags"]


def test_e2e_conformance_and_describe(axis: ModbusStageAxis) -> None:
    assert isinstance(axis, StageAxis)
    assert check_conformance(axis) == ["Instrument"]   # an axis, deliberately not a Goniometer
    info = axis.describe()
    assert info.kind == "stage-axis" and info.ranges["position_deg"] == (-170.0, 170.0)


def test_e2e_limits_send_nothing(axis: ModbusStageAxis, emu: StageEmulator) -> None:
    before = emu.state()["triggers"]
    with pytest.raises(GeometryError, match="outside"):
        axis.move_to_deg(200.0)
    assert emu.state()["triggers"] == before


def test_e2e_exception_response(axis: ModbusStageAxis) -> None:
    with pytest.raises(ProtocolError, match=r"0x0300.*code 2"):
        axis._read(0x0300, 2)
    with pytest.raises(ProtocolError, match="code 2"):   # status is read-only
        axis.write_int32("output_status", 1)
    with pytest.raises(ProtocolError, match=r"0x10\).*0x0064.*code 3"):   # current > 100 %
        axis.write_int32("direct_current", 5000)


def test_e2e_unknown_unit_id_is_a_protocol_error(emu: StageEmulator) -> None:
    with ModbusStageAxis.from_config({"port": emu.url, "name": "turntable", "device_id": 7,
                                      **AXIS}) as other:
        with pytest.raises(ProtocolError, match="turntable.*device 7"):
            other.position_deg()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_dropped_and_corrupted_replies_are_retried(axis: ModbusStageAxis,
                                                       emu: StageEmulator) -> None:
    p = axis.position_deg()
    emu.drop_replies(1)
    assert axis.position_deg() == pytest.approx(p)
    emu.corrupt_replies(1)
    assert axis.position_deg() == pytest.approx(p)


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_persistent_corruption_and_silence_are_typed(axis: ModbusStageAxis,
                                                        emu: StageEmulator) -> None:
    emu.corrupt_replies(5)
    with pytest.raises((ChecksumError, DeviceTimeoutError)):
        axis.position_deg()
    emu.clear_faults()
    emu.silence()
    with pytest.raises(DeviceTimeoutError):
        axis.position_deg()
    emu.silence(False)
    axis.position_deg()  # recovered


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_e2e_alarm_during_move_latches_until_reset(axis: ModbusStageAxis,
                                                   emu: StageEmulator) -> None:
    start = axis.position_deg()
    target = -150.0 if start > 0 else 150.0
    timer = threading.Timer(0.1, emu.alarm, (0x30,))
    timer.start()
    with pytest.raises(HardwareError) as ei:
        axis.move_to_deg(target)
    timer.join()
    assert ei.value.code == 0x30 and "overload" in str(ei.value) and "ALM" in ei.value.flags
    st = emu.state()
    assert st["position"] != st["target"]  # the alarm stopped the drive short: seen during the move
    triggers = st["triggers"]
    with pytest.raises(FaultLatchedError):
        axis.move_to_deg(0.0)
    assert emu.state()["triggers"] == triggers  # no motion command after the fault
    axis.stop()  # stop is still allowed
    axis.reset_alarm()
    assert axis.fault is None
    assert axis.move_to_deg(0.0) == pytest.approx(0.0, abs=0.05)
    assert emu.state()["triggers"] == triggers + 1


def test_e2e_alarm_present_before_move(axis: ModbusStageAxis, emu: StageEmulator) -> None:
    emu.alarm(0x30)
    triggers = emu.state()["triggers"]
    with pytest.raises(HardwareError):
        axis.move_to_deg(10.0)
    assert emu.state()["triggers"] == triggers
    axis.reset_alarm()


def test_e2e_move_timeout_stops_and_latches(emu: StageEmulator) -> None:
    with ModbusStageAxis(emu.url, **dict(AXIS, speed=36.0, move_timeout_s=0.2)) as axis:
        if axis.status()["alarm"]:
            axis.reset_alarm()
        stops = emu.state()["stops"]
        target = 100.0 if axis.position_deg() < 50 else -100.0
        with pytest.raises(DeviceTimeoutError, match="not in position"):
            axis.move_to_deg(target)
        assert emu.state()["stops"] == stops + 1 and not emu.state()["moving"]
        with pytest.raises(FaultLatchedError):
            axis.move_to_deg(0.0)
        axis.reset_alarm()  # clears the latch once the drive reports no alarm


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_e2e_killed_emulator_is_port_gone(transport: str) -> None:
    with StageEmulator.start(transport) as e:
        axis = ModbusStageAxis(e.url, **AXIS)
        axis.position_deg()
        e.die()
        with pytest.raises((PortGoneError, DeviceTimeoutError)) as ei:
            axis.position_deg()
        assert isinstance(ei.value, PortGoneError), ei.value
        with pytest.raises(FaultLatchedError if axis.fault else PortGoneError):
            axis.move_to_deg(1.0)
        if transport == "rtu":   # a vanished serial port is never reopened by itself
            with pytest.raises(PortGoneError, match="not reopened"):
                axis.position_deg()
        axis.close()


def test_e2e_two_drives_share_one_rs485_line() -> None:
    with StageEmulator.start("rtu", extra_device_ids=(2,)) as e:
        bus = ModbusSerialClient(e.port, baudrate=115200, parity="N", timeout=0.3, retries=0)
        cfg = {k: v for k, v in AXIS.items() if k not in ("parity",)}
        a1 = ModbusStageAxis(client=bus, name="turntable", device_id=1, **cfg)
        a2 = ModbusStageAxis(client=bus, name="lift", device_id=2, **cfg)
        assert a1.move_to_deg(30.0) == pytest.approx(30.0, abs=0.05)
        assert a2.move_to_deg(-60.0) == pytest.approx(-60.0, abs=0.05)
        assert a1.position_deg() == pytest.approx(30.0, abs=0.05)
        e.alarm(0x30, unit=2)
        with pytest.raises(HardwareError, match="lift"):
            a2.move_to_deg(0.0)
        assert a1.move_to_deg(0.0) == pytest.approx(0.0, abs=0.05)   # the other drive is fine
        assert e.state(unit=2)["alarm"] == 0x30 and e.state(unit=1)["alarm"] == 0
        a1.close()
        a2.close()
        assert bus.connected   # the shared client belongs to the caller
        bus.close()


def test_pymodbus_serial_client_against_rtu_emulator() -> None:
    """The plain pymodbus client (no driver) reads the feedback position over the pty."""
    with StageEmulator.start("rtu", initial_position=-1000) as e:
        c = ModbusSerialClient(e.port, baudrate=115200, parity="N", timeout=0.5, retries=0)
        assert c.connect()
        regs = c.read_holding_registers(0x120, count=2, device_id=1).registers
        assert c.convert_from_registers(regs, data_type=c.DATATYPE.INT32) == -1000
        c.close()


# --- recording ---------------------------------------------------------------------------------


def record_fixtures() -> None:
    """Re-record ``fixtures/modbus/*.jsonl`` from the RTU emulator."""
    with StageEmulator.start("rtu") as e:
        rec = RecordingTransport(SerialTransport(e.port), FIX / "az_move_rtu.jsonl",
                                 note="AZ stage emulator, RTU; position, move 45, move -30, "
                                      "position, stop (tests/test_modbus.py --record)")
        axis = ModbusStageAxis(transport=rec, **AXIS)
        axis.position_deg()
        axis.move_to_deg(45.0)
        axis.move_to_deg(-30.0)
        axis.position_deg()
        axis.stop()
        axis.close()
    with StageEmulator.start("rtu") as e:
        rec = RecordingTransport(SerialTransport(e.port), FIX / "az_faults_rtu.jsonl",
                                 note="AZ stage emulator, RTU; dropped reply, corrupted reply, "
                                      "exception response, alarm 0x30 before a move, reset, "
                                      "move 20 (tests/test_modbus.py --record)")
        axis = ModbusStageAxis(transport=rec, **AXIS)
        e.drop_replies(1)
        axis.position_deg()
        e.corrupt_replies(1)
        axis.position_deg()
        try:
            axis._read(0x0300, 2)
        except ProtocolError:
            pass
        e.alarm(0x30)
        try:
            axis.move_to_deg(20.0)
        except HardwareError:
            pass
        axis.reset_alarm()
        axis.move_to_deg(20.0)
        axis.close()


if __name__ == "__main__":
    if "--record" in sys.argv:
        record_fixtures()
        print("recorded", *sorted(p.name for p in FIX.glob("*.jsonl")))
