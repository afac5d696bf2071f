"""Designs robust to the prior (``bench plan --design``'s default): the criterion averaged over a
fixed-seed set of parameter points of a prior range (pseudo-Bayesian), and what that buys against
the uniform in-plane plan on the emulated bench (slow)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from bench.core.parsing import read_toml
from bench.identify import design_study
from bench.identify.design import PRIOR_DRAWS, PRIOR_SPREAD, criterion, mean_criterion
from bench.identify.design_io import model_point
from bench.identify.model_spec import parse_model_spec

BENCHES = Path(__file__).resolve().parent.parent / "fixtures" / "benches"
MODEL = "plastic:alpha=?,kd=?"


def test_prior_points_are_the_guess_and_a_fixed_latin_hypercube_within_the_range_and_bounds():
    point = model_point(parse_model_spec(MODEL))  # the declared defaults: alpha 0.1, kd 0.5
    assert point.spread == PRIOR_SPREAD
    pts = point.prior_points()
    assert len(pts) == 1 + PRIOR_DRAWS and dict(pts[0].values) == dict(point.values)
    assert [dict(p.values) for p in point.prior_points()] == [dict(p.values) for p in pts]  # fixed seed
    assert all(p.spread == 1.0 and p.prior_points() == [p] for p in pts)  # each point is a design at itself
    for k in point.free:
        v = point.values[k]
        lo, hi = max(v / PRIOR_SPREAD, 1e-4), min(v * PRIOR_SPREAD, 1.0)  # plastic's alpha, kd bounds
        drawn = np.array([p.values[k] for p in pts[1:]])
        assert ((drawn >= lo) & (drawn <= hi)).all(), (k, drawn)
        # one draw per stratum of the log range: a Latin hypercube, not a cluster
        strata = np.floor(np.log(drawn / lo) / np.log(hi / lo) * PRIOR_DRAWS).astype(int)
        assert sorted(strata) == list(range(PRIOR_DRAWS)), (k, strata)
    assert all(p.values["eta"] == point.values["eta"] for p in pts)  # a fixed parameter stays fixed
    assert model_point(parse_model_spec(MODEL), spread=1.0).prior_points() == [replace_spread(point, 1.0)]


def replace_spread(point, spread):
    from dataclasses import replace

    return replace(point, spread=spread)


def test_mean_criterion_averages_each_points_criterion():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 3, 4, 2))
    f = np.einsum("nmki,nmkj->nmij", a, a)  # 5 candidates x 3 prior points of 2x2 Fisher matrices
    for name in ("D", "A", "E"):
        want = np.array([[criterion(f[n, m], name) for m in range(3)] for n in range(5)]).mean(axis=1)
        assert mean_criterion(f, name) == pytest.approx(want, rel=1e-12)
        assert mean_criterion(f[0], name) == pytest.approx(want[0], rel=1e-12)
    singular = f.copy()
    singular[0, 1] = 0.0  # one point of the prior range learns nothing: the whole average is -inf
    assert mean_criterion(singular, "D")[0] == -math.inf and math.isfinite(mean_criterion(singular, "D")[1])


def test_the_cli_defaults_are_the_designs():
    """The CLI states the design's defaults without importing the design code: the copies agree."""
    from bench.cli.design import DEFAULT_INTEGRATIONS as CLI_INTEGRATIONS
    from bench.cli.design import PRIOR_SPREAD as CLI_SPREAD
    from bench.identify.time_model import DEFAULT_INTEGRATIONS

    assert CLI_SPREAD == PRIOR_SPREAD
    assert CLI_INTEGRATIONS == DEFAULT_INTEGRATIONS


def _emulated(spec: str) -> dict:
    d = copy.deepcopy(read_toml(BENCHES / "emulated.toml", "bench config"))
    d["specimen"]["spec"] = spec
    return d


def _ratios(m: dict) -> dict[int, dict[str, float]]:
    """Per seed, each parameter's designed / uniform fitted 95 % interval width."""
    res = m["results"]
    return {u["seed"]: {p: (d["fit"][p][2] - d["fit"][p][1]) / (u["fit"][p][2] - u["fit"][p][1]) for p in m["parameters"]}
            for u, d in zip(res["uniform in-plane"], res["designed"])}


