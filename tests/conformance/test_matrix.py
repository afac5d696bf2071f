"""The conformance matrix: one invariant (:mod:`harness`, :mod:`invariant`) for every cell of
known specimen x body x calibration x darks x interface x exposure x seed.

The fast slice (``FAST``, run by ``make test``) takes a few representative cells; the whole matrix
(``@pytest.mark.slow``, ``make test-slow`` / ``make test-all``) is built below.
"""

from __future__ import annotations

import pytest

from harness import Cell, check_invariant, run_cell

#: representative cells, one per body and interface family, every specimen (make test)
FAST = [
    Cell("lambert", "virtual", "once", "once", "scan", fit=True),
    Cell("plastic", "emulated", "file", "per-incidence", "scan"),
    Cell("ggx", "virtual", "repeated", "none", "scan"),
]


@pytest.mark.parametrize("cell", FAST, ids=lambda c: c.id)
def test_fast_slice(conform, cell):
    outcome, bad = conform(cell)
    assert bad == [], f"{cell.id}: {bad}"


def test_power_a_truth_3_percent_off_is_caught(tmp_path):
    """The same record judged against a truth 3 % high and 3 % low: the invariant fails both."""
    outcome = run_cell(Cell("lambert", "emulated", "once", "once", "scan", seed=3), tmp_path)
    assert check_invariant(outcome) == []
    for scale in (1.03, 0.97):
        assert any("relative bias" in b for b in check_invariant(outcome, scale=scale)), scale


def test_power_a_wrong_certificate_is_caught(conform):
    """The description declares a 0.96 certificate for the 0.99 standard its white file was
    measured with: every value 3 % low, and the cell fails."""
    outcome, bad = conform(Cell("plastic", "virtual", "file", "once", "scan", perturb="certificate"))
    assert outcome.readings is not None and any("relative bias" in b for b in bad), bad
