"""One description configures every body: the declared detector and white standard reach the
emulators and the virtual body alike, and a real bench's description runs on the emulated body
(its ports aside) with the real body's refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import load_bench
from bench.core.errors import ConfigError, PlanError
from bench.core.parsing import read_toml
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore

BENCHES = Path(__file__).parent.parent / "fixtures" / "benches"
EMULATED = read_toml(BENCHES / "emulated.toml")
REAL = read_toml(BENCHES / "real-template.toml")
#: a detector unlike the emulator's defaults in every key the test reads back
DETECTOR = {"pixels": 2048, "wavelength_coeffs": [300.0, 0.25], "dark_counts": 3000.0, "read_noise": 0.0,
            "saturation_counts": 30000, "integration_s": [0.005, 10.0], "counts_per_ms": 1500.0}
WHITE = {"reflectance_factor": 0.5, "uncertainty": 0.02, "geometry": [0, 0, 45, 180]}
IN_PLANE = {"name": "few", "kind": "in-plane", "integration_s": 0.02, "averages": 2, "dark": "per-incidence",
            "white": "once", "in_plane": {"theta_i": [30], "theta_r": [-20, 10, 50]}}


def _declared(body: str) -> dict:
    """What one body of the emulated bench described with DETECTOR and WHITE reads: the pixel
    wavelengths, a dark band, the white over the specimen at the standard's geometry, saturation."""
    # the driver undoes the unit's non-linearity (from its calibration slots), as a lab would
    cfg = {**EMULATED, "detector": DETECTOR, "white": WHITE, "spectrometer": {"nonlinearity": True}}
    with load_bench(cfg, seed=5, body=body) as bench:
        out = {"white_u": bench.white.uncertainty}
        if body == "emulated":
            out["first_pixel_nm"] = float(bench.parts["spectrometer"].wavelengths[0])
        bench.light.off()
        out["dark"] = bench.spectrometer.acquire(0.02, 4).signal
        bench.light.on()
        white = bench.measure_white(0.02, 4)
        bench.goniometer.move_to(bench.white.geometry)
        specimen = bench.spectrometer.acquire(0.02, 4)
        w, s = white.signal - out["dark"], specimen.signal - out["dark"]
        out["white_over_specimen"] = ratio = w / s
        out["ratio_std"] = ratio * np.hypot(white.std / w, specimen.std / s)
        out["saturated_long"] = bench.spectrometer.acquire(1.0, 1).saturated
        out["saturated_short"] = bench.spectrometer.acquire(0.02, 1).saturated
    return out


@pytest.mark.hil
def test_declared_detector_and_white_reach_both_bodies():
    """DETECTOR and WHITE differ from the defaults (dark 1000, 339 nm first pixel, full scale
    65535, white 0.99): each body reads the declared values."""
    virtual, emulated = _declared("virtual"), _declared("emulated")
    assert emulated["first_pixel_nm"] == pytest.approx(300.0, abs=1e-6)  # read from the unit's slots
    assert np.all(virtual["dark"] == 3000.0)  # no read noise declared: the dark level exactly
    # the emulator's dark also grows with integration (200 counts/s: 4 counts at 0.02 s)
    assert np.allclose(emulated["dark"], 3004.0, atol=1.0)
    for out in (virtual, emulated):
        assert out["white_u"] == 0.02
        # a 0.5 white over the Lambertian 0.8 specimen at 0/45, within 4 reported std
        # (Bonferroni over 6 values: two-sided 4e-4)
        assert np.all(np.abs(out["white_over_specimen"] - 0.5 / 0.8) < 4 * out["ratio_std"])
        assert not out["saturated_short"].any() and out["saturated_long"].all()


def test_declared_detector_refuses_bands_off_it_and_integration_beyond_it(tmp_path):
    off = {**EMULATED, "detector": DETECTOR, "emulated": {**EMULATED["emulated"], "bands": "450:850:100"}}
    for body in ("virtual", "emulated"):  # refused before any emulator starts
        with pytest.raises(ConfigError, match=r"band 850 nm is off the \[detector\] \(300.0\.\.811\.8 nm"):
            load_bench(off, body=body)
    fast = plan_from_dict({**IN_PLANE, "integration_s": 0.001})
    with load_bench({**EMULATED, "detector": DETECTOR}, body="virtual") as bench, \
            RunStore(tmp_path / "s.sqlite") as store:
        with pytest.raises(PlanError, match=r"integrates 0.001 s; bench 'emulated' \[detector\] takes 0.005..10 s"):
            run_scan(bench, fast, store)
        assert store.runs() == []


def test_without_detector_the_virtual_body_is_unchanged():
    with load_bench(EMULATED, seed=5, body="virtual") as bare, \
            load_bench({**EMULATED, "instrument": {}}, seed=5, body="virtual") as same:
        assert bare.spectrometer.acquire(0.02, 2).signal.tolist() == same.spectrometer.acquire(0.02, 2).signal.tolist()
        bare.light.off()
        assert np.all(bare.spectrometer.acquire(0.02, 1).signal == 0.0)


def test_dark_level_declared_twice_is_refused():
    with pytest.raises(ConfigError, match=r"dark_counts is declared twice, in \[instrument\] and in \[detector\]"):
        load_bench({**EMULATED, "detector": DETECTOR, "instrument": {"dark_counts": 10.0}}, body="virtual")


def _plan_json(cfg: dict, body: str, tmp_path: Path, capsys) -> dict:
    path = tmp_path / f"{body}.toml"
    path.write_text(_toml(cfg))
    plan = tmp_path / "plan.toml"
    plan.write_text(_toml(IN_PLANE))
    capsys.readouterr()
    main(["plan", str(plan), "--bench", str(path), "--body", body, "--json"])
    return json.loads(capsys.readouterr().out)


def _toml(d: dict) -> str:
    import tomli_w

    return tomli_w.dumps(d)


@pytest.mark.hil
def test_real_description_runs_on_the_emulated_body(tmp_path, capsys):
    """The real template (its ports aside) on the emulated body: without [light] its darks are
    refused as on the real and virtual bodies; with [light] an in-plane plan runs and the
    Lambertian 0.8 comes out at 0.8/pi within the reported uncertainty at every theta_r."""
    for body in ("virtual", "emulated"):
        out = _plan_json(REAL, body, tmp_path, capsys)
        assert out["bench_kind"] == body
        assert "declares no switchable light" in out["calibration_refused"]
    lit = {**REAL, "light": {"kind": "spectrometer-lamp"}}
    with load_bench(lit, seed=2, body="emulated") as bench, RunStore(tmp_path / "s.sqlite") as store:
        assert bench.kind == "emulated" and bench.config["spectrometer"]["port"] == "/dev/ttyUSB2"
        res = run_scan(bench, plan_from_dict(IN_PLANE), store, seed=2)
        readings = store.readings(res.run_id)
    assert res.status == "completed" and res.points_done == 3
    brdf = readings[readings["quantity"] == "brdf"] if "quantity" in readings else readings
    z = (brdf["value"] - 0.8 / np.pi) / brdf["std"]
    assert len(brdf) == 3 * 31 and np.all(np.abs(z) < 4.0), z.abs().max()
