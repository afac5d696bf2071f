"""A plan is designed from the bench's description, with nothing opened, wherever the description
says all a design reads: the emulated body (no emulator started) and a real body that declares its
bands (no port opened); the virtual body, and a real one whose spectrometer reports its own
wavelengths, are opened as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.builders.described import DescribedGoniometer, design_bench
from bench.config import load_description
from bench.identify.design_noise import bench_reading_model
from bench.identify.time_model import ReadingSettings

BENCHES = Path(__file__).resolve().parents[1] / "fixtures" / "benches"


def test_the_real_template_is_designed_on_without_opening_a_port():
    d, _ = load_description(BENCHES / "real-template.toml")
    assert d.get("bands"), "the template declares its bands"
    bench = design_bench(BENCHES / "real-template.toml")  # /dev/ttyUSB0..2 do not exist here: opening would fail
    assert isinstance(bench.goniometer, DescribedGoniometer) and bench.kind == "real"
    model = bench_reading_model(bench, ReadingSettings())
    assert model.body == "real" and model.wavelengths.size == len(bench.spectrometer.wavelengths) > 0


def test_a_real_description_without_bands_is_opened_for_its_wavelengths():
    d, _ = load_description(BENCHES / "real-template.toml")
    d = {k: v for k, v in d.items() if k != "bands"}
    from bench.core.errors import BenchError, DeviceError

    with pytest.raises((BenchError, DeviceError, OSError)):  # power: it does try the (absent) ports
        design_bench(d, body="real")


# starts the emulators once to compare (about 3 s)
def test_the_emulated_description_gives_the_reading_model_of_the_started_emulators():
    from bench.config import load_bench

    settings = ReadingSettings()
    described = design_bench(BENCHES / "emulated.toml")
    assert isinstance(described.goniometer, DescribedGoniometer)
    with load_bench(BENCHES / "emulated.toml") as opened:
        want = bench_reading_model(opened, settings)
    got = bench_reading_model(described, settings)
    for field in ("wavelengths", "counts_per_brdf", "variance_per_count", "variance_floor", "dark_level"):
        assert np.array_equal(getattr(got, field), getattr(want, field)), field
    assert got.aperture_deg == want.aperture_deg and got.standard == want.standard


@pytest.mark.parametrize("written", ["albedo", "reflectance"])
def test_a_design_names_each_parameter_as_the_model_string_wrote_it(written, tmp_path, capsys):
    import json

    from tests.helpers.cli import run_main

    out = tmp_path / "d.toml"
    code, text, err = run_main(capsys, "plan", "--design", f"lambert:{written}=?", "--prior", f"{written}=0.4",
                               "--bench", BENCHES / "real-template.toml", "--budget-seconds", 20, "--step", 20, "--out", out, "--json")
    assert code == 0, err
    got = json.loads(text)
    assert list(got["widths"]) == [written] and list(got["width_range"]) == [written]
    assert got["prior"][written] == 0.4
    header = "\n".join(line for line in out.read_text().splitlines() if line.startswith("#"))
    other = "reflectance" if written == "albedo" else "albedo"
    assert f"{written}=0.4" in header and f"{written} " in header and other not in header


def test_a_sequential_target_may_name_a_parameter_by_its_alias():
    from bench.core.errors import InputError
    from bench.identify.design_sequential import parse_targets
    from bench.identify.model_spec import parse_model_spec

    spec = parse_model_spec("lambert:albedo=?")
    assert parse_targets("albedo=0.01", spec.names, spec.canonical) == {"reflectance": 0.01}
    with pytest.raises(InputError, match="kd is not a free parameter"):
        parse_targets("kd=0.01", spec.names, spec.canonical)


def _record_covariance(bench, readings, points, brdf, dark_mode):
    """The covariance ``bench scan``'s budgets give the expected readings of ``points`` (no noise
    drawn): the calibration chain's own budgets, each dark shared by the readings it corrects."""
    import math

    from bench.core.budget import budget_covariance, calibration_budgets
    from bench.core.calibration import Calibration
    from bench.core.roles import Reading

    wl, s = readings.wavelengths, readings.settings

    def reading(signal, std, dark=False):
        return Reading(wavelengths=wl, signal=np.asarray(signal, float), saturated=np.zeros(wl.size, bool),
                       integration_s=s.integration_s, averages=s.averages, dark=dark, std=np.asarray(std, float))

    white_signal, white_std, _ = readings.counts(readings.standard.rf(wl) / math.pi,
                                                 math.cos(math.radians(readings.standard.geometry.theta_r)))
    dark = reading(readings.dark_level, np.sqrt(readings.variance_floor), dark=True)
    cal = Calibration(readings.standard, reading(white_signal, white_std), dark)
    budgets = []
    for k, g in enumerate(points):
        signal, std, saturated = readings.counts(brdf[k], abs(math.cos(math.radians(g.theta_r))))
        assert not saturated.any()
        key = {"per-incidence": f"dark at theta_i {g.theta_i:g}", "once": "dark once"}.get(dark_mode, f"dark {k}")
        budgets += [b.as_dict() for b in calibration_budgets(cal, reading(signal, std), g, dark, bench.config,
                                                             lit_index=0, dark_key=key)]
    return budget_covariance(budgets, np.full(len(budgets), np.nan))


@pytest.mark.parametrize("dark", ["per-incidence", "once", "per-point"])
def test_the_designs_information_inverts_the_records_covariance(dark):
    """The design's Fisher information of a set of points equals J^T C^-1 J with C the covariance
    the record's budgets give (the fit's): each dark one offset shared by the readings it corrects,
    the white reading per wavelength and the certificate shared scales. Power: the same points
    with each reading's dark counted as its own (the design before it counted darks as shared)
    give Cramer-Rao standard errors off by more than 1.5 % (2.3 % with the dark per incidence: no
    randomness here, the covariances are the expected readings')."""
    from bench.identify.design import information, sensitivities
    from bench.identify.design_io import model_point
    from bench.identify.model_spec import parse_model_spec
    from bench.core.geometry import Geometry

    bench = design_bench(BENCHES / "emulated.toml")
    readings = bench_reading_model(bench, ReadingSettings(integration_s=0.05, dark=dark))
    point = model_point(parse_model_spec("plastic:alpha=?,kd=?"), {"alpha": 0.4, "kd": 0.2})
    points = [Geometry.in_plane(ti, tr) for ti in (20.0, 50.0) for tr in (-40.0, 0.0, 30.0, 60.0)]
    sens = sensitivities(point, points, readings.wavelengths, readings.aperture_deg, readings.standard.geometry,
                         readings.bands)
    cov = _record_covariance(bench, readings, points, sens.brdf, dark)
    jac = sens.jacobian.reshape(-1, len(point.free))
    want = jac.T @ np.linalg.solve(cov, jac)
    got = information(point, points, readings, sens=sens).total(range(len(points)))
    np.testing.assert_allclose(got, want, rtol=1e-6)
    if dark != "per-point":  # the darks made each reading's own: what the old design counted
        own_darks = _record_covariance(bench, readings, points, sens.brdf, "per-point")
        naive = jac.T @ np.linalg.solve(own_darks, jac)
        se_naive, se_want = (np.sqrt(np.diag(np.linalg.inv(f))) for f in (naive, want))
        assert np.max(np.abs(se_naive / se_want - 1.0)) > 0.015
