"""Conformance cells of the Bluesky interface: the geometry a staged detector reads at.

Cell: emulated body (real drivers over the wire-level emulators, emulator seed 7) x white
measured once at stage x dark once x Bluesky ``count`` after ``mv(theta_i 30, theta_r 20)`` x
nominal exposure, specimen plastic alpha 0.15, kd 0.5 (a glossy lobe: the reading depends on the
geometry, where a Lambertian's calibrated reading would not).

Invariant: the event reads at the setpoint (the read-back within one servo step of it), and
every unmasked calibrated BRDF lies within k = 3 standard uncertainties of the truth (the
emulated detector's 1-deg cone calibrated against its white, bench.identify.prediction) at the
geometry read back. False-alarm rate: 3 bands x 2 readings, two-sided normal tail 0.27 % each,
at most 1.6 % for the cell (Bonferroni). Power: the same readings against the truth at the white
geometry (0/45, where staging used to leave the arm) lie far outside.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import numpy as np
import pytest
from bluesky import RunEngine

from bench.bluesky import connect
from bench.core.geometry import Geometry
from bench.identify.prediction import predicted_brdf
from virtual.specimens import parse_specimen

ROOT = Path(__file__).resolve().parents[2]
SPECIMEN = "plastic:alpha=0.15,kd=0.5"
SETPOINT = Geometry(30, 0, 20, 180)
WHITE = Geometry(0, 0, 45, 180)
APERTURE_DEG = 1.0  # emulated.toml [emulated] aperture_deg
SERVO_STEP_DEG = 360 / 4096
K = 3.0


@pytest.fixture(scope="module")
def staged_count():
    config = tomllib.loads((ROOT / "fixtures" / "benches" / "emulated.toml").read_text())
    config["specimen"]["spec"] = SPECIMEN
    RE = RunEngine({})
    devs = connect(config, run_engine=RE)
    try:
        r = devs.reflectance
        RE(bps.mv(r.integration_s, 0.02, r.averages, 1, r.dark_mode, "once", r.white_mode, "once"))
        RE(bps.mv(devs.goniometer.theta_i, SETPOINT.theta_i, devs.goniometer.theta_r, SETPOINT.theta_r))
        docs: list[tuple[str, dict]] = []
        RE(bp.count([devs.goniometer, r], num=2), lambda name, doc: docs.append((name, doc)))
        wavelengths = np.asarray(devs.bench.spectrometer.wavelengths, dtype=float)
        yield [d["data"] for n, d in docs if n == "event"], wavelengths
    finally:
        devs.close()


def _truth(g: Geometry, wavelengths: np.ndarray) -> np.ndarray:
    return predicted_brdf(parse_specimen(SPECIMEN), [g], wavelengths, APERTURE_DEG, WHITE)[0]


def test_count_after_mv_reads_at_the_setpoint_within_uncertainty_of_the_truth(staged_count):
    events, wavelengths = staged_count
    assert len(events) == 2
    for data in events:
        for axis, want in SETPOINT.as_dict().items():
            assert abs(data[f"goniometer-{axis}"] - want) <= SERVO_STEP_DEG, (axis, data[f"goniometer-{axis}"])
            assert abs(data[f"reflectance-{axis}"] - want) <= SERVO_STEP_DEG, (axis, data[f"reflectance-{axis}"])
        reached = Geometry(*(float(data[f"reflectance-{a}"]) for a in ("theta_i", "phi_i", "theta_r", "phi_r")))
        brdf, u = np.asarray(data["reflectance-brdf"]), np.asarray(data["reflectance-brdf_std"])
        ok = ~np.asarray(data["reflectance-masked"], dtype=bool)
        assert ok.all()  # nominal exposure: nothing masked
        z = (brdf - _truth(reached, wavelengths)) / u
        assert np.all(np.abs(z[ok]) <= K), z


def test_power_the_white_geometry_truth_is_far_outside(staged_count):
    events, wavelengths = staged_count
    for data in events:
        brdf, u = np.asarray(data["reflectance-brdf"]), np.asarray(data["reflectance-brdf_std"])
        z = (brdf - _truth(WHITE, wavelengths)) / u
        assert np.all(np.abs(z) > K), z  # the invariant fails for the perturbed cell
