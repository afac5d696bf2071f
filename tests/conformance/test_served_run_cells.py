"""Conformance cells of a stored run served as a Bluesky run (bench.catalog.run_documents): the
event stream's bookkeeping as Bluesky readers take it.

Cell: a scan whose points were measured in another order than their plan index (a runner orders
the plan for motion) x spectra over two wavelengths x reflection only / both sides.

Invariant: the events come in the order measured -- ``seq_num`` 1, 2, ... with non-decreasing
``time`` (what a RunEngine emits, and what tiled's ``time`` coordinate and a LiveTable assume) --,
each stamped with its point's end time; the start document's ``num_points`` is the number of
events of the ``primary`` stream, as the stop document's ``num_events`` counts them (not the number
of tidy rows, one per wavelength). Deterministic (no noise). Power: events in plan-index order
have times 30, 10, 20 here, and the rows count 2 or 4 times the events.
"""

from __future__ import annotations

import pytest
from event_model import DocumentNames, schema_validators

from bench.catalog import run_documents, served_state
from bench.store import RunStore

#: plan index -> when the point was measured (epoch s): measured in the order 1, 2, 0
T_END = {0: 1_800_000_030.0, 1: 1_800_000_010.0, 2: 1_800_000_020.0}
WAVELENGTHS = (500.0, 600.0)


def _rows(theta_r: float, sides: tuple[str, ...]) -> list[dict]:
    return [{"wavelength_nm": w, "theta_r": theta_r if s == "R" else 180 - theta_r, "phi_r": 180.0,
             "hemisphere": s, "value": 0.1 + w / 1e4, "std": 0.001} for w in WAVELENGTHS for s in sides]


@pytest.mark.parametrize("sides", [("R",), ("R", "T")], ids=["R", "R+T"])
def test_served_events_come_in_measured_order_and_num_points_counts_them(tmp_path, sides):
    path = tmp_path / "s.sqlite"
    with RunStore(path) as s:
        rid = s.create_run("scan", n_planned=3)
        for idx in (1, 2, 0):  # the order measured
            g = {"theta_i": 30.0, "phi_i": 0.0, "theta_r": 10.0 * (idx + 1), "phi_r": 180.0}
            s.add_point(rid, idx, g, _rows(g["theta_r"], sides), t_start=T_END[idx] - 1, t_end=T_END[idx])
        s.set_status(rid, "completed")
        docs = list(run_documents(s, rid))
    for name, doc in docs:
        schema_validators[DocumentNames[name]].validate(doc)
    start, stop = docs[0][1], docs[-1][1]
    events = [d for n, d in docs if n == "event"]
    assert len(events) == 3 * len(sides)
    assert [e["seq_num"] for e in events] == list(range(1, len(events) + 1))
    times = [e["time"] for e in events]
    assert times == sorted(times)
    assert [T_END[e["data"]["idx"]] for e in events] == times
    assert [e["data"]["idx"] for e in events][:: len(sides)] == [1, 2, 0]
    assert start["num_points"] == len(events) == stop["num_events"]["primary"]


def test_a_copy_kept_from_an_older_document_layout_is_not_taken_as_in_step():
    """A kept catalog's ledger records the state each copy was written from; a copy written before
    the events were ordered as measured (the state without the layout) must be written again."""
    row = {"status": "completed", "reason": None, "points_done": 3, "finished_utc": "2026-12-06T09:00:00Z"}
    older = [row["status"], row["reason"], row["points_done"], row["finished_utc"]]
    assert served_state(row) != older
    assert served_state(row)[:4] == older and served_state(dict(row)) == served_state(row)
