"""Four-axis gonioreflectometer kinematics: round trips, canonical poles and safety rules."""

from __future__ import annotations


import pydantic
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.core.errors import ConfigError, GeometryError
from bench.core.geometry import Geometry
from drivers.kinematics import (
    Joints,
    KinematicsConfig,
    canonical,
    check,
    geometry_to_joints,
    joints_to_geometry,
    violations,
    wrap180,
)

TOL = 1e-9


def adiff(a: float, b: float) -> float:
    return abs(wrap180(a - b))


def assert_same(a: Geometry, b: Geometry, tol: float = TOL) -> None:
    assert abs(a.theta_i - b.theta_i) <= tol and abs(a.theta_r - b.theta_r) <= tol, (a, b)
    assert adiff(a.phi_i, b.phi_i) <= tol and adiff(a.phi_r, b.phi_r) <= tol, (a, b)


theta = st.one_of(st.just(0.0), st.floats(0.0, 85.0, allow_nan=False))
phi = st.floats(0.0, 360.0, allow_nan=False, exclude_max=True)
geometries = st.builds(Geometry, theta, phi, theta, phi)
joint_limits = st.sampled_from([
    {},
    {"turntable": (0.0, 360.0), "detector_azimuth": (0.0, 360.0)},
    {"turntable": (-400.0, 400.0), "detector_azimuth": (-720.0, 720.0)},
])


@settings(max_examples=400, deadline=None)
@given(geometries, joint_limits)
def test_round_trip_geometry_joints_geometry(g: Geometry, limits: dict) -> None:
    cfg = KinematicsConfig(limits=limits)
    j = geometry_to_joints(g, cfg)
    for name, v in j.as_dict().items():
        lo, hi = cfg.limits[name]
        assert lo <= v <= hi
    assert_same(joints_to_geometry(j), canonical(g))


@settings(max_examples=200, deadline=None)
@given(geometries, st.builds(Joints, st.floats(-180, 180), st.floats(0, 85),
                             st.floats(-180, 180), st.floats(0, 85)))
def test_round_trip_with_a_current_position(g: Geometry, near: Joints) -> None:
    cfg = KinematicsConfig(limits={"turntable": (-400.0, 400.0)})
    j = geometry_to_joints(g, cfg, near=near)
    assert_same(joints_to_geometry(j), canonical(g))
    # the nearest representative of the turntable angle is chosen
    assert abs(j.turntable - near.turntable) <= 180.0 + TOL


@settings(max_examples=200, deadline=None)
@given(st.builds(Joints, st.floats(-180, 180), st.floats(0, 85), st.floats(-180, 180),
                 st.floats(0, 85)))
def test_round_trip_joints_geometry_joints(j: Joints) -> None:
    g = joints_to_geometry(j)
    j2 = geometry_to_joints(g, near=j)
    g2 = joints_to_geometry(j2)
    assert_same(g2, g)
    assert abs(j2.source - j.source) <= TOL and abs(j2.detector_elevation - j.detector_elevation) <= TOL
    if j.source > 0:
        assert adiff(j2.turntable, j.turntable) <= TOL
    if j.source > 0 and j.detector_elevation > 0:  # else that joint is free (pole)
        assert adiff(j2.detector_azimuth, j.detector_azimuth) <= 1e-8


def test_layout_is_documented_mapping() -> None:
    j = geometry_to_joints(Geometry(30.0, 40.0, 50.0, 100.0))
    assert j == pytest.approx(Joints(40.0, 30.0, 60.0, 50.0))
    j = geometry_to_joints(Geometry.in_plane(45.0, 45.0))  # specular, in plane
    assert j.detector_azimuth == pytest.approx(180.0)


def test_poles_are_canonical() -> None:
    g = Geometry(0.0, 123.0, 0.0, 77.0)
    assert canonical(g) == Geometry(0.0, 0.0, 0.0, 0.0)
    j = geometry_to_joints(g)
    assert j == Joints(0.0, 0.0, 0.0, 0.0)
    assert joints_to_geometry(j) == Geometry(0.0, 0.0, 0.0, 0.0)
    # source on the normal: the detector goes opposite the source arm, whatever phi_i says
    j = geometry_to_joints(Geometry(0.0, 0.0, 45.0, 0.0))
    assert adiff(j.detector_azimuth, 180.0) <= TOL and adiff(j.turntable, 180.0) <= TOL
    assert_same(joints_to_geometry(j), Geometry(0.0, 0.0, 45.0, 0.0))
    near = Joints(33.0, 0.0, 44.0, 0.0)
    assert geometry_to_joints(Geometry(0.0, 5.0, 0.0, 6.0), near=near) == near
    # at theta_r = 0 the detector azimuth stays where it is
    near = Joints(0.0, 10.0, 57.0, 20.0)
    assert geometry_to_joints(Geometry(10.0, 0.0, 0.0, 0.0), near=near).detector_azimuth == 57.0


