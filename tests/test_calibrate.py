"""Calibration: the signal model inverted, uncertainty propagated, bad reference pixels masked."""

import math

import numpy as np
import pytest

from bench.core.calibration import Calibration, WhiteStandard
from bench.core.errors import CalibrationError
from bench.core.geometry import Geometry
from bench.core.records import Reading

WL = np.array([450.0, 550.0, 650.0])


def reading(signal, t=0.1, std=None, saturated=None, averages=1):
    s = np.asarray(signal, dtype=float)
    return Reading(wavelengths=WL, signal=s, saturated=np.zeros(s.size, bool) if saturated is None else np.asarray(saturated),
                   integration_s=t, averages=averages, std=None if std is None else np.asarray(std, float))


def model_signal(f, theta_r, gain=1e5, t=0.1, dark=100.0):
    """The bench's signal model: S = G t f cos(theta_r) + D."""
    return gain * t * np.asarray(f) * math.cos(math.radians(theta_r)) + dark


def test_inverts_the_signal_model_exactly():
    std = WhiteStandard(0.99, 0.0, Geometry(0, 0, 45, 180))
    white = reading(model_signal(np.full(3, 0.99 / math.pi), 45.0, t=0.05), t=0.05, std=np.ones(3))
    dark = reading(np.full(3, 100.0), std=np.ones(3))
    cal = Calibration(std, white, reading(np.full(3, 100.0), t=0.05, std=np.ones(3)))
    f_true = np.array([0.05, 0.3, 1.7])  # any BRDF, glossy included
    g = Geometry(30, 0, 60, 180)
    c = cal.apply(reading(model_signal(f_true, 60.0), std=np.ones(3)), g, dark)
    assert np.allclose(c.brdf, f_true, rtol=1e-12)
    assert np.allclose(c.reflectance_factor, math.pi * f_true)
    assert not c.masked.any()


def test_uncertainty_matches_a_monte_carlo_of_the_inputs():
    rng = np.random.default_rng(1)
    std = WhiteStandard(0.98, 0.004, Geometry(0, 0, 45, 180))
    s_w, s, u = model_signal(np.full(3, 0.98 / math.pi), 45.0), model_signal(np.full(3, 0.2), 20.0), 30.0
    cal = Calibration(std, reading(s_w, std=np.full(3, u)))
    c = cal.apply(reading(s, std=np.full(3, u)), Geometry(10, 0, 20, 180))
    draws = []
    for _ in range(20000):
        r_w = 0.98 + 0.004 * rng.standard_normal()
        w = s_w + u * rng.standard_normal(3)
        x = s + u * rng.standard_normal(3)
        draws.append(x / w * r_w / math.pi * math.cos(math.radians(45)) / math.cos(math.radians(20)))
    mc = np.std(draws, axis=0)
    # first-order propagation against 20,000 draws: the MC std has a relative error of
    # 1/sqrt(2*20000) = 0.5 %; the linearisation error here is well below 1 %
    assert np.allclose(c.std, mc, rtol=0.03)


def test_reference_at_or_below_dark_and_saturation_are_masked_and_reported():
    std = WhiteStandard(0.99)
    white = reading([5000.0, 100.0, 80.0], saturated=[False, False, False])
    cal = Calibration(std, white, reading([100.0, 100.0, 100.0]))
    c = cal.apply(reading([3000.0, 3000.0, 3000.0], saturated=[True, False, False]), Geometry(0, 0, 30, 180),
                  reading([100.0, 100.0, 100.0]))
    assert c.mask_reason == ["signal saturated", "white reference at or below dark", "white reference at or below dark"]
    assert np.isnan(c.brdf).all()  # NaN only where a reason says why
    assert np.all(np.isfinite(c.signal))
    white_sat = reading([5000.0, 6000.0, 7000.0], saturated=[False, True, False])
    c2 = Calibration(std, white_sat).apply(reading([3000.0, 3000.0, 3000.0]), Geometry(0, 0, 30, 180))
    assert c2.mask_reason[1] == "white reference saturated" and np.isfinite(c2.brdf[[0, 2]]).all()


def test_viewing_at_the_horizon_is_refused():
    cal = Calibration(WhiteStandard(0.99), reading([1e4, 1e4, 1e4]))
    with pytest.raises(CalibrationError, match="horizon"):
        cal.apply(reading([1e3, 1e3, 1e3]), Geometry(30, 0, 90, 180))


def test_calibration_round_trips_through_its_dict():
    cal = Calibration(WhiteStandard(((400.0, 700.0), (0.97, 0.99)), 0.003), reading([1e4, 2e4, 3e4], std=[1, 2, 3]),
                      reading([10.0, 10.0, 10.0]))
    back = Calibration.from_dict(cal.as_dict())
    r = reading([5e3, 5e3, 5e3], std=[1, 1, 1])
    g = Geometry(10, 0, 30, 180)
    assert np.allclose(back.apply(r, g).brdf, cal.apply(r, g).brdf)
    with pytest.raises(CalibrationError, match="has data for"):
        WhiteStandard(((500.0, 600.0), (0.9, 0.9))).rf(WL)
