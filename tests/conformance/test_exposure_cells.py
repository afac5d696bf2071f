"""Exposure x body cells of the conformance matrix, and seeds on each body.

* over full scale (the brightest expected scan at 2x the detector's room): refused before any
  motion, in one line naming the reading and its predicted counts, on every body (virtual,
  emulated, the real description over the emulators) -- the prediction reads the description,
  so the bodies refuse alike;
* near full scale (~85 % of the room): every reading unmasked (no body saturates where the
  description says it will not) and within its uncertainty of the truth (the invariant);
* nominal: the invariant;
* seeds: the same cell at two seeds reads different noise on each body (``--seed`` governs the
  virtual body's Monte Carlo and detector, the emulators' noise, and the emulators the real
  description points at).

The false-alarm rates are the harness's (:mod:`invariant`). Fast cells (make test): the three
refusals and the virtual near cell; the others are slow.
"""

from __future__ import annotations

import numpy as np
import pytest

from harness import Cell, run_cell

BODIES = ("virtual", "emulated", "real")


def _cell(specimen: str, body: str, exposure: str, seed: int = 1) -> Cell:
    """A scan cell with a dark once; the white measured in the run, or on the real body (no
    operator at a terminal during a scan) a white file stored beforehand with ``bench white --yes``."""
    return Cell(specimen, body, "file" if body == "real" else "once", "once", "scan", exposure, seed)


@pytest.mark.parametrize("body", BODIES)
def test_over_full_scale_is_refused_before_motion_on_every_body(conform, body):
    outcome, bad = conform(_cell("lambert", body, "over"))
    assert outcome.refused, outcome.statuses
    assert bad == [], bad
    assert outcome.moves == 0 and "would saturate" in outcome.refusal and "counts per scan" in outcome.refusal


def _near(conform, body: str, specimen: str) -> None:
    outcome, bad = conform(_cell(specimen, body, "near"))
    assert not outcome.refused, outcome.refusal
    assert bad == [], bad
    df = outcome.readings
    assert len(df) > 0 and not df["masked"].any() and int(df["saturated"].sum()) == 0
    assert outcome.statuses == ["completed"]


def test_near_full_scale_reads_unmasked_and_true_on_the_virtual_body(conform):
    _near(conform, "virtual", "lambert")


@pytest.mark.slow
@pytest.mark.parametrize("body", ("emulated", "real"))
@pytest.mark.parametrize("specimen", ("lambert", "ggx"))
def test_near_full_scale_reads_unmasked_and_true(conform, body, specimen):
    _near(conform, body, specimen)


@pytest.mark.slow
@pytest.mark.parametrize("body", BODIES)
def test_nominal_exposure_holds_the_invariant(conform, body):
    outcome, bad = conform(_cell("plastic", body, "nominal"))
    assert not outcome.refused and bad == [], bad


@pytest.mark.slow
@pytest.mark.parametrize("body", BODIES)
def test_seeds_change_the_noise_on_every_body(tmp_path, body):
    signals = []
    for seed in (1, 2):
        outcome = run_cell(_cell("lambert", body, "nominal", seed), tmp_path / f"s{seed}")
        assert not outcome.refused, outcome.refusal
        df = outcome.readings.sort_values(["idx", "wavelength_nm"])
        signals.append(df["signal"].to_numpy(float))
    assert signals[0].shape == signals[1].shape and not np.array_equal(*signals)
