"""Hardware-in-the-loop tests: they run on `pytest --bench-config my-lab.toml` (a real bench)
and, without it, on the embedded emulated bench (real drivers over wire-level emulators)."""


import numpy as np
import pytest

from bench.core.geometry import Geometry
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore
from bench.core.conformance import check_goniometer, check_instrument, check_spectrometer

pytestmark = pytest.mark.hil

REACHABLE = [Geometry(30, 0, 20, 180), Geometry(45, 90, 30, 270), Geometry(20, 0, 60, 180), Geometry(0, 0, 40, 0)]
UNREACHABLE = [Geometry(95, 0, 20, 180),   # source below the horizon
               Geometry(30, 0, 30, 0),     # detector in the beam (retro-reflection)
               Geometry(30, 0, 60, 0)]     # detector head against the source boom


def test_goniometer_conforms(hil_bench):
    check_instrument(hil_bench.goniometer)
    check_goniometer(hil_bench.goniometer, REACHABLE, UNREACHABLE, tol_deg=0.5)


def test_spectrometer_conforms(hil_bench):
    check_instrument(hil_bench.spectrometer)
    r = check_spectrometer(hil_bench.spectrometer, integration_s=0.01, averages=2)
    assert np.all(r.signal > 0)


def test_light_off_reads_dark(hil_bench):
    if hil_bench.light is None:  # a real bench may have no switchable source: nothing to test there
        pytest.skip("this bench declares no LightSource role (nothing to switch)")
    hil_bench.goniometer.move_to(Geometry(30, 0, 20, 180))
    lit = hil_bench.spectrometer.acquire(0.02, 2).signal
    hil_bench.light.off()
    try:
        dark = hil_bench.spectrometer.acquire(0.02, 2).signal
    finally:
        hil_bench.light.on()
    assert np.all(lit > dark)


def test_short_scan_is_calibrated_and_stored(hil_bench, tmp_path):
    plan = plan_from_dict({"name": "hil", "kind": "in-plane", "integration_s": 0.02, "averages": 2,
                           "dark": "once", "white": "once",
                           "in_plane": {"theta_i": [30], "theta_r": {"start": 0, "stop": 60, "step": 20}}})
    with RunStore(tmp_path / "hil.sqlite") as store:
        res = run_scan(hil_bench, plan, store)
        df = store.readings(res.run_id)
    assert res.status == "completed" and res.points_done == 4
    assert np.all(np.isfinite(df["value"])) and np.all(df["value"] > 0) and np.all(df["std"] > 0)
