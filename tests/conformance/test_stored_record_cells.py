"""Conformance cells of stored records that must not be misread: record kind x damage x reader ->
refused in one line naming the run (exit 2), the store unchanged; the same run undamaged is read.

Each record kind reaches the readers by its own path (a goniophotometric record through
``to_record``, a spectrophotometer's spectra, a sweep's keyed record), so a damaged field is
checked on every path: a non-JSON ``extra``, a text in a value, an angle out of range, a non-JSON
``runs.meta``. The corpus of damages on one scan is tests/test_store_damage.py.
"""

from __future__ import annotations

import contextlib
import shutil
import sqlite3

import pytest

from bench.cli import main
from helpers.cli import run_main
from helpers.export_records import stored_runs_quietly

KINDS = ("gonio", "in-plane", "spectro", "spectro-sweep")
DAMAGES = {
    "extra not JSON": "UPDATE readings SET extra = 'garbage' WHERE run_id = :r AND rowid = "
                      "(SELECT MIN(rowid) FROM readings WHERE run_id = :r)",
    "value text": "UPDATE readings SET value = 'high' WHERE run_id = :r AND rowid = "
                  "(SELECT MIN(rowid) FROM readings WHERE run_id = :r)",
    "theta_i out of range": "UPDATE points SET theta_i = 500 WHERE run_id = :r AND idx = "
                            "(SELECT MIN(idx) FROM points WHERE run_id = :r)",
    "meta not JSON": "UPDATE runs SET meta = '{' WHERE run_id = :r",
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return stored_runs_quietly(tmp_path_factory, "stored-record-cells", main)


@pytest.mark.parametrize("damage", list(DAMAGES))
@pytest.mark.parametrize("kind", KINDS)
def test_stored_record_cell(tmp_path, capsys, runs, kind, damage):
    src, ids = runs
    rid = ids[kind]
    store = tmp_path / "s.sqlite"
    shutil.copy(src, store)
    for argv in (["show", rid, "--json"], ["export", rid, "--out", tmp_path / "undamaged.csv"]):
        code, _, err = run_main(capsys, *argv, "--store", store)
        assert code == 0, (kind, argv, err)  # the undamaged run is read
    with contextlib.closing(sqlite3.connect(store)) as db, db:
        db.execute(DAMAGES[damage], {"r": rid})
    before = store.read_bytes()
    for argv in (["show", rid, "--json"], ["export", rid, "--out", tmp_path / "r.csv"],
                 ["fit", rid, "--model", "lambert:reflectance=?"]):
        code, out, err = run_main(capsys, *argv, "--store", store)
        assert code == 2 and err.count("\n") == 1 and f"run {rid}" in err and "damaged" in err, (kind, argv, err)
        assert "internal error" not in err
    assert not list(tmp_path.glob("r.csv*")) and store.read_bytes() == before
