"""A spectral specimen's band: what the emulated detector reads and what the fit predicts.

The detector gives each pixel the specimen's value at that pixel's wavelength, and a band reads the
mean of its pixels (bench.bands.SpectralBands); the fit and the design predict that mean, not the
value at the band's centre. The referee is the specimen's own model evaluated per pixel."""

from __future__ import annotations

import numpy as np
import pytest

from bench.builders import emulated as E
from bench.core.geometry import Geometry, cone_cos_weights
from bench.identify.prediction import band_pixels, cone_nodes, predicted_brdf, record_bands
from virtual.specimens import parse_specimen
from virtual.wire.ocean_model import SpectrometerConfig, SpectrometerModel

LEAF = "leaf:healthy,roughness=0.2,eta=1.45"
DIFFUSE = Geometry(30.0, 0.0, 60.0, 180.0)  # far from the cuticle's specular peak


@pytest.fixture(scope="module")
def leaf():
    return parse_specimen(LEAF)


@pytest.fixture(scope="module")
def pixels():
    return SpectrometerModel(SpectrometerConfig()).wavelengths


def _exact(spec, g, wl, aperture):
    dirs, w = cone_cos_weights(g.view, aperture)
    lo, hi = spec.wavelength_range() or (-np.inf, np.inf)
    return E.RESPONSE_GAIN * np.array([float(w @ spec.bsdf(g.incident, dirs, float(x))) for x in np.clip(wl, lo, hi)])


def test_leaf_spectrum_at_once_equals_one_wavelength_at_a_time(leaf, pixels):
    dirs, _ = cone_cos_weights(DIFFUSE.view, 1.0)
    wl = pixels[(pixels >= 400) & (pixels <= 700)][::7]
    many = leaf.bsdf_spectrum(DIFFUSE.incident, dirs, wl)
    one = np.array([leaf.bsdf(DIFFUSE.incident, dirs, float(w)) for w in wl])
    np.testing.assert_allclose(many, one, rtol=1e-12, atol=0)


@pytest.mark.parametrize(("centre", "old_off"), [(550.0, 0.01), (650.0, 0.01)])
def test_emulated_band_mean_is_the_specimens_exact_band_mean(leaf, pixels, centre, old_off):
    """Within 1e-9 relative; the former 41-point interpolation missed both by > 1 % here."""
    band = np.abs(pixels - centre) <= 5.0
    got = E._specimen_fraction(leaf, DIFFUSE, pixels, 1.0)[band].mean()
    exact = _exact(leaf, DIFFUSE, pixels[band], 1.0).mean()
    assert got == pytest.approx(exact, rel=1e-9)
    # the former scheme, for the power of this test: 41 wavelengths between the pixel range's ends
    dirs, w = cone_cos_weights(DIFFUSE.view, 1.0)
    grid = np.linspace(400.0, pixels.max(), 41)
    old = E.RESPONSE_GAIN * np.interp(pixels, grid, [float(w @ leaf.bsdf(DIFFUSE.incident, dirs, float(x))) for x in grid])
    assert abs(old[band].mean() / exact - 1.0) > old_off


def test_non_spectral_specimen_unchanged(pixels):
    spec = parse_specimen("lambert:albedo=0.5")
    got = E._specimen_fraction(spec, DIFFUSE, pixels, 1.0)
    assert np.all(got == got[0]) and got[0] == pytest.approx(_exact(spec, DIFFUSE, pixels[:1], 1.0)[0], rel=1e-12)


def test_band_prediction_is_the_mean_over_the_bands_pixels(leaf, pixels):
    centres = [450.0, 550.0, 650.0]
    bands = band_pixels(centres, 10.0, pixels)
    f = predicted_brdf(leaf, [DIFFUSE], np.array(centres), 1.0, None, bands)[0]
    dirs, w = cone_nodes(DIFFUSE, 1.0)
    for b, band in enumerate(bands):
        assert band.nodes.size >= 27 and np.all(band.weights == 1.0 / band.nodes.size)
        per_pixel = [float(w @ leaf.bsdf(DIFFUSE.incident, dirs, float(x))) for x in band.nodes]
        assert f[b] == pytest.approx(np.mean(per_pixel), rel=1e-12)
    centre = predicted_brdf(leaf, [DIFFUSE], np.array(centres), 1.0)[0]
    assert np.max(np.abs(f / centre - 1.0)) > 1e-3  # the centre value is biased on this curved spectrum


def test_band_rule_without_pixels_matches_the_pixel_mean(leaf, pixels):
    """Gauss-Legendre over the band (no pixels known) against the pixels' mean: within 0.2 %."""
    centres = [450.0, 550.0, 650.0]
    gl = predicted_brdf(leaf, [DIFFUSE], np.array(centres), 1.0, None, band_pixels(centres, 10.0))[0]
    px = predicted_brdf(leaf, [DIFFUSE], np.array(centres), 1.0, None, band_pixels(centres, 10.0, pixels))[0]
    np.testing.assert_allclose(gl, px, rtol=2e-3)


def test_pixels_where_a_gauss_legendre_rule_would_put_its_nodes_are_still_averaged_plainly(leaf):
    """A band's weights come with its nodes, never guessed from where the nodes lie: a detector whose
    8 pixels of a band sit at the Gauss-Legendre nodes of that band reads their plain mean (as
    SpectralBands averages them), not the rule's weighted mean."""
    x, _ = np.polynomial.legendre.leggauss(8)
    pixels = np.sort(np.concatenate([650.0 + 5.0 * x, [600.0, 700.0]]))  # 8 in 650 +- 5 nm, 2 outside
    (band,) = band_pixels([650.0], 10.0, pixels)
    np.testing.assert_allclose(band.nodes, 650.0 + 5.0 * x, rtol=0, atol=1e-12)
    assert np.all(band.weights == 1.0 / 8)
    dirs, w = cone_nodes(DIFFUSE, 1.0)
    per_pixel = [float(w @ leaf.bsdf(DIFFUSE.incident, dirs, float(p))) for p in band.nodes]
    got = predicted_brdf(leaf, [DIFFUSE], np.array([650.0]), 1.0, None, (band,))[0, 0]
    assert got == pytest.approx(np.mean(per_pixel), rel=1e-12)
    rule = predicted_brdf(leaf, [DIFFUSE], np.array([650.0]), 1.0, None, band_pixels([650.0], 10.0))[0, 0]
    assert abs(rule / got - 1.0) > 1e-5  # the rule's weighted mean differs: the test can tell them apart


def test_non_spectral_prediction_bit_for_bit(pixels):
    spec = parse_specimen("lambert:albedo=0.5")
    centres = np.array([450.0, 550.0, 650.0])
    a = predicted_brdf(spec, [DIFFUSE], centres, 1.0)
    b = predicted_brdf(spec, [DIFFUSE], centres, 1.0, None, band_pixels(centres, 10.0, pixels))
    assert np.array_equal(a, b)


def test_record_bands_from_the_bench_description(pixels):
    extra = {"bands_nm": [450.0, 650.0], "bandwidth_nm": 10.0, "pixels": int(pixels.size),
             "wavelength_coeffs": list(SpectrometerConfig().wavelength_coeffs)}
    bands = record_bands({"bench_description": {"spectrometer": {"extra": extra}}})
    assert set(bands) == {450.0, 650.0}
    np.testing.assert_array_equal(bands[650.0].nodes, pixels[np.abs(pixels - 650.0) <= 5.0])
    assert record_bands({}) is None
