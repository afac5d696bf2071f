"""Plans: building from TOML, refusal naming every bad point, travel order, time estimate."""

import math
from pathlib import Path

import pytest

from bench.core.errors import ConfigError, GeometryError, PlanError
from bench.plans import (MotionProfile, estimate, half_vector_to_geometry, load_plan, order_for_travel,
                         plan_from_dict, validate)

FIXTURES = Path(__file__).parent.parent / "fixtures" / "plans"


@pytest.mark.parametrize("name,count", [("cie-spectral", 2), ("in-plane", 3 * 21), ("hemispherical", 2 * (1 + 5 * 12))])
def test_example_plans_load(name, count):
    plan = load_plan(FIXTURES / f"{name}.toml")
    assert len(plan) == count and plan.name == name


def test_spectral_plan_maps_cie_names_to_goniometer_geometries():
    plan = load_plan(FIXTURES / "cie-spectral.toml")
    g45_0, g0_45 = plan.points
    assert (g45_0.theta_i, g45_0.theta_r) == (45.0, 0.0)
    assert (g0_45.theta_i, g0_45.theta_r) == (0.0, 45.0)
    with pytest.raises(ConfigError, match="integrating sphere"):
        plan_from_dict({"kind": "spectral", "spectral": {"geometries": ["8/d"]}})


def test_validate_refuses_the_whole_plan_naming_each_bad_point():
    plan = plan_from_dict({"kind": "list", "points": [[10, 0, 20, 180], [95, 0, 20, 180], [30, 0, 30, 0],
                                                       [40, 0, 10, 180]]})
    calls = []

    def check(g):
        calls.append(g)
        if g.theta_i >= 90:
            raise GeometryError("source below the horizon", g)
        if g.angle_between_source_and_detector() < 5:
            raise GeometryError("detector blocks the beam", g)

    with pytest.raises(PlanError) as err:
        validate(plan, check)
    assert [i for i, _, _ in err.value.problems] == [1, 2]
    assert "point 1" in str(err.value) and "point 2" in str(err.value) and "2 of 4" in str(err.value)
    assert len(calls) == 4  # every point checked, not just up to the first bad one


@pytest.mark.parametrize("bad,needle", [({"kind": "spiral"}, "kind"), ({"kind": "list"}, "points"),
                                        ({"kind": "list", "points": [[1, 2, 3]]}, "point 0"),
                                        ({"kind": "in-plane", "averages": 0}, "averages"),
                                        ({"kind": "in-plane", "in_plane": {"theta_r": {"start": 5, "stop": 1, "step": 1}}},
                                         "start <= stop"),
                                        ({"kind": "in-plane", "dark": "sometimes"}, "dark")])
def test_bad_plans_name_the_key(bad, needle):
    with pytest.raises(ConfigError, match=needle):
        plan_from_dict(bad)


def test_travel_order_groups_incidences_and_sweeps_back_and_forth():
    plan = load_plan(FIXTURES / "in-plane.toml")
    order = order_for_travel(plan.points)
    assert sorted(order) == list(range(len(plan)))
    pts = [plan.points[i] for i in order]
    # incidences are contiguous
    seen, last = [], None
    for g in pts:
        if g.theta_i != last:
            assert g.theta_i not in seen
            seen.append(g.theta_i)
            last = g.theta_i
    # boustrophedon: the detector does not fly back between incidences
    assert pts[20].theta_r_signed == pts[21].theta_r_signed == 80.0


def test_estimate_counts_motion_acquisition_and_references_and_ordering_helps():
    plan = load_plan(FIXTURES / "in-plane.toml")
    prof = MotionProfile(velocity={"source": 10, "detector_elevation": 20, "detector_azimuth": 20, "turntable": 10},
                         acceleration={"source": 20, "detector_elevation": 40, "detector_azimuth": 40,
                                       "turntable": 20}, settle_s=0.1)
    good = estimate(plan, prof, order_for_travel(plan.points))
    naive = estimate(plan, prof, list(range(len(plan)))[::-1][::2] + list(range(len(plan)))[::-1][1::2])
    assert good["seconds"] < naive["seconds"]
    per_reading = plan.integration_s * plan.averages + 0.01 + prof.overhead_s
    assert good["acquisition_s"] == pytest.approx(len(plan) * per_reading)
    assert good["references_s"] == pytest.approx((3 + 1) * per_reading + 2 * 0.1)
    assert good["relative_uncertainty"] == pytest.approx(0.01 / math.sqrt(2))


def test_trapezoid_move_time():
    prof = MotionProfile(velocity={"source": 10.0}, acceleration={"source": 20.0}, settle_s=0.0)
    # short move: never reaches v: t = 2 sqrt(d/a)
    assert prof.move_time({"source": 0.0}, {"source": 2.0}) == pytest.approx(2 * math.sqrt(2 / 20))
    # long move: d/v + v/a
    assert prof.move_time({"source": 0.0}, {"source": 50.0}) == pytest.approx(5.0 + 0.5)


def test_half_vector_geometry_is_mirror_about_h():
    g = half_vector_to_geometry(0.0, 0.0, 30.0, 0.0)  # h on the normal: specular pair at 30 deg
    assert g.theta_i == pytest.approx(30.0) and g.theta_r == pytest.approx(30.0)
    assert abs(((g.phi_r - g.phi_i) % 360) - 180) < 1e-9
