"""AZ stage: homing via ZHOME / HOME-END, the accurate cause of a pty refusing even parity, and
replies matched to their request. Facts: Oriental Motor AZ Series Function Edition manual
(Modbus RTU), Oriental Motor FAQ 0331.
"""

from __future__ import annotations

import os

import pytest

pytest.importorskip("pymodbus")

from pymodbus.framer import FramerRTU

from bench.core.errors import (
    ChecksumError,
    DeviceTimeoutError,
    FaultLatchedError,
    HardwareError,
    PortGoneError,
    ProtocolError,
)
from drivers.modbus import ModbusStageAxis
from drivers.modbus._client import decode_rtu_reply, port_open_hint
from drivers.transport import ScriptedTransport
from virtual.wire.modbus_stage import StageEmulator

AXIS = dict(steps_per_rev=1000, gear_ratio=10.0, speed=720.0, limits=(-170.0, 170.0),
            timeout_s=0.3, retries=1, poll_interval_s=0.005, parity="N")


def rtu(hexstr: str) -> bytes:
    body = bytes.fromhex(hexstr)
    return body + FramerRTU.compute_CRC(body).to_bytes(2, "big")


# --- homing -----------------------------------------------------------------------------------


def test_home_is_a_zhome_rising_edge_then_home_end_byte_exactly() -> None:
    """Status read (0x7E), input command 0 then ZHOME (bit 4 of 0x7D) then 0, polls until
    HOME-END (output bit 4) with neither BUSY nor MOVE, then the feedback position."""
    status = "01 03 00 7E 00 02"
    busy = (1 << 8) | (1 << 13)
    home_end = (1 << 4) | (1 << 5) | (1 << 14)
    pairs = [
        (rtu(status), rtu("01 03 04 00 00 00 20")),                      # READY
        (rtu("01 10 00 7C 00 02 04 00 00 00 00"), rtu("01 10 00 7C 00 02")),
        (rtu("01 10 00 7C 00 02 04 00 00 00 10"), rtu("01 10 00 7C 00 02")),  # ZHOME
        (rtu("01 10 00 7C 00 02 04 00 00 00 00"), rtu("01 10 00 7C 00 02")),
        (rtu(status), rtu(f"01 03 04 00 00 {busy >> 8:02X} {busy & 0xFF:02X}")),
        (rtu(status), rtu(f"01 03 04 00 00 {home_end >> 8:02X} {home_end & 0xFF:02X}")),
        (rtu("01 03 01 20 00 02"), rtu("01 03 04 00 00 00 00")),          # feedback 0
    ]
    script = ScriptedTransport(pairs)
    axis = ModbusStageAxis(transport=script, **AXIS)
    assert axis.home() == pytest.approx(0.0)
    axis.close()  # raises on any byte not sent / not read
    assert script.done


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_home_on_the_emulator_returns_to_zero() -> None:
    with StageEmulator.start("tcp", time_scale=20.0, initial_position=3000) as emu:
        axis = ModbusStageAxis(emu.url, **AXIS)
        assert axis.position_deg() == pytest.approx(3000 / (1000 * 10 / 360), abs=1e-6)
        assert axis.home() == pytest.approx(0.0, abs=0.05)
        st = emu.state()
        assert st["homings"] == 1 and st["home_end"] is True
        assert "HOME-END" in axis.status()["flags"]
        axis.move_to_deg(10.0)             # a move clears HOME-END
        assert "HOME-END" not in axis.status()["flags"]
        axis.close()


@pytest.mark.timeout(60, func_only=True)  # a hang guard (pytest-timeout), not a speed assertion
def test_home_that_never_ends_is_a_bounded_timeout_then_latched() -> None:
    with StageEmulator.start("tcp", homing=False) as emu:
        axis = ModbusStageAxis(emu.url, **AXIS)
        with pytest.raises(DeviceTimeoutError, match="no HOME-END.*within 0.3 s"):
            axis.home(timeout_s=0.3)
        assert emu.state()["stops"] >= 1   # STOP sent on the timeout
        with pytest.raises(FaultLatchedError):
            axis.home()
        axis.reset_alarm()
        axis.close()


def test_alarm_before_homing_is_a_hardware_error() -> None:
    with StageEmulator.start("tcp") as emu:
        axis = ModbusStageAxis(emu.url, **AXIS)
        emu.alarm(0x30)
        with pytest.raises(HardwareError, match="0x30.*before homing"):
            axis.home()
        assert emu.state()["homings"] == 0
        axis.close()


# --- a pty refusing even parity ---------------------------------------------------------------


def test_pty_refusing_even_parity_names_einval_not_a_busy_port() -> None:
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        axis = ModbusStageAxis(path, **{**AXIS, "parity": "E", "retries": 0})
        with pytest.raises(PortGoneError) as ei:
            axis.read_int32("feedback_position")
        msg = str(ei.value)
        assert "EINVAL" in msg and "pseudo-terminal" in msg and "parity = \"N\"" in msg
        assert "open elsewhere" not in msg
        axis.close()
    finally:
        os.close(master)
        os.close(slave)


def test_port_open_hint_other_causes() -> None:
    assert "open elsewhere" in port_open_hint("/dev/ttyUSB7", "E", OSError(16, "busy"))
    hint = port_open_hint("/dev/ttyUSB7", "E", OSError(22, "Invalid argument"))
    assert "EINVAL" in hint and "pseudo-terminal" not in hint


# --- replies matched to their request ---------------------------------------------------------


def test_reply_of_another_function_is_not_this_request_s_answer() -> None:
    late_write = rtu("01 10 00 7C 00 02")
    with pytest.raises(ProtocolError, match="function code 16, expected 3"):
        decode_rtu_reply(late_write, 3, 1, 0x120, 2)
    with pytest.raises(ProtocolError, match="device 2"):
        decode_rtu_reply(rtu("02 03 04 00 00 00 01"), 3, 1, 0x120, 2)
    with pytest.raises(ProtocolError, match="1 register"):
        decode_rtu_reply(rtu("01 03 02 00 01"), 3, 1, 0x120, 2)
    with pytest.raises(ProtocolError, match="address"):
        decode_rtu_reply(rtu("01 10 00 5C 00 02"), 16, 1, 0x7C, 2)
    bad = bytearray(rtu("01 03 04 00 00 00 01"))
    bad[-1] ^= 1
    with pytest.raises(ChecksumError):
        decode_rtu_reply(bytes(bad), 3, 1, 0x120, 2)
    assert decode_rtu_reply(rtu("01 03 04 00 00 00 01"), 3, 1, 0x120, 2).registers == [0, 1]


def test_driver_discards_a_late_reply_and_retries_byte_exactly() -> None:
    read = rtu("01 03 01 20 00 02")
    pairs = [(read, rtu("01 10 00 7C 00 02")),          # the late answer to an earlier write
             (read, rtu("01 03 04 00 00 03 E8"))]
    script = ScriptedTransport(pairs)
    axis = ModbusStageAxis(transport=script, **AXIS)
    assert axis.read_int32("feedback_position") == 1000
    axis.close()
    script = ScriptedTransport([(read, rtu("01 10 00 7C 00 02"))] * 2)
    axis = ModbusStageAxis(transport=script, **AXIS)
    with pytest.raises(ChecksumError, match="did not match the request"):
        axis.read_int32("feedback_position")
    axis.close()
