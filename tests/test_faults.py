"""Transient faults recovered, persistent faults typed, device state established: the
drivers against the emulators (virtual/wire) injecting each fault kind byte
by byte, and devices left in a non-default state by an earlier program.
"""

from __future__ import annotations

from typing import Any

import pytest

from bench.core.errors import ChecksumError, DeviceTimeoutError, HardwareError
from drivers.dynamixel import DynamixelArm
from drivers.modbus import ModbusStageAxis
from drivers.ocean import OceanSpectrometer
from virtual.wire.dxl_bus import BusTransport, DynamixelBus
from virtual.wire.modbus_stage import StageEmulator
from virtual.wire._ocean_device import DeviceTransport
from virtual.wire.ocean_model import SpectrometerConfig, SpectrometerModel

AXES = {"turntable": {"id": 1, "limits": [-170, 170]}, "source": {"id": 2, "limits": [0, 85]},
        "detector_azimuth": {"id": 3, "zero_offset": 0, "limits": [0, 359.9]},
        "detector_elevation": {"id": 4, "limits": [0, 85]}}


def arm_on(bus: DynamixelBus, **kw: Any) -> DynamixelArm:
    return DynamixelArm({"axes": AXES, "settle_timeout_s": 3.0, "poll_interval_s": 0.002, "retries": 2,
                         "latency_s": 0.001, **kw}, transport=BusTransport(bus))


# --- Dynamixel ----------------------------------------------------------------------------------


def test_a_late_sync_read_status_neither_fails_nor_poisons_the_retries() -> None:
    """Seen in a long run: a late status of an aborted SYNC_READ arrived in the retry window and every
    retry failed on it ("status from id 2, expected id 1 after 4 attempt(s)"). The first status
    is corrupt and the rest of the reply comes 30 ms late, past the 1 ms quiet window: the late
    statuses are discarded as they arrive, and the read recovers at the first retry."""
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0, seed=1)
    arm = arm_on(bus)
    before = arm.faults.snapshot()
    bus.set_faults(corrupt_next=1, late_s=0.03)
    arm.position()
    d = {k: v - before.get(k, 0) for k, v in arm.faults.snapshot().items()}
    assert d["fault.corrupt"] == 1 and d["recovered"] == 1 and d["failed"] == 0 and d["retries"] == 1
    assert d["discarded"] >= 1 and bus.faults.late == 3
    arm.position()  # nothing of the aborted reply is left to answer a later request
    arm.close()


@pytest.mark.parametrize("fault,kind", [({"drop_next": 1}, "timeout"), ({"corrupt_next": 1}, "corrupt")])
def test_each_dynamixel_fault_kind_is_recovered_and_counted(fault, kind) -> None:
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0, seed=2)
    arm = arm_on(bus)
    before = arm.faults.snapshot()
    bus.set_faults(**fault)
    arm.position()
    after = arm.faults.snapshot()
    assert after[f"fault.{kind}"] - before.get(f"fault.{kind}", 0) == 1
    assert after["recovered"] - before["recovered"] == 1
    arm.close()


def test_a_persistent_dynamixel_fault_names_device_transaction_and_bytes() -> None:
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0, seed=3)
    arm = arm_on(bus, name="left-arm")
    bus.set_faults(corrupt_rate=1.0)
    with pytest.raises(ChecksumError, match=r"left-arm: corrupt reply .* to sync read 116\+20 \(id 1\): "
                                            r"ff ff fd 00 01 .* after 3 attempt"):
        arm.position()
    assert arm.faults.failed == 1


def test_dynamixel_open_establishes_the_state_an_earlier_program_left() -> None:
    """Status Return Level 1 (writes unanswered), reverse Drive Mode, a Homing Offset, another
    Return Delay Time, torque on: the driver sets each, reads it back and moves."""
    bus = DynamixelBus((1, 2, 3, 4), time_scale=50.0, seed=4)
    for s in bus.servos.values():
        s.put("status_return_level", 1)
        s.put("drive_mode", 0b101)
        s.put("homing_offset", 400)
        s.put("return_delay", 7)
        s.put("torque_enable", 1)
    arm = arm_on(bus, return_delay_s=100e-6)
    for s in bus.servos.values():
        assert s.value("status_return_level") == 2 and s.value("drive_mode") == 0
        assert s.value("homing_offset") == 0 and s.value("return_delay") == 50 and s.torque
    arm.position()
    arm.close()


# --- Ocean ----------------------------------------------------------------------------------------


def ocean_on(**cfg: Any) -> tuple[OceanSpectrometer, DeviceTransport]:
    t = DeviceTransport(SpectrometerModel(SpectrometerConfig(pixels=64, dark_pixels=(0, 4), seed=1, time_scale=50.0,
                                                             **cfg)))
    return OceanSpectrometer(t, model="EMU", pixels=64, dark_pixels=(0, 4), timeout_s=0.3, retries=2), t


@pytest.mark.parametrize("inject,kind", [(lambda f: f.nak.append(ord("S")), "nak"),
                                         (lambda f: setattr(f, "drop", 1), "timeout"),
                                         (lambda f: setattr(f, "corrupt", 1), "corrupt")])
