"""Spectral batching (issue 18): a Lambertian (and GGX with one roughness) measured at W wavelengths at once
(:func:`virtual.engine.gonio_counts_spectral`) gives, per wavelength, exactly the
single-wavelength count distribution.

Each wavelength's row is compared with an independent single-wavelength run by the two-sample
chi-square (bins + absorbed + missed): p > 1e-3 fails a correct kernel once in 1000 per
comparison (fixed seeds, so fixed outcomes). Power: a row against a single run whose reflectance
differs by 0.02 gives p < 1e-6.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from tests.test_engine import _two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_counts, gonio_counts_spectral, measurement_seed
from virtual.kernels.scatter import MODEL_ANISO_GGX, MODEL_GGX, MODEL_LAMBERT, MODEL_PHONG
from virtual.specimens import parse_specimen

COL = Collector("equal-psa", 9, 24)
N = 400_000
# (R, T) per wavelength: reflecting and transmitting, opaque, a 50/50 split, a near-white one
RT = [(0.6, 0.3), (0.2, 0.0), (0.5, 0.5), (0.9, 0.05), (0.6, 0.3)]


def _single(p, beam, theta, seed):
    return gonio_counts(MODEL_LAMBERT, np.array(p), beam.code, beam.disk_code, beam.kernel_args(theta, 20.0),
                        COL.kernel_args(), N, measurement_seed(seed))


def _spectral(rows, beam, theta, seed, n=N):
    return gonio_counts_spectral(MODEL_LAMBERT, [np.array(p) for p in rows], beam.code, beam.disk_code,
                                 beam.kernel_args(theta, 20.0), COL.kernel_args(), n, measurement_seed(seed))


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_every_wavelength_has_the_single_wavelength_distribution(beam, theta):
    many = _spectral(RT, beam, theta, 1)
    assert many.shape == (len(RT), 2 * COL.n_patches + 2) and (many.sum(axis=1) == N).all()
    np.testing.assert_array_equal(many[0], many[-1])  # equal parameters, shared rays: equal rows
    for w, p in enumerate(RT[:-1]):
        assert _two_sample_p(many[w], _single(p, beam, theta, 10 + w)) > 1e-3, w


def test_the_comparison_has_power_against_a_slightly_different_reflectance():
    many = _spectral(RT, Beam("conical"), 35.0, 1)
    assert _two_sample_p(many[0], _single((0.62, 0.3), Beam("conical"), 35.0, 10)) < 1e-6


def test_spectral_counts_do_not_depend_on_the_thread_count():
    n, before = 3 * (1 << 20) + 9, numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = _spectral(RT, Beam("conical"), 35.0, 4, n)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = _spectral(RT, Beam("conical"), 35.0, 4, n)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(one, many)


def test_other_models_fall_back_to_one_measurement_per_wavelength():
    sp = parse_specimen("phong:exponent=20")
    beam = Beam("conical")
    p = sp.params(550.0)
    rows = gonio_counts_spectral(MODEL_PHONG, [p, p], beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                                 COL.kernel_args(), 10_000, measurement_seed(2))
    single = gonio_counts(MODEL_PHONG, p, beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                          COL.kernel_args(), 10_000, measurement_seed(2))
    np.testing.assert_array_equal(rows[0], single)
    np.testing.assert_array_equal(rows[1], single)
    with pytest.raises(ValueError, match="at least one"):
        gonio_counts_spectral(MODEL_LAMBERT, [], beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                              COL.kernel_args(), 10, measurement_seed(2))


# GGX, one roughness, eta and k per wavelength: a dielectric, a conductor, another conductor
GGX_ROWS = [(0.2, 0.2, 1.5, 0.0), (0.2, 0.2, 0.2, 3.0), (0.2, 0.2, 0.6, 2.0)]


def _ggx_single(p, beam, theta, seed, model=MODEL_GGX):
    return gonio_counts(model, np.array(p), beam.code, beam.disk_code, beam.kernel_args(theta, 20.0),
                        COL.kernel_args(), N, measurement_seed(seed))


def _ggx_spectral(rows, beam, theta, seed, model=MODEL_GGX, n=N):
    return gonio_counts_spectral(model, [np.array(p) for p in rows], beam.code, beam.disk_code,
                                 beam.kernel_args(theta, 20.0), COL.kernel_args(), n, measurement_seed(seed))


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_ggx_wavelengths_each_have_the_single_wavelength_distribution(beam, theta):
    many = _ggx_spectral(GGX_ROWS, beam, theta, 1)
    assert (many.sum(axis=1) == N).all()
    for w, p in enumerate(GGX_ROWS):
        assert _two_sample_p(many[w], _ggx_single(p, beam, theta, 20 + w)) > 1e-3, w
    aniso = [(0.4, 0.1, 1.5, 0.0), (0.4, 0.1, 0.2, 3.0)]
    many = _ggx_spectral(aniso, beam, theta, 2, MODEL_ANISO_GGX)
    for w, p in enumerate(aniso):
        assert _two_sample_p(many[w], _ggx_single(p, beam, theta, 30 + w, MODEL_ANISO_GGX)) > 1e-3, w


def test_ggx_batch_has_power_against_a_slightly_different_fresnel():
    many = _ggx_spectral(GGX_ROWS, Beam("conical"), 35.0, 1)
    assert _two_sample_p(many[1], _ggx_single((0.2, 0.2, 0.2, 3.3), Beam("conical"), 35.0, 20)) < 1e-6


def test_ggx_with_a_spectral_roughness_falls_back_to_one_measurement_per_wavelength():
    rows = [(0.2, 0.2, 1.5, 0.0), (0.3, 0.3, 1.5, 0.0)]
    many = _ggx_spectral(rows, Beam("conical"), 35.0, 3, n=10_000)
    for w, p in enumerate(rows):
        np.testing.assert_array_equal(many[w], gonio_counts(
            MODEL_GGX, np.array(p), Beam("conical").code, Beam("conical").disk_code,
            Beam("conical").kernel_args(35.0, 20.0), COL.kernel_args(), 10_000, measurement_seed(3)))
