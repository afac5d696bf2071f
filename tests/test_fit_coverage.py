"""Honest intervals: 200 synthetic records with known parameters per model, fitted with 95 %
profile-likelihood intervals; the fraction of intervals covering the truth must be 95 %.

Records: GGX alpha and plastic (alpha, kd) on a 5x12 collector at 30 deg, 200,000 rays, one
multinomial draw each from the certified patch probabilities; a leaf's N, Cab, Cw, Cm from
8/d spectra (400-2400 nm every 50 nm, 100,000 rays) drawn from ``prosail.run_prospect``. Seeds
are fixed.

The acceptance band, stated: for each of the 7 parameters the number of covering intervals out
of 200 must lie in [179, 198], the central band of Binomial(200, 0.95) with a two-sided
false-alarm rate of 0.089 % (scipy), i.e. at most 0.62 % over the 7 parameters. (The issue's
93-97 % band holds a correct method's count only 86 % of the time at n = 200 -- a 14 %
false-alarm rate per parameter, 66 % over seven -- so it is printed, not asserted.) Power: the
same fits' intervals narrowed to 80 % (the Hessian's +-1.28 se) must fall outside the band
(Binomial(200, 0.80) reaches 179 with probability 2e-5).

Measured (AMD EPYC Zen1, 2 cores, loaded): GGX 191/200, plastic alpha 187 and kd 188, leaf
N 189, Cab 186, Cw 188, Cm 189 -- every one inside the band and inside 93-97 %; the 80 %
intervals covered 154-166 of 200, all rejected. Cost: about 22 CPU-minutes in all (GGX and
plastic 750 CPU-s, leaf 600 CPU-s), hence ``slow``. No cheap twin runs in
``make test``: 40 records of the cheapest model (GGX) cost 20 CPU-s, over that budget; the
fast checks of tests/test_fit.py recover each parameter from one record.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom

from bench.identify import fit_record
from tests.helpers.fit_records import gonio_template, leaf_spectrum, redraw

pytestmark = pytest.mark.slow

RECORDS = 200
BAND = (int(binom.ppf(0.01 / 7 / 2, RECORDS, 0.95)), int(binom.isf(0.01 / 7 / 2, RECORDS, 0.95)))
Z80 = 1.2815515655446004


def _coverage(fits: list, truth: dict[str, float]) -> tuple[dict[str, int], dict[str, int]]:
    """Per parameter: intervals covering the truth, and (power) the 80 % Hessian intervals doing so."""
    cover = {k: 0 for k in truth}
    narrow = {k: 0 for k in truth}
    for res in fits:
        for k, v in truth.items():
            p = res.parameters[k]
            cover[k] += p.ci[0] <= v <= p.ci[1]
            narrow[k] += abs(p.value - v) <= Z80 * p.stderr
    return cover, narrow


def _check(name: str, fits: list, truth: dict[str, float]) -> None:
    assert all(r.converged for r in fits), name
    cover, narrow = _coverage(fits, truth)
    print(f"\n{name}: 95 % intervals covering the truth, out of {RECORDS}: {cover} "
          f"(issue's band 93-97 %: {[k for k, c in cover.items() if 0.93 <= c / RECORDS <= 0.97]} inside); "
          f"80 % intervals: {narrow}")
    for k in truth:
        assert BAND[0] <= cover[k] <= BAND[1], (name, k, cover[k], BAND)
        assert not BAND[0] <= narrow[k] <= BAND[1], (name, k, "power", narrow[k])


def test_band_is_the_stated_one():
    assert BAND == (179, 198)
    assert binom.cdf(BAND[0] - 1, RECORDS, 0.95) + binom.sf(BAND[1], RECORDS, 0.95) < 0.01 / 7


@pytest.mark.parametrize("specimen, model, seed", [
    ("ggx:alpha=0.3", "ggx:alpha=?0.05:0.8", 2700),
    ("plastic:alpha=0.2,kd=0.5", "plastic:alpha=?0.05:0.6,kd=?", 2701),
])
def test_gonio_intervals_cover_the_truth(specimen, model, seed):
    truth = {k: float(v) for k, v in (kv.split("=") for kv in specimen.split(":")[1].split(","))}
    template, p = gonio_template(specimen)
    rng = np.random.default_rng(seed)
    fits = [fit_record(redraw(template, p, 200_000, rng), model) for _ in range(RECORDS)]
    _check(specimen, fits, truth)


def test_leaf_intervals_cover_the_truth():
    truth = {"n": 1.6, "cab": 45.0, "cw": 0.012, "cm": 0.008}
    wl = np.arange(400.0, 2401.0, 50.0)
    rng = np.random.default_rng(2702)
    fits = [fit_record(leaf_spectrum(truth, wl, 100_000, rng), "leaf:n=?,cab=?,cw=?,cm=?") for _ in range(RECORDS)]
    _check("leaf", fits, truth)