# ~10 CPU-min on 2 loaded cores: 12 emulated scans and fits, 2 designs over 9 prior points
@pytest.mark.slow
@pytest.mark.parametrize("truth", ["plastic:alpha=0.15,kd=0.5", "plastic:alpha=0.4,kd=0.2"])
def test_the_default_design_beats_the_uniform_plan_by_0_7x_at_the_default_prior(truth):
    """At the default prior (alpha 0.1, kd 0.5), in the uniform plan's bench time, the designed plan's
    fitted 95 % intervals are at most 0.7x the uniform plan's on every seed 7, 8, 9, for a specimen
    near the prior and for a rough, dark one far from it (alpha x4, kd /2.5: the case the design at
    the guess alone lost, 0.72-0.89x), and hold the truth in at least 2 of 3 seeds (0.7 % false
    alarm per parameter if they are honest). Measured (AMD EPYC, 2 loaded cores), designed / uniform
    per seed 7, 8, 9, the design counting each dark as one offset shared by the readings it corrects
    (as the fit's covariance does): alpha 0.534, 0.493, 0.487 and kd 0.649, 0.614, 0.596 (0.15/0.5);
    alpha 0.411, 0.398, 0.418 and kd 0.502, 0.488, 0.507 (0.4/0.2); truth in 3/3 throughout."""
    m = design_study.measure(MODEL, _emulated(truth), methods=("uniform", "designed"))
    ratios = _ratios(m)
    assert sorted(ratios) == [7, 8, 9]
    assert all(r[p] <= 0.7 for r in ratios.values() for p in ("alpha", "kd")), ratios
    by = {r["method"]: r for r in design_study.rows(m)}
    assert all(by["designed"]["truth_in"][p] >= 2 for p in ("alpha", "kd")), by["designed"]
    assert m["designs"]["designed"]["prior_points"] == 1 + PRIOR_DRAWS


@pytest.mark.slow  # ~2 CPU-min: 2 emulated scans and fits, one design at the guess alone
def test_power_the_design_at_the_guess_alone_loses_the_gain_far_from_it():
    """The same rough, dark plastic, seed 7, designed at the default guess alone (``--prior-spread 1``,
    the earlier default): measured 0.80x (alpha) and 0.88x (kd) of the uniform plan's widths, so the
    0.7x bound above would fail for it: the bound can see what the prior range buys."""
    m = design_study.measure(MODEL, _emulated("plastic:alpha=0.4,kd=0.2"), seeds=[7], methods=("uniform", "designed"),
                             spread=1.0)
    assert m["designs"]["designed"]["prior_points"] == 1
    assert max(_ratios(m)[7].values()) > 0.7, _ratios(m)


LEAF = "leaf:roughness=?,eta=?"


# ~8 min on 2 cores (more when loaded): the leaf's cuticle albedo is rebuilt for every roughness and index a
# design or a fit tries (a design over 9 prior points, 2 emulated scans and fits)
@pytest.mark.slow
def test_a_leafs_cuticle_at_the_default_prior_the_design_narrows_both_below_0_7x():
    """A healthy leaf's angular parameters (cuticle roughness 0.2, wax index 1.45; the PROSPECT-D
    body fixed) at the default prior (0.3, 1.5), seed 7. Measured (AMD EPYC, 2 loaded cores),
    designed / uniform fitted widths per seed 7, 8, 9, the design counting each dark as one offset
    shared by the readings of its incidence and band (as the fit's covariance does; 28 points at
    0.05 s): roughness 0.577, 0.584, 0.562; index 0.647, 0.649, 0.635. Counting each dark per
    reading it gave roughness 0.45, 0.44, 0.44 and index 0.71, 0.70, 0.68 (61 points at 0.02 s):
    the index at 0.7x, not below it. This pins what the design buys: both narrower, the roughness
    by more than 0.7x, and the plan header's Cramer-Rao widths at the guess within 2x of the
    fitted ones (measured 1.84-1.93x and 1.36-1.39x, pessimistic: the guess is rougher than the
    leaf)."""
    m = design_study.measure(LEAF, _emulated("leaf:healthy,roughness=0.2,eta=1.45"), seeds=[7],
                             methods=("uniform", "designed"))
    d = _ratios(m)[7]
    assert d["roughness"] <= 0.7 and d["eta"] <= 0.7, d  # the index was 0.71 while the design counted each dark per reading
    fitted = {p: m["results"]["designed"][0]["fit"][p][2] - m["results"]["designed"][0]["fit"][p][1] for p in m["parameters"]}
    predicted = m["designs"]["designed"]["predicted_widths"]
    assert all(0.5 <= predicted[p] / fitted[p] <= 2.0 for p in m["parameters"]), (predicted, fitted)
    # the estimates within 0.5 % of the truth (and within 1.6 of their standard errors on seeds
    # 7-9 since each band is predicted as its pixels' mean and the emulated detector reads each
    # pixel at its own wavelength: tests/conformance/test_spectral_bands.py asserts that)
    for runs in m["results"].values():
        assert all(abs(runs[0]["fit"][p][0] - t) < 5e-3 * t for p, t in m["truth"].items()), runs[0]["fit"]