def test_each_ocean_fault_kind_is_recovered_and_counted(inject, kind) -> None:
    s, t = ocean_on()
    s.acquire(0.01, 1)
    inject(t.device.faults)
    s.acquire(0.01, 1)
    snap = s.faults.snapshot()
    assert snap[f"fault.{kind}"] == 1 and snap["recovered"] == 1 and snap["failed"] == 0
    s.close()


def test_a_persistent_ocean_nak_is_typed_naming_the_command() -> None:
    s, t = ocean_on()
    t.device.faults.nak += [ord("S")] * 3
    with pytest.raises(Exception, match=r"spectrometer: NAK to command 'S'.*after 3 attempt"):
        s.acquire(0.01, 1)
    assert s.faults.failed == 1
    s.close()


def test_ocean_open_establishes_trigger_and_scans_an_earlier_program_left() -> None:
    s, t = ocean_on()
    s.close()
    t.closed = False
    t.device.s.trigger, t.device.s.scans, t.device.s.checksum = 1, 7, True
    s, _ = OceanSpectrometer(t, model="EMU", pixels=64, dark_pixels=(0, 4), timeout_s=0.3, checksum=False), t
    assert (t.device.s.trigger, t.device.s.scans, t.device.s.checksum) == (0, 1, False)
    s.acquire(0.01, 1)  # free running again: the acquisition needs no trigger
    s.close()


# --- AZ stage over Modbus ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stage():
    with StageEmulator.start("tcp", time_scale=50.0) as emu:
        yield emu


def axis_on(emu: StageEmulator) -> ModbusStageAxis:
    return ModbusStageAxis(emu.url, name="turntable", speed=90.0, settle_s=0.2, poll_interval_s=0.002,
                           retries=2, retry_delay_s=0.0, timeout_s=0.3)


def test_dropped_and_corrupt_stage_replies_are_recovered_and_counted(stage) -> None:
    ax = axis_on(stage)
    ax.establish()
    stage.drop_replies(1)
    stage.corrupt_replies(1)
    assert abs(ax.move_to_deg(5.0) - 5.0) < 0.5
    snap = ax.faults.snapshot()
    assert snap["recovered"] >= 1 and snap["failed"] == 0 and snap["retries"] >= 2
    stage.drop_replies(3)
    with pytest.raises(DeviceTimeoutError, match="turntable: read holding registers"):
        ax.position_deg()
    ax.close()


def _left_with_alarm_reset_on(stage) -> None:
    old = axis_on(stage)
    old.write_int32("input_command", 1 << old.rmap.input_bits["ALM-RST"])
    old.close()
    stage.alarm(0x30)


def test_stage_open_clears_an_input_command_left_on(stage) -> None:
    """An earlier program left ALM-RST on in the input command: without establishing the word,
    the driver's ALM-RST pulse has no rising edge and the alarm never clears."""
    _left_with_alarm_reset_on(stage)
    ax = axis_on(stage)
    with pytest.raises(HardwareError, match="persists"):
        ax.reset_alarm()  # the power of the check: the edge is lost while the bit stays on
    ax.close()
    _left_with_alarm_reset_on(stage)
    ax = axis_on(stage)
    ax.establish()  # what the builders call on open
    ax.reset_alarm()
    assert stage.state()["alarm"] == 0
    ax.close()


# --- the run records them per point; bench show summarises ----------------------------------------


def test_recovered_faults_are_recorded_per_point_and_summarised_by_show(tmp_path, capsys) -> None:
    from pathlib import Path

    from bench.config import load_bench
    from bench.plans import plan_from_dict
    from bench.runner import run_scan
    from bench.store import RunStore
    from drivers._faultlog import FaultLog
    from tests.helpers.cli import run_main

    bench_file = Path(__file__).resolve().parents[1] / "fixtures" / "benches" / "virtual.toml"
    plan = plan_from_dict({"name": "two", "kind": "list", "integration_s": 0.01, "averages": 1, "white": "once",
                           "points": [[20, 0, 30, 180], [20, 0, 40, 180]]})
    log = FaultLog()
    moves: list[Any] = []
    with load_bench(bench_file, seed=1) as bench, RunStore(tmp_path / "s.sqlite") as store:
        bench.parts["spectrometer"] = type("Flaky", (), {"faults": log})()
        move = bench.goniometer.move_to

        def move_with_a_nak(g: Any) -> Any:
            moves.append(g)
            if len(moves) == 2:  # the second point: one NAK, retried
                log.attempt_failed("nak", True)
                log.finished(1, True)
            return move(g)

        bench.goniometer.move_to = move_with_a_nak
        rid = run_scan(bench, plan, store, seed=1).run_id
        held = store.run(rid)["meta"]["device_faults"]
    assert list(held["points"].values()) == [{"spectrometer.fault.nak": 1, "spectrometer.recovered": 1,
                                              "spectrometer.retries": 1}]
    assert held["total"] == held["points"][next(iter(held["points"]))]
    code, out, _ = run_main(capsys, "show", rid, "--store", tmp_path / "s.sqlite")
    assert code == 0 and "device faults: spectrometer 1 recovered after 1 retries (nak 1) -- on 1 point(s)" in out
