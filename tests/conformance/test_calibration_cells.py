"""Cells of the calibration seam (body x calibration source): a white belongs to the body that
measured it (:mod:`bench.calibration_chain`).

* a white measured in the run, a stored file of the same body, and the white of a completed run
  (``bench white --from-run``): the run holds the invariant;
* a stored file measured on another body (``foreign-file``: the emulated body's white handed to
  the virtual twin or to the real description over the emulators): refused in one line, exit 2,
  before any motion, nothing stored -- it read 40-280x low and said ``completed``;
* a specimen stored as the white (``bench white --yes`` with the specimen mounted): refused in one
  line, the file not written, the accepted white kept.

Fast cells run on the virtual body; the emulated and real ones start emulators (slow).
"""

from __future__ import annotations

import pytest

from harness import Cell, bench_cli, body_of, check_refusal, prepare_calibration, write_toml
from bench.core.parsing import read_toml

FAST = [
    Cell("lambert", "virtual", "once", "once", "scan"),
    Cell("lambert", "virtual", "file", "once", "scan"),
]
SLOW = [
    Cell("lambert", "virtual", "run", "once", "scan"),  # `bench white --from-run`: the run's white keeps its origin
    Cell("plastic", "emulated", "file", "once", "scan"),
    Cell("lambert", "real", "file", "once", "scan"),
]
FOREIGN = [
    Cell("lambert", "virtual", "foreign-file", "once", "scan"),
    pytest.param(Cell("lambert", "real", "foreign-file", "once", "scan"), marks=pytest.mark.slow),
    pytest.param(Cell("lambert", "virtual", "foreign-file", "once", "resume"), marks=pytest.mark.slow),
]


@pytest.mark.parametrize("cell", FAST + [pytest.param(c, marks=pytest.mark.slow) for c in SLOW], ids=lambda c: c.id)
def test_a_white_of_the_same_body_is_taken(conform, cell):
    outcome, bad = conform(cell)
    assert not outcome.refused and bad == [], f"{cell.id}: {outcome.refusal} {bad}"


@pytest.mark.parametrize("cell", FOREIGN, ids=lambda c: c.id)
def test_a_white_of_another_body_is_refused_before_motion(conform, cell):
    outcome, bad = conform(cell)
    assert outcome.refused, f"{cell.id} was not refused: {outcome.statuses}"
    assert bad == [] and check_refusal(outcome) == [], bad
    assert "measured on the emulated body" in outcome.refusal and outcome.moves == 0


@pytest.mark.slow
def test_a_specimen_stored_as_the_white_is_refused(tmp_path):
    """The real description over the emulators: the operator's white (standard mounted) is
    accepted; ``bench white --yes`` again with the specimen left on the turntable reads 0.81 of it
    (a Lambertian 0.8 for the 0.99 standard): refused in one line, exit 2, nothing written."""
    cell = Cell("lambert", "real", "file", "once", "scan")
    with body_of(cell, tmp_path) as (bench_toml, emulators):
        accepted = prepare_calibration(cell, bench_toml, emulators, tmp_path, tmp_path / "prep.sqlite")
        white = read_toml(accepted)["white"]["reference_file"]
        before = open(white).read()
        out = tmp_path / "specimen-as-white.csv"
        code, _, err = bench_cli("white", "--bench", accepted, "--body", "real", "--out", out, "--yes",
                                 "--integration-s", 0.02, "--averages", 2)
        assert code == 2 and len(err.strip().splitlines()) == 1, err
        assert "x the accepted white" in err and not out.exists()
        assert open(white).read() == before
        # the standard mounted again: accepted
        emulators.mount_white(True)
        try:
            code, _, err = bench_cli("white", "--bench", accepted, "--body", "real", "--out", out, "--yes",
                                     "--integration-s", 0.02, "--averages", 2)
        finally:
            emulators.mount_white(False)
        assert code == 0, err


def test_an_old_white_file_is_refused_in_one_line_saying_how_to_take_it_again(tmp_path):
    """A white file written before origins were recorded: readable, but a run refuses it in one
    line naming what it lacks and the command that takes it again."""
    cell = Cell("lambert", "virtual", "file", "once", "scan")
    with body_of(cell, tmp_path) as (bench_toml, emulators):
        described = prepare_calibration(cell, bench_toml, emulators, tmp_path, tmp_path / "prep.sqlite")
    d = read_toml(described)
    path = d["white"]["reference_file"]
    text = open(path).read()
    head, origin = text.split(', "origin": ', 1)
    open(path, "w").write(head + "}" + origin[origin.index("\n"):])  # the meta line without its origin
    plan = write_toml(tmp_path / "plan.toml", {"name": "p", "kind": "list", "integration_s": 0.02, "averages": 2,
                                               "dark": "once", "white": "once", "list": {"points": [[30, 0, 10, 180]]}})
    code, _, err = bench_cli("scan", plan, "--bench", described, "--body", "virtual", "--store", tmp_path / "s.sqlite")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "records no body or detector" in err and "bench white --bench BENCH.toml --body virtual" in err
