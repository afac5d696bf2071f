"""Control charts of check standards: the run rules, the chart's limits and E_n numbers, checked
against published values, not against our own code.

Referees: the in-control average run length (ARL) of an individuals chart with the four Western
Electric rules is 91.75 points (Champ & Woodall, Technometrics 29 (1987) 393, table 2); with the
3-sigma rule alone it is 1 / P(|z| > 3) = 370.4 and, after a step of d sigma, 1 / (P(z > 3 - d) +
P(z < -3 - d)) (the geometric law of a per-point probability). Simulations use fixed seeds and
assert within 4 standard errors (a false-alarm rate of about 6e-5 per check).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from compare.control import RULES, chart, en_numbers, false_alarm_rate, run_length, violations

WE = ("beyond-3-sigma", "2-of-3-beyond-2-sigma", "4-of-5-beyond-1-sigma", "8-on-one-side")


def _tail(x: float) -> float:
    return 0.5 * math.erfc(x / math.sqrt(2))


def _run_lengths(rules, trials: int, shift: float = 0.0, n: int = 1500, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(trials):
        rl = run_length(rng.standard_normal(n) + shift, 0.0, 1.0, rules)
        out.append(n + 1 if rl is None else rl)
    return np.asarray(out, float)


@pytest.mark.parametrize("rule, fires, misses", [
    ("beyond-3-sigma", [0, 3.1], [0, 2.9]),
    ("2-of-3-beyond-2-sigma", [2.1, 0, 2.2], [2.1, 0, -2.2]),       # both beyond, but on two sides
    ("4-of-5-beyond-1-sigma", [1.1, 1.2, 0, 1.3, 1.4], [1.1, 1.2, 0, 0, 1.4]),
    ("8-on-one-side", [0.1] * 8, [0.1] * 7 + [-0.1]),
    ("6-trending", [-1, -0.5, 0, 0.2, 0.3, 0.9], [-1, -0.5, 0, 0.2, 0.3, 0.25]),
])
def test_each_rule_fires_on_its_pattern_and_not_on_a_near_miss(rule, fires, misses):
    hit = violations(fires, 0.0, 1.0, [rule])
    assert [v.index for v in hit] == [len(fires) - 1] and hit[0].text == RULES[rule]
    assert violations(misses, 0.0, 1.0, [rule]) == []


def test_the_in_control_run_length_of_the_four_western_electric_rules_is_champ_and_woodalls():
    rl = _run_lengths(WE, 2000)
    se = rl.std(ddof=1) / math.sqrt(rl.size)
    assert abs(rl.mean() - 91.75) < 4 * se, (rl.mean(), se)


def test_the_3_sigma_rule_alone_has_the_geometric_run_lengths_in_and_out_of_control():
    """Power of the check above: the 3-sigma rule alone runs 370 points in control, so the same
    comparison would reject it as a stand-in for the four rules; after a 1.5 sigma step it runs
    1 / (P(z > 1.5) + P(z < -4.5)) = 14.9 points."""
    rl = _run_lengths(["beyond-3-sigma"], 1500, n=6000, seed=2)
    se = rl.std(ddof=1) / math.sqrt(rl.size)
    assert abs(rl.mean() - 1 / (2 * _tail(3))) < 4 * se and abs(rl.mean() - 91.75) > 4 * se
    shifted = _run_lengths(["beyond-3-sigma"], 2000, shift=1.5, seed=3)
    expected = 1 / (_tail(1.5) + _tail(4.5))
    assert abs(shifted.mean() - expected) < 4 * shifted.std(ddof=1) / math.sqrt(shifted.size)


def test_a_drift_is_flagged_sooner_by_the_run_rules_than_by_3_sigma_alone():
    alone = _run_lengths(["beyond-3-sigma"], 1000, shift=1.0, seed=4).mean()
    rules = _run_lengths(tuple(RULES), 1000, shift=1.0, seed=4).mean()
    assert rules < alone / 3  # about 44 points with the 3-sigma rule alone, under 10 with the rules


def test_the_false_alarm_rate_of_a_30_point_chart_is_the_per_point_rate_compounded():
    p = false_alarm_rate(["beyond-3-sigma"], n_points=30, trials=4000, seed=5)
    expected = 1 - (1 - 2 * _tail(3)) ** 30
    assert abs(p - expected) < 4 * math.sqrt(expected * (1 - expected) / 4000)


def test_limits_come_from_the_baseline_or_are_declared():
    rng = np.random.default_rng(6)
    values = 0.5 + 0.01 * rng.standard_normal(20)
    c = chart(np.r_[values, 0.5 + 0.05], baseline=20)
    assert c.centre == pytest.approx(values.mean()) and c.baseline == 20 and not c.declared
    assert c.sigma == pytest.approx(np.abs(np.diff(values)).mean() / 1.128)
    assert c.violations[-1].index == 20 and c.violations[-1].rule == "beyond-3-sigma"
    assert c.limits["+3"] == pytest.approx(c.centre + 3 * c.sigma)
    fixed = chart([0.5, 0.51, 0.49], centre=0.5, sigma=0.01)
    assert fixed.declared and fixed.in_control and fixed.as_dict()["limits"]["-3"] == pytest.approx(0.47)


def test_bad_chart_inputs_say_what_is_wrong():
    with pytest.raises(ValueError, match="at least 2 baseline points"):
        chart([0.5])
    with pytest.raises(ValueError, match="finite"):
        chart([0.5, float("nan"), 0.4])
    with pytest.raises(ValueError, match="unknown control rule 'nine'"):
        violations([0.1], 0.0, 1.0, ["nine"])
    with pytest.raises(ValueError, match="sigma > 0"):
        violations([0.1], 0.0, 0.0)


def test_en_numbers_follow_iso_13528():
    # x = 0.52 (u 0.005), reference 0.50 (u 0.005): E_n = 0.02 / (2 * sqrt(2) * 0.005) = 1.414
    assert en_numbers([0.52], [0.005], [0.50], [0.005])[0] == pytest.approx(0.02 / (2 * math.sqrt(2) * 0.005))
    assert abs(en_numbers([0.505], [0.005], [0.50], [0.005])[0]) <= 1
