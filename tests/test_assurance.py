"""Measurement assurance end to end: declare check standards, measure them on simulated days,
chart them, and let ``bench scan`` warn or refuse -- on the virtual body (fast) and the emulated
body (real drivers over the emulators).

The drift is a declared effect of the simulated bodies (``[drift]``: the working white soils,
its certificate unchanged), so what a lab's chart must catch is simulated, not painted onto the
numbers: the readings of the check standard rise by 1 / (1 + white_per_day x days).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parent.parent

CHECK = '''
[[check]]
name = "grey tile"
specimen = "lambert:albedo=0.5"
geometries = [[30, 0, 20, 180], [30, 0, 50, 180]]
baseline = 5
'''


def _bench(tmp_path: Path, fixture: str = "virtual.toml", assurance: str = "refuse", drift: str = "") -> Path:
    text = (ROOT / "fixtures" / "benches" / fixture).read_text()
    head, sep, rest = text.partition("\n[")  # top-level keys go before the first table
    path = tmp_path / "bench.toml"
    path.write_text(f'{head}\nassurance = "{assurance}"\n{sep}{rest}\n{CHECK}\n{drift}')
    return path


def _check(capsys, bench: Path, store: Path, day: int, seed: int) -> dict:
    code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--seed", seed,
                              "--date", f"2026-12-{day:02d}", "--json")
    assert code == 0, err
    return json.loads(out)["checks"][0]


def _scan(capsys, bench: Path, store: Path, day: int, tmp_path: Path) -> tuple[int, str, str]:
    plan = tmp_path / "plan.toml"
    plan.write_text('name = "tiny"\nkind = "list"\nintegration_s = 0.02\npoints = [[30, 0, 20, 180]]\n')
    return run_main(capsys, "scan", plan, "--bench", bench, "--store", store, "--seed", 5, "--date",
                    f"2026-12-{day:02d}", "--quiet")


def test_a_check_scores_each_reading_as_an_en_number_against_the_standards_model(capsys, tmp_path):
    c = _check(capsys, _bench(tmp_path), tmp_path / "s.sqlite", 1, 1)
    assert c["check"] == "grey tile" and c["date"] == "2026-12-01" and len(c["readings"]) == 6
    for r in c["readings"]:  # Lambertian 0.5: BRDF 0.5 / pi at every geometry, an independent closed form
        # (up to the 1-degree detector cone the bench declares: a cos-weighted cone mean, < 1e-4)
        assert r["reference"] == pytest.approx(0.5 / math.pi, rel=1e-4)
    assert c["agree"] and abs(c["value"] - 1) < 0.02
    code, out, _ = run_main(capsys, "show", c["run"], "--store", tmp_path / "s.sqlite", "--json")
    shown = json.loads(out)
    assert code == 0 and shown["kind"] == "check" and shown["check"]["value"] == pytest.approx(c["value"])


def test_the_bench_refuses_to_report_when_overdue_or_out_of_control_and_says_why(capsys, tmp_path):
    """Five days in control, then the white soils 1 % a day from day 5 (its day 0): the chart
    flags it within two drifted days (day 7 reads ~2 % high, over 4 sigma of this chart: missed
    with a probability below 1e-4), the scan is refused naming the check, the rule and the date; with
    assurance = "warn" the scan runs, warns, and records the check it relied on. (The charts'
    false-alarm rates and run lengths, in and out of control, are measured against published
    values in tests/test_control_chart.py.)"""
    drift = '[drift]\nstart = "2026-12-05"\nwhite_per_day = -0.01\n'
    bench, store = _bench(tmp_path, drift=drift), tmp_path / "s.sqlite"
    code, _, err = _scan(capsys, bench, store, 1, tmp_path)
    assert code == 2 and "'grey tile' was never measured" in err and len(err.strip().splitlines()) == 1
    for day in range(1, 6):
        _check(capsys, bench, store, day, 10 + day)
    code, out, err = _scan(capsys, bench, store, 5, tmp_path)  # in control, checked today
    assert code == 0, err
    code, _, err = _scan(capsys, bench, store, 6, tmp_path)  # yesterday's check, due daily
    assert code == 2 and "due daily and was last measured on 2026-12-05" in err
    flagged_on = None
    for day in range(6, 12):
        _check(capsys, bench, store, day, 10 + day)
        code, out, err = run_main(capsys, "chart", "--bench", bench, "--store", store, "--json")
        last = json.loads(out)["charts"][0]
        if any(v["index"] == len(last["values"]) - 1 for v in last["violations"]):
            flagged_on = day
            break
    assert flagged_on is not None and flagged_on <= 7, last
    code, _, err = _scan(capsys, bench, store, flagged_on, tmp_path)
    assert code == 2 and "broke the rule" in err and f"2026-12-{flagged_on:02d}" in err
    warn = _bench(tmp_path, assurance="warn", drift=drift)
    code, out, err = _scan(capsys, warn, store, flagged_on, tmp_path)
    assert code == 0 and "warning:" in err and "broke the rule" in err
    run = out.strip().splitlines()[-1]
    code, out, _ = run_main(capsys, "show", run, "--store", store, "--json")
    relied = json.loads(out)["assurance"]
    assert relied["policy"] == "warn" and relied["checks"]["grey tile"]["state"] == "out of control"


def test_assurance_inputs_are_refused_in_one_line(capsys, tmp_path):
    bench = _bench(tmp_path)
    code, _, err = run_main(capsys, "check", "--bench", bench, "--store", tmp_path / "s.sqlite", "--check", "nope")
    assert code == 2 and "has no check named 'nope'; its checks: grey tile" in err
    both = tmp_path / "both.toml"
    both.write_text(bench.read_text().replace('specimen = "lambert:albedo=0.5"',
                                              'specimen = "lambert:albedo=0.5"\nreference = 0.16'))
    code, _, err = run_main(capsys, "check", "--bench", both, "--store", tmp_path / "s.sqlite")
    assert code == 2 and "not both or neither" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_main(capsys, "chart", "--bench", bench, "--store", tmp_path / "none.sqlite")
    assert code == 2
    real = tmp_path / "real.toml"
    real.write_text(_bench(tmp_path, "emulated.toml", drift='[drift]\nstart = "2026-12-06"\n').read_text())
    code, _, err = run_main(capsys, "check", "--bench", real, "--body", "real", "--store", tmp_path / "s.sqlite")
    assert code == 2 and "[drift] is simulated by the virtual and emulated bodies only" in err


@pytest.mark.slow
def test_the_emulated_body_drifts_as_declared(capsys, tmp_path):
    """The same declared drift through the real drivers and the emulators: the check value on
    the 10th drifted day is 1 / (1 - 0.004 x 10) of the first day's, within the readings' noise."""
    drift = '[drift]\nstart = "2026-12-02"\nwhite_per_day = -0.004\n'
    bench, store = _bench(tmp_path, "emulated.toml", drift=drift), tmp_path / "e.sqlite"
    first = _check(capsys, bench, store, 1, 1)["value"]
    later = _check(capsys, bench, store, 12, 2)["value"]
    assert later / first == pytest.approx(1 / (1 - 0.004 * 10), rel=2e-3)


def test_each_simulated_day_draws_noise_of_its_own_and_the_same_day_the_same(capsys, tmp_path):
    """Without --seed a bench's fixed seed would repeat one day's noise on every --date."""
    bench, store = _bench(tmp_path), tmp_path / "s.sqlite"
    values = []
    for day in (1, 2, 1):
        code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--date", f"2026-12-0{day}",
                                  "--json")
        assert code == 0, err
        values.append(json.loads(out)["checks"][0]["value"])
    assert values[0] != values[1] and values[0] == values[2]
