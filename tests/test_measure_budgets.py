"""The computing halves of `bench spectro` / `bench gonio` (bench.adaptive), called directly:
the budget chosen, the record measured and the rays spent, as values (the CLI's wording and
files are tested through the CLI in test_cli.py and test_measure_tradeoff.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.adaptive import (INTEREST_FRACTION, PILOT_RAYS, AdaptiveOutcome, GonioBudget, adaptive_message,
                            choose_gonio_budget, measure_adaptively, measure_gonio, relative_widths)
from virtual.spectrophotometer import VirtualSpectrophotometer

KW = {"collector": "equal-psa:3x8", "beam": "collimated", "seed": 5, "delta": 0.01, "wavelengths": "550",
      "method": "auto", "common_random_numbers": False}


def test_adaptive_spectrum_spends_fewer_rays_than_eq_3_5_and_meets_v():
    sp = VirtualSpectrophotometer("lambert:reflectance=0.05", rays=10, seed=1)
    o = measure_adaptively(sp, 0.005, 0.01, geometry="8/d", wavelengths="540,560")
    assert isinstance(o, AdaptiveOutcome) and not o.gonio
    assert o.hoeffding_N == 105_967 and len(o.per_wavelength) == 2
    assert o.N == max(o.per_wavelength) <= 105_967 / 4 and sp.rays == o.N
    assert o.saved_rays == 105_967 - o.N and o.saved_fraction == pytest.approx(o.saved_rays / 105_967)
    assert list(o.result.N) == o.per_wavelength and o.result.meta["budget"] == "adaptive"
    assert np.all(np.abs(o.result.reflectance - 0.05) <= 0.005)
    assert f"{o.N:,} rays per wavelength" in adaptive_message(o) and "saved" in adaptive_message(o)


def test_a_rule_run_to_its_cap_says_it_certifies_its_readings_jointly():
    o = AdaptiveOutcome(result=None, per_wavelength=[120, 150], hoeffding_N=100, mode="union", patches=2,
                        uncertainty=0.1, delta=0.05, gonio=True)
    assert o.N == 150 and o.saved_rays == -50 and o.saved_fraction == -0.5
    msg = adaptive_message(o)
    assert "50 more than eq. 3.12's 100" in msg and "its 2 readings jointly" in msg and "each patch" in msg


def test_the_three_gonio_budgets():
    fixed = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, rays=20_000)
    assert fixed.kind == "fixed rays" and fixed.instrument_kw["rays"] == 20_000 and not fixed.bounds_its_time
    default = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW)
    assert default.kind == "fixed rays" and "rays" not in default.instrument_kw and not default.bounds_its_time
    eq312 = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, patch_probability_uncertainty=0.02)
    assert eq312.adaptive and eq312.bounds_its_time and eq312.instrument_kw["uncertainty"] == 0.02
    fixed312 = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, patch_probability_uncertainty=0.02,
                                   adaptive=False)
    assert not fixed312.adaptive and not fixed312.bounds_its_time
    assert KW == {**KW} and "rays" not in KW  # the caller's keywords are not changed


def test_a_relative_budget_sizes_n_from_the_pilot_and_names_what_the_time_limit_leaves_out():
    rel = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, relative_uncertainty=0.3)
    plan = rel.relative
    assert rel.kind == "relative BSDF" and rel.bounds_its_time and not plan["capped"]
    assert plan["pilot_rays"] == PILOT_RAYS and plan["patches"] == 48 and plan["patches_of_interest"] == 24
    # the dimmest patch of interest decides: N = ceil(z^2 (1 - p) / (v^2 p))
    assert rel.instrument_kw["rays"] == plan["N"] == math.ceil(plan["z"] ** 2 * (1 - plan["p_min"])
                                                                / (0.09 * plan["p_min"]))
    capped = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, relative_uncertainty=0.01, max_seconds=1e-3,
                                 rays_per_second=1e7)
    assert capped.relative["capped"] and capped.instrument_kw["rays"] == 10_000
    assert capped.relative["needed"] > 10_000 and len(capped.relative["unreachable_patches"]) == 24


def test_measure_gonio_returns_the_record_and_what_it_achieved():
    budget = choose_gonio_budget("lambert:albedo=0.5", 40.0, 10.0, KW, rays=20_000)
    res = measure_gonio(budget.instrument("lambert:albedo=0.5"), budget, 40.0, 10.0)
    m = res.record.meta
    assert res.incidence == (40.0, 10.0) and res.adaptive is None
    assert (m["body"], m["bench_name"], m["plan_name"], m["incidence"]) == ("virtual", "virtual-gonio", "gonio",
                                                                          [40.0, 10.0])
    assert res.uncertainty == {"mode": "fixed rays", "N": 20_000}
    t = res.record.table
    up = t[t.value > 0]
    assert res.achieved == relative_widths(res.record)
    assert res.achieved["patches_of_interest"] == int((up.value >= INTEREST_FRACTION * up.value.max()).sum())
    b = res.achieved["brightest"]
    assert b["value"] == up.value.max()
    assert res.achieved["max_relative_half_width"] >= res.achieved["dimmest_of_interest"]["relative_half_width"]


def test_measure_gonio_under_eq_3_12_uses_the_adaptive_rule():
    budget = choose_gonio_budget("lambert:albedo=0.5", 30.0, 0.0, KW, patch_probability_uncertainty=0.02)
    res = measure_gonio(budget.instrument("lambert:albedo=0.5"), budget, 30.0, 0.0)
    assert isinstance(res.adaptive, AdaptiveOutcome) and res.adaptive.gonio
    assert res.record.meta["budget"] == "adaptive" and res.record.meta["rays"] == res.adaptive.N
    assert res.adaptive.N < res.adaptive.hoeffding_N
    assert res.uncertainty == {"mode": "patch probability (eq. 3.12)", "v": 0.02, "delta": 0.01}
    assert isinstance(budget, GonioBudget) and res.budget is budget
