"""Accuracy per bench-minute: fitted interval widths of the uniform in-plane plan, a designed plan and
the sequential design, on the emulated bench (real drivers over the wire emulators).

Specimen ``plastic:alpha=0.15,kd=0.5`` (eta = 1.5), model ``plastic:alpha=?,kd=?``. The designs
start from the family's declared defaults (alpha = 0.1, kd = 0.5) as the prior -- a guess, not the
truth -- and average their criterion over the prior range around it (each free parameter / 4 .. x 4,
``bench plan --design``'s default); the sequential design corrects the guess from its own fits. Every plan is scanned on the emulated
body with emulator seeds 7, 8, 9 and fitted with the bench's likelihood
(:func:`bench.identify.design_sequential.fit_readings`: the readings' full covariance). Bench time is
``bench plan``'s estimate. Reported: median and range over the seeds of each 95 % interval width,
the ratio of medians to the uniform plan's, and in how many seeds the interval contains the truth.

The designed plans are D-optimal (the default) unless named A-optimal. The study itself is
:mod:`bench.identify.design_study` (also ``bench tradeoff --design``); this is its table.

``python -m benchmarks design`` (several CPU-minutes: 18 emulated scans and 24 fits).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from benchmarks.common import table
from bench.identify import design_study

ROOT = Path(__file__).resolve().parent.parent
MODEL = "plastic:alpha=?,kd=?"
TRUTH = {"alpha": 0.15, "kd": 0.5}
SEEDS = design_study.SEEDS


def description() -> dict[str, Any]:
    """The shipped emulated bench holding the benchmark's specimen (the study sets each seed)."""
    from bench.core.parsing import read_toml

    d = copy.deepcopy(read_toml(ROOT / "fixtures" / "benches" / "emulated.toml", "bench config"))
    d["specimen"]["spec"] = "plastic:" + ",".join(f"{k}={v:g}" for k, v in TRUTH.items())
    return d


def measure(seeds: tuple[int, ...] = SEEDS) -> dict[str, Any]:
    """Scan and fit every method on every seed (:func:`bench.identify.design_study.measure`)."""
    return design_study.measure(MODEL, description(), seeds=seeds)


def run() -> str:
    m = measure()
    cpu = m["cpu"]
    title = (f"Accuracy per bench-minute, {MODEL} on the emulated bench, truth "
             f"{', '.join(f'{k}={v:g}' for k, v in TRUTH.items())}, prior {m['prior']}, seeds {list(SEEDS)} "
             f"({cpu.get('model', '?')})")
    notes = "\n".join(f"  {n}: {x['points']} points at {x['integration_s']:g} s, predicted widths "
                      + ", ".join(f"{k} {v:.3g}" for k, v in x["predicted_widths"].items())
                      for n, x in m["designs"].items())
    return table(title, design_study.header(m), design_study.summary(m)) + "\n" + notes