# ~25 min on 2 loaded cores: the uniform scan and fit, then three designed steps each scanned and
# fitted with every reading so far (the first design over 9 prior points)
@pytest.mark.slow
def test_a_leafs_cuticle_the_sequential_design_clears_0_7x_on_both():
    """The same leaf, seed 7, measured with the sequential design (``bench scan --sequential``: a
    first design over the prior range spends 40 % of the uniform plan's bench time, each later
    step is designed at the fit of every reading so far): where the one-shot design at the prior
    left the index at 0.68-0.71x (0.64-0.65x once it counted the darks as the record does), the
    re-centred steps buy the specular points that fix it.
    Measured (AMD EPYC, 2 loaded cores), sequential / uniform fitted widths, seed 7: roughness
    0.378, index 0.575 with the darks shared (0.385, 0.581 before; docs/design.md gives seeds 8 and 9); the bound 0.7 is the issue's target, the
    truth must lie within 3 standard errors (a 0.3 % false alarm per parameter for honest errors)."""
    m = design_study.measure(LEAF, _emulated("leaf:healthy,roughness=0.2,eta=1.45"), seeds=[7],
                             methods=("uniform", "sequential"))
    res = m["results"]
    u, s = res["uniform in-plane"][0], res["sequential"][0]
    ratios = {p: (s["fit"][p][2] - s["fit"][p][1]) / (u["fit"][p][2] - u["fit"][p][1]) for p in m["parameters"]}
    assert all(r <= 0.7 for r in ratios.values()), ratios
    assert s["seconds"] <= u["seconds"] * 1.001, (s["seconds"], u["seconds"])  # at equal bench time, not more
    for p, t in m["truth"].items():
        value, lo, hi = s["fit"][p]
        assert abs(value - t) <= 3 * (hi - lo) / (2 * 1.959963984540054), (p, s["fit"][p], t)


# ~3 min on 2 cores: three seeds of the uniform scan and fit and the three-step sequential design
@pytest.mark.slow
def test_ggx_the_sequential_design_clears_0_7x_on_both_on_every_seed():
    """A GGX conductor (alpha 0.3, eta 2.5) from the default prior (alpha 0.2, eta 1.5): the case
    the one-shot design cannot clear robustly. Its roughness sits at 0.69x of the uniform plan's
    width by the Cramer-Rao bound at the truth with the default 8 prior draws, 0.74-0.75x with 24
    or 32 (the 8 draws' figure is the luck of their places), and 0.63x for the D design made at
    the truth itself: the D criterion buys the index first. The sequential design re-centres on
    the estimate and clears 0.7x on every seed. Measured (AMD EPYC Zen 3, 2 cores), sequential /
    uniform fitted widths, seeds 7, 8, 9: alpha 0.639, 0.610, 0.624; eta 0.362, 0.339, 0.338; the
    truth within 3 standard errors (0.3 % false alarm per parameter for honest errors)."""
    m = design_study.measure("ggx:alpha=?,eta=?", _emulated("ggx:alpha=0.3,eta=2.5"), methods=("uniform", "sequential"))
    res = m["results"]
    for u, s in zip(res["uniform in-plane"], res["sequential"]):
        ratios = {p: (s["fit"][p][2] - s["fit"][p][1]) / (u["fit"][p][2] - u["fit"][p][1]) for p in m["parameters"]}
        assert all(r <= 0.7 for r in ratios.values()), (u["seed"], ratios)
        assert s["seconds"] <= u["seconds"] * 1.001, (s["seconds"], u["seconds"])
        for p, t in m["truth"].items():
            value, lo, hi = s["fit"][p]
            assert abs(value - t) <= 3 * (hi - lo) / (2 * 1.959963984540054), (u["seed"], p, s["fit"][p], t)
