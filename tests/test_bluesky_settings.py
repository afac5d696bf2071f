"""The Bluesky detectors' reading settings follow the devices: the spectrometer and the
reflectance detector share one integration time and number of averages, the defaults follow the
bench's stored white, and a stored white taken with other settings is refused in one line, before
any motion, as our own exception (not a FailedStatus wrapping a status repr).
"""

from __future__ import annotations

import asyncio
import tomllib

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import pytest

from bench.bluesky import connect
from bench.core.errors import CalibrationRefused
from bench.core.geometry import Geometry
from bluesky_support import BENCHES, run, spy
from helpers.cli import run_main


def _get(RE, signal):
    return asyncio.run_coroutine_threadsafe(signal.get_value(), RE.loop).result(10)


def test_the_spectrometers_integration_time_is_the_reflectance_detectors(RE):
    with connect(BENCHES / "virtual.toml", run_engine=RE, seed=3) as devs:
        RE(bps.mv(devs.goniometer, Geometry(30, 0, 20, 180), devs.spectrometer.integration_s, 0.02,
                  devs.spectrometer.averages, 2))
        assert _get(RE, devs.reflectance.integration_s) == 0.02 and _get(RE, devs.reflectance.averages) == 2
        acquired = spy(devs.bench.spectrometer, "acquire")
        try:
            docs, _ = run(RE, devs, bp.count([devs.reflectance]))
        finally:
            acquired.restore()
        assert {args for args, _ in acquired} == {(0.02, 2)}  # white, darks and the point alike
        conf = docs.of("descriptor")[0]["configuration"]["reflectance"]["data"]
        assert conf["reflectance-integration_s"] == 0.02 and conf["reflectance-averages"] == 2
        RE(bps.mv(devs.reflectance.integration_s, 0.05))  # and the other way round
        assert _get(RE, devs.spectrometer.integration_s) == 0.05


def test_a_stored_white_sets_the_defaults_and_a_mismatch_is_one_line_before_motion(RE, tmp_path, capsys):
    white = tmp_path / "white.csv"
    code, _, err = run_main(capsys, "white", "--bench", BENCHES / "virtual.toml", "--out", white,
                            "--integration-s", "0.02", "--averages", "2", "--yes")
    assert code == 0, err
    config = tomllib.loads((BENCHES / "virtual.toml").read_text())
    config["white"]["reference_file"] = str(white)
    with connect(config, run_engine=RE, seed=3) as devs:
        # the defaults are the stored white's: a plain count is calibrated from it
        assert _get(RE, devs.reflectance.integration_s) == 0.02 and _get(RE, devs.spectrometer.averages) == 2
        RE(bps.mv(devs.goniometer, Geometry(30, 0, 20, 180)))
        docs, _ = run(RE, devs, bp.count([devs.reflectance]))
        assert docs.of("stop")[0]["exit_status"] == "success"
        # another integration time: refused at stage, as CalibrationRefused, one line, no motion
        RE(bps.mv(devs.spectrometer.integration_s, 0.05))
        moves = devs.goniometer.mover.moves
        acquired = spy(devs.bench.spectrometer, "acquire")
        try:
            with pytest.raises(CalibrationRefused) as info:
                RE(bp.count([devs.reflectance]))
        finally:
            acquired.restore()
        msg = str(info.value)
        assert "\n" not in msg and "integration_s = 0.02 s" in msg and msg.startswith("reflectance"), msg
        assert list(acquired) == [] and devs.goniometer.mover.moves == moves
