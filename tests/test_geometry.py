"""Geometry conventions: in-plane signs, reciprocity, CIE names, degenerate directions."""

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from bench.core.errors import GeometryError
from bench.core.geometry import CIE_GEOMETRIES, Geometry, cie_geometry, direction, spherical


def test_in_plane_signs_follow_the_specular_side():
    g = Geometry.in_plane(30.0, 30.0)
    # the specular direction of an incidence at phi_i = 0 lies at phi = 180
    assert g.phi_r == 180.0 and g.theta_r == 30.0
    assert np.allclose(g.view, [-g.incident[0], -g.incident[1], g.incident[2]])
    back = Geometry.in_plane(30.0, -30.0)
    assert back.phi_r == 0.0 and back.angle_between_source_and_detector() == pytest.approx(0.0, abs=1e-12)
    assert g.theta_r_signed == 30.0 and back.theta_r_signed == -30.0


def test_reciprocal_swaps_source_and_detector():
    g = Geometry(20.0, 10.0, 50.0, 250.0)
    r = g.reciprocal()
    assert (r.theta_i, r.phi_i, r.theta_r, r.phi_r) == (50.0, 250.0, 20.0, 10.0)


@pytest.mark.parametrize("bad", [dict(theta_i=-1.0), dict(theta_r=181.0), dict(theta_i=float("nan")),
                                 dict(phi_r=float("inf")), dict(theta_i="x")])
def test_bad_angles_are_refused_naming_the_field(bad):
    kw = dict(theta_i=10.0, phi_i=0.0, theta_r=10.0, phi_r=180.0) | bad
    with pytest.raises(GeometryError, match=next(iter(bad))):
        Geometry(**kw)


def test_azimuth_normalised_including_the_rounding_to_360():
    assert Geometry(10, 360.0, 10, -1e-14).phi_i == 0.0
    assert Geometry(10, 720.5, 10, 0).phi_i == pytest.approx(0.5)
    assert Geometry(10, 0, 10, -1e-14).phi_r < 360.0  # naive (-x % 360) gives exactly 360.0


def test_spherical_is_stable_at_the_pole_and_past_unit_length():
    # acos(z) for z = 1 + 2e-16 is NaN; atan2 is not
    assert spherical(np.array([0.0, 0.0, 1.0 + 2e-16])) == (0.0, 0.0)
    t, p = spherical(np.array([0.0, 0.0, -1.0]))
    assert t == 180.0 and p == 0.0
    t, p = spherical(np.array([1e-300, -1e-300, 1.0]))
    assert math.isfinite(t) and 0 <= p < 360


@given(st.floats(0, 180), st.floats(0, 359.999))
def test_direction_and_spherical_round_trip(theta, phi):
    t, p = spherical(direction(theta, phi))
    assert t == pytest.approx(theta, abs=1e-9)
    if 1e-6 < theta < 180 - 1e-6:
        assert min(abs(p - phi), 360 - abs(p - phi)) == pytest.approx(0.0, abs=1e-6)


def test_cie_geometries_and_aliases():
    assert set(CIE_GEOMETRIES) >= {"45/0", "0/45", "d/0", "0/d", "8/d"}
    assert cie_geometry("45:0").name == "45/0"
    assert cie_geometry("di:8").name == "8/d"
    d0 = cie_geometry("d/0").reciprocal_directional
    assert d0.illumination == "directional" and d0.theta_i == 0.0 and d0.viewing == "diffuse"
    with pytest.raises(GeometryError, match="unknown CIE geometry"):
        cie_geometry("47/3")


def test_the_cone_quadrature_keeps_numpys_cross_product_and_gauss_legendre_rule_bit_for_bit():
    """The cone's frame and rule are computed without np.cross's axis handling and with the rule
    remembered per order: the same bits as numpy's own, which the recorded fits were made with."""
    from bench.core.geometry import _cross, gauss_legendre

    rng = np.random.default_rng(3)
    for a, b in rng.normal(size=(500, 2, 3)):
        assert np.array_equal(_cross(a, b), np.cross(a, b))
    for n in (1, 4, 8):
        x, w = np.polynomial.legendre.leggauss(n)
        got = gauss_legendre(n)
        assert np.array_equal(got[0], x) and np.array_equal(got[1], w)
        assert not got[0].flags.writeable  # shared: nobody may change the remembered rule