def _refused(g: Geometry, rule: str, cfg: KinematicsConfig | None = None) -> GeometryError:
    with pytest.raises(GeometryError) as ei:
        check(g, cfg)
    assert ei.value.geometry is g
    assert str(ei.value).startswith(rule + ":"), str(ei.value)
    assert str(g) in str(ei.value)
    return ei.value


def test_rules_name_themselves() -> None:
    _refused(Geometry(90.0, 0.0, 30.0, 180.0), "source_hemisphere")
    _refused(Geometry(95.0, 0.0, 30.0, 180.0), "source_hemisphere")
    _refused(Geometry(30.0, 0.0, 88.0, 180.0), "joint_limit")
    _refused(Geometry(30.0, 0.0, 120.0, 180.0), "joint_limit")  # no transmission arm by default
    _refused(Geometry(30.0, 0.0, 32.0, 2.0), "beam_block")
    _refused(Geometry(30.0, 90.0, 29.0, 90.0), "beam_block")
    # detector below the source head, on the source's side: hits the source boom
    _refused(Geometry(30.0, 0.0, 60.0, 0.0), "arm_collision")
    _refused(Geometry(40.0, 200.0, 80.0, 195.0), "arm_collision")


def test_reachable_geometries_pass() -> None:
    for g in (Geometry.in_plane(45.0, 45.0), Geometry.in_plane(45.0, 0.0), Geometry.in_plane(60.0, -20.0),
              Geometry(45.0, 0.0, 45.0, 90.0), Geometry(45.0, 10.0, 60.0, 60.0),
              Geometry(0.0, 0.0, 45.0, 0.0), Geometry(8.0, 0.0, 0.0, 0.0)):
        j = check(g)
        assert isinstance(j, Joints)
        assert violations(g) == []


def test_margins_are_configurable() -> None:
    g = Geometry(30.0, 0.0, 33.0, 2.0)
    _refused(g, "beam_block")
    check(g, KinematicsConfig(min_retro_deg=1.0, arm_clearance_deg=1.0))
    g = Geometry(30.0, 0.0, 60.0, 0.0)
    _refused(g, "arm_collision")
    check(g, KinematicsConfig(arm_clearance_deg=0.0))
    cfg = KinematicsConfig.from_dict({"limits": {"detector_elevation": [0, 170]}})
    check(Geometry(30.0, 0.0, 150.0, 180.0), cfg)  # transmission arm allowed


def test_several_rules_are_all_mentioned() -> None:
    e = _refused(Geometry(95.0, 0.0, 96.0, 0.0), "source_hemisphere")
    assert "joint_limit" in str(e) and "beam_block" in str(e)


def test_config_from_dict() -> None:
    cfg = KinematicsConfig.from_dict({"min_retro_deg": 3, "limits": {"source": [0, 80]}})
    assert cfg.min_retro_deg == 3.0 and cfg.limits["source"] == (0.0, 80.0)
    assert cfg.limits["turntable"] == (-180.0, 180.0)
    assert KinematicsConfig.from_dict(cfg.as_dict()) == cfg
    with pytest.raises(ConfigError, match="kinematics: unknown key 'min_retro'; did you mean 'min_retro_deg'"):
        KinematicsConfig.from_dict({"min_retro": 3})
    with pytest.raises(ConfigError, match=r"kinematics: key limits\.elbow: input should be 'turntable'"):
        KinematicsConfig.from_dict({"limits": {"elbow": [0, 1]}})
    with pytest.raises(ConfigError, match="source = \\[10, 0\\]: expected \\[lo, hi\\] degrees with lo <= hi"):
        KinematicsConfig.from_dict({"limits": {"source": [10, 0]}})
    with pytest.raises(ConfigError, match="key arm_clearance_deg: input should be greater than or equal to 0"):
        KinematicsConfig.from_dict({"arm_clearance_deg": -1})
    with pytest.raises(ConfigError, match="key min_retro_deg: expected a finite number"):
        KinematicsConfig(min_retro_deg=float("inf"))
    with pytest.raises(pydantic.ValidationError, match="frozen"):
        cfg.min_retro_deg = 1.0


def test_periodic_joint_outside_limits() -> None:
    cfg = KinematicsConfig(limits={"turntable": (-90.0, 90.0)})
    with pytest.raises(GeometryError, match="joint_limit.*turntable"):
        geometry_to_joints(Geometry(30.0, 180.0, 30.0, 0.0), cfg)
    assert geometry_to_joints(Geometry(30.0, 270.0, 30.0, 90.0), cfg).turntable == pytest.approx(-90.0)


def test_wrap180() -> None:
    assert wrap180(180.0) == 180.0 and wrap180(-180.0) == 180.0
    assert wrap180(540.0) == 180.0 and wrap180(-190.0) == 170.0
    assert math.isclose(wrap180(359.5), -0.5)
