"""Fixtures of the conformance matrix (:mod:`harness`): a fresh directory and store per cell,
the shipped bench descriptions (the emulated bench and its virtual twin), and ``conform``, which
runs a cell there and returns its violations of the invariant.

Other test files of this directory add their cells with them::

    from harness import Cell

    def test_my_seam(conform):
        outcome, bad = conform(Cell(specimen="plastic", body="emulated", calibration="file"))
        assert bad == []
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

import pytest

HERE = Path(__file__).resolve().parent
for path in (HERE, HERE.parent):  # harness/truth/invariant, and tests/ (store_probe, helpers)
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from harness import BENCHES, Cell, Outcome, verdict  # noqa: E402


@pytest.fixture
def store(tmp_path: Path) -> Path:
    """A run store file in the test's own directory (created by the first run)."""
    return tmp_path / "runs.sqlite"


@pytest.fixture
def emulated_bench() -> Path:
    """The emulated bench: real drivers over the wire-level emulators."""
    return BENCHES / "emulated.toml"


@pytest.fixture
def virtual_body() -> Path:
    """The emulated bench's virtual twin (the embedded default description)."""
    return BENCHES / "virtual.toml"


@pytest.fixture
def conform(tmp_path: Path) -> Callable[[Cell], tuple[Outcome, list[str]]]:
    """``conform(cell) -> (outcome, violations)``: the cell run in a directory of its own."""
    def run(cell: Cell) -> tuple[Outcome, list[str]]:
        return verdict(cell, tmp_path / cell.id)
    return run
