"""The Bluesky devices on the emulated bench (real drivers over wire-level emulators, started
once for the module): protocols, standard plans, no byte for a refused geometry, pause/resume/abort
and a servo fault mid-plan.
"""

from __future__ import annotations

import asyncio
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import bluesky.preprocessors as bpp
import numpy as np
import pytest
from bluesky.utils import FailedStatus, RunEngineInterrupted

from bench.bluesky import StoreWriter, connect
from bench.core.errors import GeometryError
from bench.core.geometry import Geometry
from bench.store import RunStore
from bluesky_support import BENCHES, STANDARD, Docs, check_protocols, reset_reflectance, run, spy


@pytest.fixture(scope="module")
def emulated(RE):
    devs = connect(BENCHES / "emulated.toml", run_engine=RE)
    yield devs
    devs.close()


def test_every_emulated_device_satisfies_the_bluesky_protocols(emulated):
    check_protocols(emulated)


@pytest.mark.parametrize("name", list(STANDARD))
def test_standard_plans_succeed_on_the_emulated_bench(RE, emulated, tmp_path, name):
    reset_reflectance(RE, emulated)
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 20, 180)))
    plan, n_events, _ = STANDARD[name](emulated)
    if name == "scan":  # the back-scatter side stops at -20 deg on this bench (arm collision)
        plan = bp.scan([emulated.reflectance], emulated.goniometer.theta_r, 60, -10, 5)
    docs, writer = run(RE, emulated, plan, tmp_path / "s.sqlite")
    assert docs.of("stop")[0]["exit_status"] == "success" and len(docs.of("event")) == n_events
    with RunStore(tmp_path / "s.sqlite") as store:
        (info,) = store.runs()
        assert info["status"] == "completed" and info["points_done"] == n_events
        assert store.run(info["run_id"])["bench"]["kind"] == "emulated"


def test_a_refused_geometry_on_the_emulated_bench_sends_no_byte(RE, emulated):
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 20, 180)))
    arm = emulated.bench.parts["arm"]

    async def attempt() -> BaseException | None:
        try:  # -30 across the normal: the detector in the beam
            await emulated.goniometer.theta_r.set(-30)
        except GeometryError as exc:
            return exc
        return None

    writes = spy(arm.transport, "write")
    try:
        refused = asyncio.run_coroutine_threadsafe(attempt(), RE.loop).result(10)
    finally:
        writes.restore()
    assert writes == []  # the status failed before anything was queued for the wire
    assert str(refused).startswith("beam_block:") and "blocks the beam" in str(refused)
    with pytest.raises(FailedStatus):  # and through the RunEngine (which then holds the arm)
        RE(bps.mv(emulated.goniometer.theta_r, -30))
    assert emulated.goniometer.mover.target["theta_r"] == 20.0


def test_a_late_move_fails_its_status_with_a_timeout_and_the_arm_then_holds(RE, emulated):
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 20, 180)))

    async def late() -> BaseException | None:
        try:
            await emulated.goniometer.theta_r.set(70, timeout=0.001)
        except (TimeoutError, asyncio.TimeoutError) as exc:
            return exc
        return None

    assert asyncio.run_coroutine_threadsafe(late(), RE.loop).result(30) is not None
    asyncio.run_coroutine_threadsafe(emulated.goniometer.stop(), RE.loop).result(30)
    assert _bus_still(emulated)  # the move ended in the worker, then stop held the arm
    assert abs(emulated.goniometer.mover.reached.theta_r - 70) < 0.2


def _bus_still(devs: Any) -> bool:
    from virtual.wire.dynamixel_bus import BusControl

    with BusControl(devs.bench.parts["emulators"].bus.control) as ctl:
        return all(s["moving"] == 0 for s in ctl.state()["servos"].values())


def test_pause_resume_and_abort_leave_the_emulated_goniometer_stopped(RE, emulated, tmp_path):
    reset_reflectance(RE, emulated)
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 20, 180)))
    g = emulated.goniometer

    def paused_scan():
        @bpp.stage_decorator([emulated.reflectance])
        @bpp.run_decorator()
        def inner():
            for tr in (20, 40, 60):
                yield from bps.checkpoint()
                yield from bps.mv(g.theta_r, tr)
                if tr == 40:
                    yield from bps.pause()
                yield from bps.trigger_and_read([g, emulated.reflectance])
        return (yield from inner())

    stops = spy(emulated.bench.goniometer, "stop")
    db = tmp_path / "s.sqlite"
    writer = StoreWriter(db)
    token = RE.subscribe(writer)
    try:
        with pytest.raises(RunEngineInterrupted):
            RE(paused_scan())
        assert RE.state == "paused" and len(stops) >= 1 and _bus_still(emulated)
        RE.resume()
        n = len(stops)
        with pytest.raises(RunEngineInterrupted):
            RE(paused_scan())
        assert RE.state == "paused" and len(stops) > n and _bus_still(emulated)
        RE.abort("operator aborted")
    finally:
        RE.unsubscribe(token)
        stops.restore()
    assert _bus_still(emulated)
    with RunStore(db) as store:
        first, second = store.runs()
        assert first["status"] == "completed" and first["points_done"] == 3
        # bluesky 1.15 leaves the stop document's reason empty on RE.abort(reason); the store says why
        assert second["status"] == "interrupted" and "exit_status 'abort'" in second["reason"]


