"""The detector's aperture is declared once and every body reads it: the virtual body counts rays
into the declared cone as the emulated spectrometer averages it, and a fit predicts what each
body read (the cone average, calibrated against the white read through the same cone).

Statistical checks are two-sided at a false-alarm rate of 1e-3 each (fixed seeds): the mean of
standardized readings (normal, |z| < 3.29) and their variance (chi-square); power: the collector
patch the virtual body read before is rejected by the same test.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.stats import chi2, norm

from bench.builders.emulated import RESPONSE_GAIN, emulated_response
from bench.builders.instrument import ApertureReading, declared_aperture
from bench.config import load_bench
from bench.core.geometry import Geometry, cone_quadrature
from bench.core.parsing import read_toml
from bench.core.records import BSDFRecord
from bench.identify.design import ModelPoint, sensitivities
from bench.identify.likelihood import GaussianReadings
from bench.identify.prediction import predicted_brdf
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.specimens import Lambertian, parse_specimen

BENCHES = Path(__file__).resolve().parents[1] / "fixtures" / "benches"
EMULATED = read_toml(BENCHES / "emulated.toml")
GLOSSY = "plastic:alpha=0.15,kd=0.5"
SPECULAR, OFF_SPECULAR = Geometry(60, 0, 60, 180), Geometry(30, 0, 10, 180)
ALPHA = 1e-3
Z = float(norm.isf(ALPHA / 2))


def test_one_answer_to_which_aperture_a_description_declares():
    plain = {"kind": "virtual", "specimen": {"spec": "lambert"}}
    assert declared_aperture(plain) == 0.0  # a virtual description: the collector patch
    assert declared_aperture(EMULATED) == 1.0
    assert declared_aperture(read_toml(BENCHES / "virtual.toml")) == 1.0  # the emulated bench's twin
    assert declared_aperture({"kind": "emulated"}) == 1.0  # the emulator's default
    assert declared_aperture({"kind": "real", "emulated": {"aperture_deg": 2.0}}) == 2.0
    assert declared_aperture({**plain, "instrument": {"aperture_deg": 3.0}}) == 3.0
    assert declared_aperture({**EMULATED, "instrument": {"aperture_deg": 3.0}}) == 3.0  # [instrument] wins
    with pytest.raises(Exception, match=r"\[emulated\]"):
        declared_aperture({"kind": "emulated", "emulated": {"aperture_deg": -1.0}})


def _virtual_detector(seed: int, wavelengths=(450.0, 550.0, 650.0), rays: int = 10_000_000) -> ApertureReading:
    return ApertureReading(VirtualGoniophotometer(GLOSSY, seed=seed, rays=rays, wavelengths=wavelengths), 1.0)


def test_the_virtual_body_of_the_emulated_description_reads_the_emulators_cone():
    """Its expected reading is the emulator's, to quadrature precision; its readings scatter
    around it as binomial counts (60 seeds x 3 bands per geometry); the collector patch the
    virtual body read before (9x36, ~10 deg) is rejected by the same test."""
    d = {**EMULATED, "specimen": {"spec": GLOSSY}}
    with load_bench(d, seed=1, body="virtual") as bench:
        assert bench.describe()["spectrometer"]["extra"]["detector_reads"] == "cone"
        bench.goniometer.move_to(SPECULAR)
        first = bench.spectrometer.acquire(0.02, 2)
        again = bench.spectrometer.acquire(0.02, 2)
        assert not np.array_equal(first.signal, again.signal)  # a repeated trigger draws counts of its own
    with load_bench(d, seed=1, body="virtual") as bench:
        bench.goniometer.move_to(SPECULAR)
        # the first reading is keyed by its geometry and band: a rebuilt bench (a resume) draws it again
        assert np.array_equal(bench.spectrometer.acquire(0.02, 2).signal, first.signal)
    spec = parse_specimen(GLOSSY)
    for g in (SPECULAR, OFF_SPECULAR):
        wl = np.array([450.0, 550.0, 650.0])
        emulated = emulated_response(g, wl, GLOSSY, 0.99, "/nonexistent/mount.json", 1.0) / RESPONSE_GAIN
        det = _virtual_detector(0)
        mean = det.expected(g, wl)
        assert np.allclose(mean, emulated, rtol=1e-12, atol=0)
        d_fine, w_fine = cone_quadrature(g.view, 1.0, rings=32, azimuths=64)
        fine = float((w_fine * d_fine[:, 2]) @ spec.bsdf(g.incident, d_fine, 550.0))
        assert mean[1] == pytest.approx(fine, rel=1e-4)  # the 4 x 8 rule's own error

        z, z_patch = [], []
        for seed in range(60):
            det = _virtual_detector(seed)
            det.move_to(g)
            r = det.acquire(0.02, 1)
            scale = det.gain * 0.02
            p = det.omega * mean
            sd = scale * np.sqrt(p * (1 - p) / det.rays) / det.omega
            z.append((r.signal - scale * mean) / sd)
            assert np.allclose(r.std, sd, rtol=0.05)  # the reported std: binomial at the observed count
        z = np.ravel(z)
        k = z.size - 1
        assert abs(z.mean()) * math.sqrt(z.size) < Z
        assert chi2.ppf(ALPHA / 2, k) < k * z.var(ddof=1) < chi2.isf(ALPHA / 2, k)
        # power: the patch of the viewing direction, one reading (the old detector's)
        patch = VirtualGoniophotometer(GLOSSY, seed=0, rays=10_000_000, wavelengths=(550.0,))
        patch.move_to(g)
        r = patch.acquire(0.02, 1)
        z_patch = (r.signal[0] - patch.gain * 0.02 * mean[1]) / (patch.gain * 0.02 * math.sqrt(
            det.omega * mean[1] / det.rays) / det.omega)
        assert abs(z_patch) > Z, z_patch


def test_without_an_aperture_the_virtual_detector_reads_the_collector_patch_as_before():
    d = {"name": "plain", "kind": "virtual", "specimen": {"spec": "lambert:albedo=0.8"},
         "virtual": {"collector": "equal-psa:9x36", "rays": 100000, "wavelengths": 550.0}}
    bare = VirtualGoniophotometer("lambert:albedo=0.8", collector="equal-psa:9x36", rays=100000, seed=4,
                                  wavelengths=550.0)
    with load_bench(d, seed=4, body="virtual") as bench:
        assert "aperture_deg" not in bench.describe()["spectrometer"]["extra"]
        bench.goniometer.move_to(OFF_SPECULAR)
        bare.move_to(OFF_SPECULAR)
        assert np.array_equal(bench.spectrometer.acquire(0.02, 1).signal, bare.acquire(0.02, 1).signal)


class _NoDensity(Lambertian):
    has_density = False


def test_a_specimen_without_a_density_reads_the_patch_and_says_so(caplog):
    inner = VirtualGoniophotometer(_NoDensity(reflectance=0.5), rays=20000, seed=2, wavelengths=550.0,
                                   method="rays")
    with caplog.at_level(logging.INFO, logger="bench.builders.instrument"):
        det = ApertureReading(inner, 1.0)
    assert sum("has no density" in m for m in caplog.messages) == 1
    assert det.describe().extra["detector_reads"] == "patch"
    det.move_to(OFF_SPECULAR)
    assert np.array_equal(det.acquire(0.02, 1).signal, inner.acquire(0.02, 1).signal)


def _record(meta: dict) -> BSDFRecord:
    rows = [{"theta_i": g.theta_i, "phi_i": g.phi_i, "theta_r": g.theta_r, "phi_r": g.phi_r, "wavelength_nm": 550.0,
             "value": 1.0, "std": 0.01} for g in (SPECULAR, OFF_SPECULAR)]
    return BSDFRecord(pd.DataFrame(rows), meta)


WHITE = Geometry(0, 0, 45, 180)
CALIBRATION = {"standard": {"reflectance_factor": 0.99, "uncertainty": 0.005, "geometry": WHITE.as_dict()}}


def test_a_fit_predicts_the_cone_each_body_read():
    """Emulated record: the description's aperture; virtual record: what its detector says it read;
    the design's likelihood predicts with the same function."""
    spec = parse_specimen(GLOSSY)
    cone = predicted_brdf(spec, [SPECULAR, OFF_SPECULAR], np.array([550.0]), 1.0, WHITE)[:, 0]
    point = predicted_brdf(spec, [SPECULAR, OFF_SPECULAR], np.array([550.0]))[:, 0]
    assert cone[0] / point[0] - 1 < -0.005  # at the 60/60 peak the cone reads 0.7 % below the point
    emulated = _record({"bench_kind": "emulated", "bench": EMULATED, "calibration": CALIBRATION})
    lik = GaussianReadings(emulated)
    assert lik.aperture_deg == 1.0 and np.array_equal(lik.predictions(spec), cone)
    design = sensitivities(ModelPoint(type(spec), {"alpha": 0.15, "kd": 0.5}, ("alpha",)),
                          [SPECULAR, OFF_SPECULAR], np.array([550.0]), 1.0, WHITE)
    assert np.allclose(design.brdf[:, 0], cone, rtol=1e-14)  # the design predicts what the fit does
    described = {"kind": "virtual", "spectrometer": {"extra": {"aperture_deg": 1.0, "detector_reads": "cone"}},
                 "goniometer": {"extra": {"collector": {"scheme": "equal-psa", "n_theta": 9, "n_phi": 36}}}}
    virtual = _record({"bench_kind": "virtual", "bench_description": described, "calibration": CALIBRATION})
    assert np.array_equal(GaussianReadings(virtual).predictions(spec), cone)
    described["spectrometer"]["extra"] = {}  # a virtual detector that read its collector patch
    patch = GaussianReadings(_record({"bench_kind": "virtual", "bench_description": described}))
    assert patch.aperture_deg == 0.0 and all(r["patch"] is not None for r in patch.rows)
