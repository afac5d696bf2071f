"""The control chart of a check standard over a month of simulated days on the virtual body, with
and without a declared drift: its false-alarm rate and detection delay are those its rules
predict for the chart's sigma.

Per seed (16): ``bench check`` of a Lambertian 0.5 standard on each day of November 2026 (a fresh
noise seed per day), ``bench chart`` from the store: centre and sigma from the first 10 days
(mean, mean moving range / 1.128), the five Western Electric / Nelson rules. The drifted bench
is the same bench with ``[drift] start = 2026-11-16, white_per_day = -0.002``: identical up to
the 16th (its store is the undrifted one's up to then), then the working white soils 0.2 % a day
so the standard reads 1 / (1 - 0.002 d) of its model d days later.

The bench's day-to-day sigma of the check value (reading / reference, pooled over the 16
undrifted months): 0.0037, so the drift is ~0.54 sigma a day. Predicted for that sigma (the same
chart procedure on independent normal points, 4000 fixed-seed trials):
  * false alarm: P(any rule fires on days 11-30 of an undrifted month) = 0.45 (all five rules
    over 20 points, limits estimated from 10: the supplementary rules are not free, as ISO 7870-2
    and the NIST/SEMATECH handbook warn); over 16 months the central 99.8 % is 2..13 alarms;
  * detection delay (days from the drift's start to the first flag on a drifted day): mean 4.1,
    sd 1.7, never missed within the month.
Measured (16 seeds): 9 of 16 undrifted months raised a false alarm (0.56), and every drift was
flagged, after 3.4 days on average (1 to 6 days; predicted 4.1 +- 0.4 standard error).
Asserted: the false alarms within the central 99.8 % of Binomial(16, p_predicted), the mean
delay within 4 standard errors of the predicted mean, every drift flagged (the power, against
the undrifted months' size). ~55 CPU-s: slow.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy import stats

from compare.control import chart
from tests.helpers.cli import run_main
from tests.test_assurance import _bench

SEEDS, DAYS, BASELINE, START, PER_DAY = 16, 30, 10, 16, -0.002
DRIFT = f'[drift]\nstart = "2026-11-{START:02d}"\nwhite_per_day = {PER_DAY}\n'


def _check(capsys, bench, store, day: int, seed: int) -> float:
    code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--seed", 1000 * seed + day,
                              "--date", f"2026-11-{day:02d}", "--json")
    assert code == 0, err
    return json.loads(out)["checks"][0]["value"]


def _chart(capsys, bench, store) -> dict:
    code, out, err = run_main(capsys, "chart", "--bench", bench, "--store", store, "--json")
    assert code == 0, err
    return json.loads(out)["charts"][0]


def _predicted(sigma: float, centre: float, trials: int = 4000) -> tuple[float, np.ndarray]:
    """The procedure on independent normal points: P(false alarm after the baseline), and the
    delays of the declared drift (in units of the chart's sigma, as the bench drifts)."""
    rng = np.random.default_rng(0)
    days = np.arange(1, DAYS - START + 1)
    ramp = centre * (1 / (1 + PER_DAY * days) - 1) / sigma
    alarms, delays = 0, []
    for _ in range(trials):
        z = rng.standard_normal(DAYS)
        alarms += any(v.index >= BASELINE for v in chart(z, baseline=BASELINE).violations)
        z[START:] += ramp
        hits = [v.index for v in chart(z, baseline=BASELINE).violations if v.index >= START]
        delays.append(hits[0] - START + 1 if hits else np.inf)
    return alarms / trials, np.array(delays)


@pytest.mark.slow
def test_a_month_of_checks_false_alarms_and_detects_a_drift_as_the_rules_predict(capsys, tmp_path):
    (tmp_path / "u").mkdir()
    (tmp_path / "d").mkdir()
    steady = _bench(tmp_path / "u", assurance="off")
    steady.write_text(steady.read_text().replace("baseline = 5", f"baseline = {BASELINE}"))
    drifted = _bench(tmp_path / "d", assurance="off", drift=DRIFT)
    drifted.write_text(drifted.read_text().replace("baseline = 5", f"baseline = {BASELINE}"))
    # the drifted bench is the steady one up to the drift's start (nothing else simulated)
    assert _check(capsys, drifted, tmp_path / "x.sqlite", START, 0) == _check(capsys, steady, tmp_path / "y.sqlite",
                                                                              START, 0)
    values, alarms, delays = [], 0, []
    for seed in range(SEEDS):
        u, d = tmp_path / f"u{seed}.sqlite", tmp_path / f"d{seed}.sqlite"
        for day in range(1, START + 1):
            _check(capsys, steady, u, day, seed)
        shutil.copy(u, d)  # the same days, measured once
        for day in range(START + 1, DAYS + 1):
            _check(capsys, steady, u, day, seed)
            _check(capsys, drifted, d, day, seed)
        c = _chart(capsys, steady, u)
        assert len(c["values"]) == DAYS and c["baseline"] == BASELINE and not c["declared"]
        values.append(c["values"])
        alarms += any(v["index"] >= BASELINE for v in c["violations"])
        hits = [v["index"] for v in _chart(capsys, drifted, d)["violations"] if v["index"] >= START]
        delays.append(hits[0] - START + 1 if hits else np.inf)
    v = np.array(values)
    sigma = float(np.sqrt(v.var(axis=1, ddof=1).mean()))  # the bench's day-to-day sigma, pooled over seeds
    p, predicted = _predicted(sigma, float(v.mean()))
    lo, hi = stats.binom.ppf([0.001, 0.999], SEEDS, p)
    delays = np.array(delays)
    report = (f"sigma {sigma:.4g}; false alarms {alarms}/{SEEDS} (predicted p {p:.3f}, range {lo:.0f}..{hi:.0f}); "
              f"delays {delays.tolist()} (mean {delays.mean():.2f}, predicted {predicted.mean():.2f} "
              f"sd {predicted.std():.2f})")
    print(report)
    assert 0.3 < p < 0.6 and np.isfinite(predicted).all(), report  # the prediction stated above
    assert lo <= alarms <= hi, report
    assert np.isfinite(delays).all(), report  # every drift flagged within the month
    assert abs(delays.mean() - predicted.mean()) <= 4 * predicted.std() / np.sqrt(SEEDS), report
    # power against size: the drift is flagged in every month, the steady bench in fewer
    assert np.isfinite(delays).sum() > alarms, report
