"""Instrument effects of the virtual body are declared, never implicit.

Each effect is off by default (bit-identical readings without ``[instrument]`` or with every
effect at its default) and, when declared, changes the readings as stated. Variance checks are
chi-square tests of the sample variance against the declared one, each two-sided at a
false-alarm rate of 1e-3 (fixed seeds); power: the same test rejects a variance 1.5x off.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from bench.config import load_bench
from bench.core.errors import CalibrationRefused, ConfigError
from bench.core.geometry import Geometry, cone_quadrature
from bench.core.parsing import read_toml
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore
from virtual.specimens import parse_specimen

VIRTUAL = read_toml(Path(__file__).parent.parent / "fixtures" / "benches" / "virtual.toml")
POINT = Geometry(30, 0, 20, 180)
ALPHA = 1e-3


def _bench(**instrument):
    return load_bench({**VIRTUAL, "instrument": instrument} if instrument else VIRTUAL, seed=3)


def _lit(bench, n=1, averages=1):
    bench.goniometer.move_to(POINT)
    return np.array([bench.spectrometer.acquire(0.02, averages).signal for _ in range(n)])


def _dark(bench, n=1, averages=1):
    bench.light.off()
    try:
        return np.array([bench.spectrometer.acquire(0.02, averages).signal for _ in range(n)])
    finally:
        bench.light.on()


def _variance_consistent(samples: np.ndarray, variance: float) -> bool:
    """Two-sided chi-square test of the sample variance (false-alarm rate ALPHA)."""
    k = samples.size - 1
    stat = k * samples.var(ddof=1) / variance
    return chi2.ppf(ALPHA / 2, k) < stat < chi2.isf(ALPHA / 2, k)


def test_no_effect_unless_declared():
    with _bench() as bare, _bench(seed=5) as empty:
        assert np.array_equal(_lit(bare), _lit(empty)) and np.array_equal(_dark(bare), _dark(empty))
        assert np.all(_dark(bare) == 0.0)
        assert np.array_equal(bare.measure_white(0.02, 1).signal, empty.measure_white(0.02, 1).signal)
        assert bare.goniometer.move_to(POINT) == POINT


def test_dark_offset_is_added_and_removed_by_the_darks(tmp_path):
    with _bench() as bare, _bench(dark_counts=150.0) as offset:
        assert np.array_equal(_dark(offset), np.full((1, 3), 150.0))
        assert np.allclose(_lit(offset), _lit(bare) + 150.0, rtol=0, atol=1e-9)
        table = {"name": "p", "kind": "list", "points": [[30, 0, 20, 180], [30, 0, 60, 180]], "integration_s": 0.02}
        with RunStore(tmp_path / "s.sqlite") as store:
            values = {}
            for name, bench in (("bare", bare), ("offset", offset)):
                run = run_scan(bench, plan_from_dict({**table, "dark": "once"}), store).run_id
                values[name] = store.readings(run)["value"].to_numpy()
            # without darks the offset would show in the values: refused before any motion, nothing stored
            with pytest.raises(CalibrationRefused, match="takes no dark, .* dark level of 150 counts"):
                run_scan(offset, plan_from_dict({**table, "dark": "none"}), store)
            assert len(store.runs()) == 2
    assert np.allclose(values["offset"], values["bare"], rtol=1e-9)  # the darks take the offset out


def test_read_noise_has_the_declared_variance():
    with _bench(read_noise=8.0, seed=1) as bench:
        samples = _dark(bench, n=400, averages=4).ravel()
    assert _variance_consistent(samples, (8.0 / 2) ** 2)
    assert not _variance_consistent(samples, 1.5 * (8.0 / 2) ** 2)  # power


def test_shot_noise_is_poisson_in_the_counts():
    with _bench() as bare, _bench(shot_noise=True, seed=2) as noisy:
        mean = _lit(bare)[0]
        samples = _lit(noisy, n=400, averages=2)
    for i in range(mean.size):
        assert _variance_consistent(samples[:, i], mean[i] / 2)
        assert not _variance_consistent(samples[:, i], 1.5 * mean[i] / 2)
    assert np.all(np.abs(samples.mean(axis=0) - mean) < 4 * np.sqrt(mean / 2 / 400))


def test_lamp_drift_scales_each_lit_reading():
    with _bench() as bare, _bench(lamp_drift=0.01) as drifting:
        base = _lit(bare, n=4)  # repeated triggers scatter; the k-th draws alike on both benches (same seed)
        got = _lit(drifting, n=4)
        assert np.array_equal(_dark(drifting), np.zeros((1, 3)))  # darks do not drift
    for k in range(4):
        assert np.allclose(got[k], base[k] * (1 + 0.01 * k), rtol=1e-12)


def test_positioning_error_moves_where_declared():
    with _bench(positioning_error_deg=0.2, seed=4) as bench:
        reached = [bench.goniometer.move_to(POINT) for _ in range(300)]
        with pytest.raises(Exception, match="source_hemisphere"):
            bench.goniometer.move_to(Geometry(95, 0, 20, 180))
    errors = np.array([[g.theta_i - POINT.theta_i, g.theta_r - POINT.theta_r] for g in reached]).ravel()
    assert _variance_consistent(errors, 0.2**2) and not _variance_consistent(errors, 1.5 * 0.2**2)
    assert abs(errors.mean()) < 4 * 0.2 / math.sqrt(errors.size)


def _specular_brdf_cos(aperture_deg: float) -> tuple[float, float, float]:
    """A peaked GGX lobe (alpha 0.1) read at its specular peak, in units of BRDF x cos theta_r,
    with its reported std, and the model's own mean of f cos theta_r over the declared cone (a
    48 x 96 quadrature of the specimen's BRDF: the prediction)."""
    spec, g = "ggx:alpha=0.1,eta=1.5,k=0", Geometry(30, 0, 30, 180)
    emulated = {k: v for k, v in VIRTUAL["emulated"].items() if k != "aperture_deg"}  # [instrument] declares it
    cfg = {**VIRTUAL, "specimen": {"spec": spec}, "virtual": {**VIRTUAL["virtual"], "wavelengths": 550.0},
           "emulated": emulated}
    with load_bench({**cfg, "instrument": {"aperture_deg": aperture_deg}}, seed=1) as bench:
        bench.goniometer.move_to(g)
        r = bench.spectrometer.acquire(0.02, 1)
        scale = bench.spectrometer.gain * 0.02
    d, w = cone_quadrature(g.view, aperture_deg, rings=48, azimuths=96)
    f = np.asarray(parse_specimen(spec).bsdf(g.incident, d, 550.0), dtype=float)
    return float(r.signal[0] / scale), float(r.std[0] / scale), float(np.sum(w * f * d[:, 2]))


def test_detector_aperture_averages_the_lobe_over_its_cone():
    """Off by default (aperture_deg 0: the point reading, test_no_effect_unless_declared); a
    declared 6 deg half-angle reads the cone mean of f cos theta_r, 24 % below the peak, as the
    model predicts. Each comparison within 3 reported std (an upper bound: false alarm < 2.7e-3)."""
    point, point_std, peak = _specular_brdf_cos(0.0)
    cone, cone_std, predicted = _specular_brdf_cos(6.0)
    assert abs(point - peak) < 3 * point_std and abs(cone - predicted) < 3 * cone_std
    assert peak - predicted > 10 * (point_std + cone_std)  # the change is the aperture's, not noise
    assert predicted / peak == pytest.approx(0.76, abs=0.01)


def test_instrument_table_is_checked():
    with pytest.raises(ConfigError, match=r"\[instrument\]: key read_noise"):
        _bench(read_noise=-1.0)
    with pytest.raises(ConfigError, match="did you mean 'shot_noise'"):
        _bench(shot_nose=True)
