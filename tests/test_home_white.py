"""Homing and motion on the application side: ``bench home`` and plans with ``home = true``
(homing end to end on the emulated bench), ``bench plan`` motion estimates of real and emulated
benches from the configured speeds and ramps, white reference files (round trip, bad files) and
a HIL run on a ``kind = "real"`` bench with no terminal (stdin closed)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.builders.motion import motion_profile
from bench.cli import main
from bench.config import load_bench
from bench.core.calibration import Calibration, WhiteStandard
from bench.core.errors import CalibrationError, ConfigError, HardwareError, InputError
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.core.records import Reading
from bench.core.schemas import BenchFile, PlanFile, validate_document
from bench.builders.homing import home_axis, homeable_axes
from bench.io.white import WhiteReference, read_white_reference, write_white_reference
from bench.plans import estimate, plan_from_dict
from bench.runner import measure_calibration, run_scan
from bench.store import RunStore

ROOT = Path(__file__).parent.parent
BENCHES = ROOT / "fixtures" / "benches"
TEMPLATE = read_toml(BENCHES / "real-template.toml")
SHORT = {"name": "short", "kind": "in-plane", "integration_s": 0.02, "averages": 2, "dark": "once",
         "white": "once", "in_plane": {"theta_i": [30], "theta_r": {"start": 0, "stop": 40, "step": 20}}}


@pytest.fixture(scope="module")
def emulated():
    bench = load_bench(BENCHES / "emulated.toml")
    try:
        yield bench
    finally:
        bench.close()


# --- motion estimates ---------------------------------------------------------------------------


def _two_points(a, b):
    return plan_from_dict({"name": "one-move", "kind": "list", "points": [a, b], "dark": "none",
                           "white": "none", "order": "as-given"})


def test_real_template_estimate_matches_a_hand_computation():
    """Template: source profile_velocity 30 x 0.229 rev/min = 41.22 deg/s, profile_acceleration
    10 x 214.577 rev/min^2 = 214.577 deg/s^2; a 30 deg move is past the ramp distance v^2/a =
    7.92 deg, so t = 30/41.22 + 41.22/214.577 = 0.9199 s, plus settle 0.2 s. Turntable: 20 deg/s,
    accel 1000 steps/s^2 / (1000 x 18 / 360 steps/deg) = 20 deg/s^2; 90 deg takes
    90/20 + 20/20 = 5.5 s, 10 deg (under the 20 deg ramp distance) 2 sqrt(10/20) = 1.414 s."""
    profile = motion_profile(TEMPLATE["arm"], TEMPLATE["turntable"])
    assert profile.velocity["source"] == pytest.approx(41.22, abs=1e-9)
    assert profile.acceleration["source"] == pytest.approx(214.577, abs=1e-9)
    assert profile.velocity["turntable"] == 20.0 and profile.acceleration["turntable"] == pytest.approx(20.0)
    tol = 1e-3  # s: the hand computation's rounding
    move = estimate(_two_points([10, 0, 40, 180], [40, 0, 40, 180]), profile)["motion_s"]
    assert move == pytest.approx(0.9199 + 0.2, abs=tol)
    assert profile.move_time({"turntable": 0.0}, {"turntable": 90.0}) == pytest.approx(5.5 + 0.2, abs=tol)
    assert profile.move_time({"turntable": 0.0}, {"turntable": 10.0}) == pytest.approx(1.414 + 0.2, abs=tol)
    # a whole plan on the real template is no longer estimated as 0:00:00
    plan = plan_from_dict(read_toml(ROOT / "fixtures" / "plans" / "in-plane.toml"))
    assert estimate(plan, profile)["motion_s"] > 10.0


def test_gear_ratio_and_zero_profiles():
    arm = {"axes": {"source": {"id": 1, "profile_velocity": 30, "profile_acceleration": 0, "gear_ratio": 2.0},
                    "detector_azimuth": {"id": 2}}}
    p = motion_profile(arm, None)
    assert p.velocity["source"] == pytest.approx(41.22 / 2) and math.isinf(p.acceleration["source"])
    assert "detector_azimuth" not in p.velocity  # Velocity Limit unknown: the profile default applies
    assert p.move_time({"detector_azimuth": 0.0}, {"detector_azimuth": 30.0}) == pytest.approx(1.0 + 0.2)
    with pytest.raises(ConfigError, match=r"^\[turntable\]: key speed: expected a finite number, got nan$"):
        motion_profile(arm, {"speed": float("nan")})


def test_plan_on_the_emulated_bench_estimates_motion(emulated, capsys):
    """Emulated: velocities x time_scale (50), constant speed (the emulators make no ramps)."""
    profile = emulated.motion
    assert profile.velocity["source"] == pytest.approx(60 * 41.22 / 30 * 50)
    assert profile.velocity["turntable"] == pytest.approx(30.0 * 50)
    dt = profile.move_time({"source": 10.0}, {"source": 40.0})
    assert dt == pytest.approx(30.0 / (60 * 1.374 * 50) + 0.01, rel=1e-6)
    plan = plan_from_dict(read_toml(ROOT / "fixtures" / "plans" / "in-plane.toml"))
    est = estimate(plan, profile, joints=emulated.joints)
    assert est["motion_s"] > 0


def test_bench_plan_cli_on_the_emulated_bench_is_not_zero(capsys):
    assert main(["plan", str(ROOT / "fixtures" / "plans" / "in-plane.toml"), "--bench",
                 str(BENCHES / "emulated.toml"), "--json"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert out["bench_kind"] == "emulated" and out["motion_s"] > 0


# --- homing -------------------------------------------------------------------------------------


def test_home_on_the_emulated_bench_end_to_end(emulated):
    assert homeable_axes(emulated) == ["turntable"]
    emulated.goniometer.move_to(Geometry(30, 90, 20, 270))
    assert emulated.parts["turntable"].position_deg() == pytest.approx(90.0, abs=0.1)
    before = emulated.parts["emulators"].stage.state()["homings"]
    assert home_axis(emulated) == pytest.approx(0.0, abs=0.05)
    st = emulated.parts["emulators"].stage.state()
    assert st["homings"] == before + 1 and st["home_end"] is True
    with pytest.raises(ConfigError, match="nothing to home on axis 'source'"):
        home_axis(emulated, "source")


def test_plan_with_home_homes_before_the_first_point(emulated, tmp_path):
    emulated.goniometer.move_to(Geometry(30, 45, 20, 225))
    before = emulated.parts["emulators"].stage.state()["homings"]
    plan = plan_from_dict({**SHORT, "home": True, "white": "none", "dark": "none"})
    with RunStore(tmp_path / "h.sqlite") as store:
        res = run_scan(emulated, plan, store)
        meta = store.run(res.run_id)["meta"]
    assert res.status == "completed"
    assert emulated.parts["emulators"].stage.state()["homings"] == before + 1
    assert meta["homed"]["turntable"] == pytest.approx(0.0, abs=0.05)


def test_plan_home_key_is_declared_and_checked():
    assert plan_from_dict({**SHORT, "home": True}).home is True
    assert plan_from_dict(SHORT).home is False
    validate_document(PlanFile, {**SHORT, "home": True}, "p.toml")
    with pytest.raises(ConfigError, match="home"):
        validate_document(PlanFile, {**SHORT, "home": "yes"}, "p.toml")
    with pytest.raises(ConfigError, match="key home"):
        plan_from_dict({**SHORT, "home": 1})


def test_a_virtual_bench_plan_with_home_runs_without_homing(tmp_path):
    plan = plan_from_dict({**SHORT, "home": True, "white": "none", "dark": "none"})
    with load_bench(BENCHES / "virtual.toml", seed=1) as bench, RunStore(tmp_path / "v.sqlite") as store:
        res = run_scan(bench, plan, store, seed=1)
        assert store.run(res.run_id)["meta"]["homed"] is None


def test_bench_home_cli_exit_codes(tmp_path, capsys, monkeypatch):
    # virtual: nothing to home, exit 2 before anything is built
    assert main(["home", "--bench", str(BENCHES / "virtual.toml")]) == 2
    assert "nothing to do" in capsys.readouterr().err
    assert main(["home", "--bench", str(tmp_path / "missing.toml")]) == 2
    capsys.readouterr()
    # emulated: homed, the position read back
    assert main(["home", "--bench", str(BENCHES / "emulated.toml"), "--json"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert out["axis"] == "turntable" and out["position_deg"] == pytest.approx(0.0, abs=0.05)
    assert main(["home", "--bench", str(BENCHES / "emulated.toml"), "--axis", "source"]) == 2
    assert "nothing to home" in capsys.readouterr().err
    # a drive in alarm: a typed device error, exit 1
    from drivers.modbus import ModbusStageAxis

    def alarm(self, timeout_s=None):
        raise HardwareError("turntable: alarm 0x30 (overload) while homing")

    monkeypatch.setattr(ModbusStageAxis, "home", alarm)
    assert main(["home", "--bench", str(BENCHES / "emulated.toml")]) == 1
    assert "failed: turntable: alarm" in capsys.readouterr().err


# --- white reference files ----------------------------------------------------------------------


def _reading(signal, integration=0.05, std=None, dark=False):
    wl = np.array([450.0, 550.0, 650.0])
    return Reading(wl, np.asarray(signal, float), np.array([False, True, False]), integration, 3,
                   timestamp=1796040000.5, dark=dark, std=None if std is None else np.asarray(std, float))


def test_white_reference_round_trip_is_exact(tmp_path):
    cal = Calibration(WhiteStandard(), _reading([1000.1, 65535.0, 1234.5678901234], std=[1.5, 0.0, 2.25]),
                      _reading([10.0, 11.0, 12.0], std=[0.1, 0.2, 0.3], dark=True))
    ref = WhiteReference.from_calibration(cal, operator_note="SRS-99 #4471, cleaned;\nlamp warm 30 min",
                                          bench="my-lab")
    assert ref.date == "2026-11-30T12:00:00Z"
    path = write_white_reference(tmp_path / "white-2026-11-30.csv", ref)
    back = read_white_reference(path)
    assert back.date == ref.date and back.operator_note == ref.operator_note and back.bench == "my-lab"
    for a, b in ((back.white, cal.white), (back.dark, cal.white_dark)):
        assert np.array_equal(a.wavelengths, b.wavelengths) and np.array_equal(a.signal, b.signal)
        assert np.array_equal(a.std, b.std) and a.integration_s == b.integration_s and a.averages == b.averages
    assert np.array_equal(back.white.saturated, cal.white.saturated)
    g = Geometry(30, 0, 20, 180)
    r = _reading([500.0, 600.0, 700.0])
    np.testing.assert_array_equal(back.calibration(WhiteStandard()).apply(r, g).brdf, cal.apply(r, g).brdf)
    # no dark (a bench without a switchable light)
    no_dark = write_white_reference(tmp_path / "nd.csv", WhiteReference(cal.white, None, "2026-11-30", ""))
    assert read_white_reference(no_dark).dark is None


def test_white_reference_bad_files_are_typed_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_white_reference(tmp_path / "none.csv")
    p = tmp_path / "w.csv"
    write_white_reference(p, WhiteReference(_reading([1.0, 2.0, 3.0]), None, "2026-11-30", "x"))
    good = p.read_text()
    cases = {"not a goniobench white": good.replace("goniobench-white 1", "something"),
             "not a number": good.replace("\n450.0,1.0", "\n450.0,abc"),
             "date is required": good.replace('"date": "2026-11-30"', '"date": ""'),
             "integration_s must be a number > 0": good.replace('"integration_s": 0.05', '"integration_s": -1'),
             "counts >= 0": good.replace("\n450.0,1.0", "\n450.0,-1.0")}
    for why, text in cases.items():
        p.write_text(text)
        with pytest.raises(InputError, match=why):
            read_white_reference(p)
    p.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="UTF-8"):
        read_white_reference(p)
    # taken at another viewing angle than the bench's standard: refused
    ref = WhiteReference(_reading([1.0, 2.0, 3.0]), None, "d", standard={"geometry": {"theta_r": 30.0}})
    with pytest.raises(InputError, match="theta_r = 30"):
        ref.calibration(WhiteStandard())


def test_bench_white_then_a_run_calibrated_from_the_file(emulated, tmp_path, capsys):
    """`bench white` on the emulated bench, then a bench config naming the file: the run uses
    the stored reading (recorded in its meta) and gives the values a live white gives within
    their uncertainty."""
    out = tmp_path / "white.csv"
    assert main(["white", "--bench", str(BENCHES / "emulated.toml"), "--out", str(out), "--note", "bench day",
                 "--integration-s", "0.02", "--averages", "2"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    ref = read_white_reference(out)
    assert ref.operator_note == "bench day" and ref.dark is not None and ref.white.integration_s == 0.02
    plan = plan_from_dict(SHORT)
    with RunStore(tmp_path / "w.sqlite") as store:
        live = run_scan(emulated, plan, store).run_id
        emulated.config = {**emulated.config, "white": {**emulated.config["white"], "reference_file": str(out)}}
        try:
            stored = run_scan(emulated, plan, store).run_id
        finally:
            emulated.config = {**emulated.config, "white": {k: v for k, v in emulated.config["white"].items()
                                                          if k != "reference_file"}}
        info = store.run(stored)
        a, b = store.readings(live), store.readings(stored)
        # the white reference of the completed run, saved again by --from-run
        again = tmp_path / "again.csv"
        assert main(["white", "--from-run", stored, "--store", str(tmp_path / "w.sqlite"), "--out", str(again)]) == 0
    assert info["meta"]["white_reference"]["operator_note"] == "bench day"
    assert np.array_equal(np.asarray(info["calibration"]["white"]["signal"]), ref.white.signal)
    z = (a.value - b.value) / np.hypot(a["std"], b["std"])
    assert np.all(np.abs(z) < 4.5)  # Bonferroni over 9 values at two-sided 1e-4 is 4.4
    assert np.array_equal(read_white_reference(again).white.signal, ref.white.signal)
    assert main(["white", "--out", str(again)]) == 2  # neither --bench nor --from-run


@pytest.mark.slow  # a whole HIL session on the emulated bench (21 s under load)
def test_hil_run_on_a_real_bench_with_no_terminal(tmp_path):
    """A ``kind = "real"`` bench (the real builder, on the emulators' ports) whose [white] names a
    stored reading: the HIL scan test runs with stdin closed. Without the file the same run
    needs an operator and fails with a CalibrationError that names reference_file."""
    from bench.builders.emulated import DEFAULT_EMULATED_CONFIG, Emulators

    emu = Emulators(DEFAULT_EMULATED_CONFIG)
    try:
        config = emu.real_bench_config()
        assert "turntable" in config
        # the operator's reading of the standard, taken once (the mount the emulator reads)
        with load_bench(config) as real:
            assert real.kind == "real" and real.motion is not None and real.motion.velocity
            assert homeable_axes(real) == ["turntable"]
            if not sys.stdin.isatty():  # pytest captures stdin: no terminal, as in CI
                with pytest.raises(CalibrationError, match="reference_file"):
                    measure_calibration(real, plan_from_dict(SHORT))
            emu.mount_white(True)
            real.operator_confirmed = True  # what `bench white --yes` says: the standard is mounted
            try:
                cal = measure_calibration(real, plan_from_dict(SHORT))
            finally:
                emu.mount_white(False)
        assert cal.white_dark is not None  # the emulators' real-bench config declares the lamp: a dark
        ref = tmp_path / "white-2026-11-30.csv"
        write_white_reference(ref, WhiteReference.from_calibration(cal, "emulated bench day", date="2026-11-30T09:00:00Z"))
        config["white"] = {**config["white"], "reference_file": str(ref)}
        validate_document(BenchFile, config, "bench config")
        import tomli_w

        path = tmp_path / "lab.toml"
        path.write_bytes(tomli_w.dumps(config).encode())
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               str(ROOT / "tests" / "test_hil.py"), "--bench-config",
                               str(path), "-k", "short_scan"],
                              stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300, env=env,
                              cwd=tmp_path)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        assert "1 passed" in proc.stdout
    finally:
        emu.close()


def test_bench_white_by_default_integrates_as_the_benchs_detector_starts(emulated, tmp_path, capsys):
    """Without --integration-s, `bench white` integrates as the Bluesky detector starts: 0.1 s, or the
    longest below it keeping the white below full scale (the emulated bench's white saturates at 0.1 s,
    which used to be this command's default and was refused)."""
    from bench.config import load_description
    from bench.exposure import starting_integration

    out = tmp_path / "white.csv"
    start = starting_integration(load_description(BENCHES / "emulated.toml")[0])
    assert 0 < start < 0.1  # power: the old default would saturate here
    assert main(["white", "--bench", str(BENCHES / "emulated.toml"), "--out", str(out), "--averages", "2"]) == 0, \
        capsys.readouterr().err
    assert read_white_reference(out).white.integration_s == start
    assert main(["white", "--bench", str(BENCHES / "emulated.toml"), "--out", str(tmp_path / "w1.csv"),
                 "--integration-s", "0.1", "--averages", "2"]) == 2  # what the old default gave
    err = capsys.readouterr().err
    assert "saturat" in err and len(err.strip().splitlines()) == 1, err
