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
from bench.core.errors import ConfigError
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore

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
            for name, bench, dark in (("bare", bare, "once"), ("offset", offset, "once"),
                                      ("offset, no dark", offset, "none")):
                run = run_scan(bench, plan_from_dict({**table, "dark": dark}), store).run_id
                values[name] = store.readings(run)["value"].to_numpy()
    assert np.allclose(values["offset"], values["bare"], rtol=1e-9)  # the darks take the offset out
    assert not np.allclose(values["offset, no dark"], values["bare"], rtol=1e-3)  # without them it shows


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
        base = _lit(bare)[0]
        got = _lit(drifting, n=4)
        assert np.array_equal(_dark(drifting), np.zeros((1, 3)))  # darks do not drift
    for k in range(4):
        assert np.allclose(got[k], base * (1 + 0.01 * k), rtol=1e-12)


def test_positioning_error_moves_where_declared():
    with _bench(positioning_error_deg=0.2, seed=4) as bench:
        reached = [bench.goniometer.move_to(POINT) for _ in range(300)]
        with pytest.raises(Exception, match="source_hemisphere"):
            bench.goniometer.move_to(Geometry(95, 0, 20, 180))
    errors = np.array([[g.theta_i - POINT.theta_i, g.theta_r - POINT.theta_r] for g in reached]).ravel()
    assert _variance_consistent(errors, 0.2**2) and not _variance_consistent(errors, 1.5 * 0.2**2)
    assert abs(errors.mean()) < 4 * 0.2 / math.sqrt(errors.size)


def test_instrument_table_is_checked():
    with pytest.raises(ConfigError, match=r"\[instrument\]: key read_noise"):
        _bench(read_noise=-1.0)
    with pytest.raises(ConfigError, match="did you mean 'shot_noise'"):
        _bench(shot_nose=True)