def test_a_servo_fault_mid_plan_fails_the_run_with_the_fault_and_nothing_moves(RE, emulated, tmp_path):
    from virtual.wire.dynamixel_bus import BusControl

    reset_reflectance(RE, emulated)
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 20, 180)))
    arm = emulated.bench.parts["arm"]
    docs = Docs()

    def overload_after_first_point(name: str, doc: dict[str, Any]) -> None:
        if name == "event" and doc["seq_num"] == 1:  # the detector servo overloads as it next starts
            with BusControl(emulated.bench.parts["emulators"].bus.control) as ctl:
                ctl.hardware_error(3, 1 << 5, on_goal=True)

    tokens = [RE.subscribe(docs), RE.subscribe(overload_after_first_point)]
    try:
        with pytest.raises(FailedStatus):
            run(RE, emulated, bp.scan([emulated.reflectance], emulated.goniometer.theta_r, 30, 50, 3),
                tmp_path / "s.sqlite")
        with BusControl(emulated.bench.parts["emulators"].bus.control) as ctl:
            servos = ctl.state()["servos"]
        assert all(s["moving"] == 0 for s in servos.values())
        assert all(s["torque"] == 0 for s in servos.values())  # torque off after a hardware error
    finally:
        for t in tokens:
            RE.unsubscribe(t)
        emulated.worker.call(arm.reset)  # leave the shared bench usable
    stop = docs.of("stop")[0]
    assert stop["exit_status"] == "fail" and "hardware error" in stop["reason"] and "overload" in stop["reason"]
    with RunStore(tmp_path / "s.sqlite") as store:
        (info,) = store.runs()
        assert info["status"] == "failed" and info["points_done"] == 1
        assert info["reason"].startswith("HardwareError: emulated-arm: hardware error") and "overload" in info["reason"]
    RE(bps.mv(emulated.goniometer, Geometry(30, 0, 25, 180)))  # the bench works again after reset()
    assert abs(emulated.goniometer.mover.reached.theta_r - 25) < 0.2


def test_staging_returns_the_arm_to_the_setpoint_after_measuring_the_white(RE, emulated):
    """The white is read at 0/45 on this bench: stage() moves there and back, so ``count`` after
    ``mv`` reads at the setpoint (it used to read at the white geometry while ``locate()`` said
    the setpoint). The truth of the readings: tests/conformance/test_bluesky_cells.py."""
    reset_reflectance(RE, emulated)
    RE(bps.mv(emulated.goniometer.theta_i, 30, emulated.goniometer.theta_r, 20))
    docs, _ = run(RE, emulated, bp.count([emulated.reflectance]))
    (event,) = docs.of("event")
    got = [event["data"][f"reflectance-{a}"] for a in ("theta_i", "phi_i", "theta_r", "phi_r")]
    assert np.allclose(got, [30, 0, 20, 180], atol=0.1), got
    loc = asyncio.run_coroutine_threadsafe(emulated.goniometer.locate(), RE.loop).result(10)
    assert np.allclose(loc["readback"], loc["setpoint"], atol=0.1), loc


def test_a_count_at_a_parked_arm_is_refused_in_one_line_naming_the_setpoint(RE):
    """Fresh from connect() the emulated arm is parked (detector in the beam): the white moves it
    away and it is not returned to a geometry nothing can be measured at (a scan moves it after
    staging); a count there is refused in one line, not read at the white geometry."""
    devs = connect(BENCHES / "emulated.toml", run_engine=RE)
    try:
        reset_reflectance(RE, devs)
        with pytest.raises(FailedStatus) as info:
            RE(bp.count([devs.reflectance]))
        exc = info.value.__cause__ or info.value
        assert isinstance(exc, GeometryError), repr(exc)
        assert "not at the goniometer's setpoint" in str(exc) and "\n" not in str(exc), str(exc)
    finally:
        devs.close()


@pytest.mark.slow  # ~6 CPU-s (a fresh interpreter, bluesky, three emulators); every emulated test above starts
# its emulators through the same python -m virtual.wire._spawned path
def test_an_emulated_bench_connects_and_scans_from_a_script_piped_into_python(tmp_path):
    """``python -`` (no ``__main__`` module file, no guard): the emulators start as ``python -m``
    subprocesses, where multiprocessing's spawn died with EOFError re-importing ``<stdin>``."""
    import os
    import subprocess
    import sys

    from bluesky_support import ROOT

    script = (
        "from bluesky import RunEngine\n"
        "from bluesky.plans import scan\n"
        "from bench.bluesky import connect\n"
        "RE = RunEngine()\n"
        f"devs = connect({str(BENCHES / 'emulated.toml')!r}, run_engine=RE)\n"
        "docs = []\n"
        "RE(scan([devs.spectrometer], devs.goniometer.theta_r, 20, 40, 2), lambda n, d: docs.append(n))\n"
        "devs.close()\n"
        "print('events', docs.count('event'))\n")
    r = subprocess.run([sys.executable, "-"], input=script, capture_output=True, text=True, timeout=120,
                       cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0 and r.stdout.splitlines()[-1] == "events 2", r.stdout + r.stderr[-3000:]
