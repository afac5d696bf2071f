"""Stored runs as Bluesky runs in a Tiled catalog (bench/catalog/, `bench serve`).

Fast: the documents of a stored run are valid event-model documents keyed by the run id, and
their event rows are the rows `bench export` writes (values, identity, units). Slow (a real Tiled
server: ~10 CPU-s of imports and start-up): `bench serve` on a free port, read back with
`tiled.client.from_uri` equal to the export, a RunEngine's TiledWriter writing into it, and a run
stored after the start served once it ends.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from event_model import DocumentNames, schema_validators

from bench.catalog import run_documents
from bench.cli import main
from bench.core.records import BSDFRecord
from bench.store import RunStore

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture()
def known_store(tmp_path):
    """A store with one small run of known values (two incidences, two wavelengths, R and T rows)."""
    rows = []
    for ti in (20.0, 40.0):
        for wl in (500.0, 600.0):
            for tr, hemi in ((30.0, "R"), (150.0, "T")):
                rows.append({"wavelength_nm": wl, "theta_i": ti, "phi_i": 0.0, "theta_r": tr, "phi_r": 180.0,
                             "hemisphere": hemi, "value": 0.1 + ti / 1000 + wl / 1e5 + (tr > 90) * 0.01,
                             "std": 0.001, "ci_lo": 0.09, "ci_hi": 0.11})
    rec = BSDFRecord(pd.DataFrame(rows), {"specimen": "lambert:albedo=0.3", "plan_name": "two-incidences",
                                          "bench_kind": "virtual"})
    path = tmp_path / "s.sqlite"
    with RunStore(path) as s:
        rid = s.create_run("virtual", n_planned=2)
        s.add_record(rid, rec)
        s.set_status(rid, "completed")
    return path, rid


def test_a_stored_run_becomes_valid_bluesky_documents_with_the_exports_rows(known_store, tmp_path, capsys):
    path, rid = known_store
    with RunStore(path, create=False) as s:
        docs = list(run_documents(s, rid))
        again = next(run_documents(s, rid))[1]
    for name, doc in docs:
        schema_validators[DocumentNames[name]].validate(doc)
    names = [n for n, _ in docs]
    # one event per measured spectrum (each point's R and T sides), not one per wavelength
    assert names == ["start", "descriptor", "event", "event", "event", "event", "stop"]
    start, desc, *events, stop = (d for _, d in docs)
    # the uid is a UUID (as a RunEngine's), the same at every serve; the run id is metadata
    assert uuid.UUID(start["uid"]).version == 5 and start["uid"] == again["uid"]
    assert start["run_id"] == rid and start["scan_id"] == 1
    assert start["specimen"] == "lambert:albedo=0.3" and start["plan_name"] == "two-incidences"
    assert start["body"] == "virtual" and start["column_units"]["value"] == "1/sr" and stop["exit_status"] == "success"
    assert desc["name"] == "primary" and desc["data_keys"]["value"]["units"] == "1/sr"
    value = desc["data_keys"]["value"]
    assert value["dtype"] == "array" and value["shape"] == [2] and value["dims"] == ["wavelength_nm"]
    # each event stamped when its point was measured (the store's point end times), in order
    with RunStore(path, create=False) as s:
        ends = dict(zip(s.points(rid)["idx"], s.points(rid)["t_end"]))
    assert [e["time"] for e in events] == [ends[e["data"]["idx"]] for e in events]
    # the events hold exactly the rows `bench export` writes, spectra spread over wavelength_nm
    assert main(["export", rid, "--store", str(path), "--out", str(tmp_path / "r.csv")]) == 0
    capsys.readouterr()
    exported = pd.read_csv(tmp_path / "r.csv")
    assert set(desc["data_keys"]) == set(exported.columns)
    rows = []
    for e in events:
        for i, wl in enumerate(e["data"]["wavelength_nm"]):
            rows.append({c: (v[i] if isinstance(v, list) else v) for c, v in e["data"].items()} | {"wavelength_nm": wl})
    served = pd.DataFrame(rows)
    assert len(served) == len(exported)
    order = ["idx", "hemisphere", "wavelength_nm"]
    served = served.sort_values(order).reset_index(drop=True)
    exported = exported.sort_values(order).reset_index(drop=True)
    for col in exported.columns:
        got = served[col]
        if exported[col].isna().all():  # a key no row fills (collector, geometry): empty text
            assert set(got) == {""}, col
        elif exported[col].dtype.kind in "if":
            assert np.array_equal(got.to_numpy(float), exported[col].to_numpy(float), equal_nan=True), col
        else:
            assert [g or None for g in got] == [None if v != v else v for v in exported[col]], col


def test_a_run_without_readings_has_no_event_stream_and_a_bluesky_run_keeps_its_uid(known_store):
    """A run that measured nothing (a fit, a Bluesky run that failed before its first point) gives
    start and stop only: an empty `primary` made `run["primary"].read()` raise in tiled.client.
    A Bluesky run keeps the RunEngine's uid and scan_id, so the live TiledWriter copy and the
    stored one are one run in the catalog."""
    from bench.catalog import run_uid

    path, _ = known_store
    with RunStore(path) as s:
        empty = s.create_run("bluesky", n_planned=3, meta={"bluesky_uid": "0b7e1c7e-6f55-4a0e-9a43-6c1b1b6f0e11",
                                                           "bluesky_start": {"scan_id": 17}})
        s.set_status(empty, "failed", "HardwareError: overload (device goniometer)")
        docs = list(run_documents(s, empty))
        assert run_uid(s.run(empty)) == "0b7e1c7e-6f55-4a0e-9a43-6c1b1b6f0e11"
    assert [n for n, _ in docs] == ["start", "stop"]
    assert docs[0][1]["uid"] == "0b7e1c7e-6f55-4a0e-9a43-6c1b1b6f0e11" and docs[0][1]["scan_id"] == 17
    assert docs[1][1]["exit_status"] == "fail"


@pytest.mark.slow
def test_bench_serve_serves_runs_tiled_reads_back_the_export_and_a_run_engine_writes_into_it(known_store, tmp_path):
    from bluesky import RunEngine
    from bluesky.plans import scan
    from bluesky_tiled_plugins import TiledWriter
    from tiled.client import from_uri
    from tiled.queries import Key

    from bench.bluesky import StoreWriter, connect

    path, rid = known_store
    assert main(["export", rid, "--store", str(path), "--out", str(tmp_path / "r.csv")]) == 0
    exported = pd.read_csv(tmp_path / "r.csv")
    server = subprocess.Popen([sys.executable, "-m", "bench.cli", "serve", "--store", str(path), "--port", "0",
                               "--json", "--max-seconds", "300"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env={"PYTHONPATH": str(ROOT), **{k: v for k, v in __import__("os").environ.items()
                                                                        if k != "PYTHONPATH"}})
    try:
        line = server.stdout.readline()
        assert line, server.stderr.read()[-3000:]
        info = json.loads(line)
        assert info["uri"].startswith("http://127.0.0.1:") and info["runs"] == [rid]
        client = from_uri(info["uri"])
        (run,) = client.search(Key("start.run_id") == rid).values()
        assert run.metadata["start"]["specimen"] == "lambert:albedo=0.3"
        primary = run["primary"].read()  # one event per spectrum, arrays over wavelength_nm
        value = np.asarray(primary["value"], float)  # (events, wavelengths): arrays, not text
        assert value.shape == (4, 2)
        spectra = exported.sort_values("wavelength_nm", kind="stable").groupby(["idx", "hemisphere"], sort=False)
        want = {k: g["value"].to_numpy(float) for k, g in spectra}
        got = {(int(i), str(h)): v for i, h, v in zip(np.asarray(primary["idx"]), np.asarray(primary["hemisphere"]),
                                                       value)}
        assert got.keys() == want.keys() and all(np.array_equal(got[k], want[k]) for k in want)
        # a Bluesky script writes into the same catalog with the served API key, and reads it back
        # (and into the store: the run is then served once, as the RunEngine wrote it)
        RE = RunEngine({})
        RE.subscribe(TiledWriter(from_uri(info["uri"], api_key=info["api_key"])))
        RE.subscribe(StoreWriter(path))
        with connect(ROOT / "fixtures" / "benches" / "virtual.toml", run_engine=RE, seed=1) as devs:
            (uid,) = RE(scan([devs.reflectance], devs.goniometer.theta_r, 10, 30, 2))
        written = from_uri(info["uri"])[uid]["primary"]
        assert written["reflectance-rf_mean"].read().shape == (2,)
        assert np.all(np.asarray(written["reflectance-rf_mean"].read()) > 0)
        # without the key, writing is refused (anonymous clients only read)
        from tiled.client.utils import ClientError

        with pytest.raises(ClientError, match="401"):
            from_uri(info["uri"]).create_container("not-allowed")
        # a run that ends while the server runs is added within a few seconds (polled every 2 s)
        with RunStore(path) as s:
            later = s.create_run("virtual", n_planned=2)
            s.add_record(later, BSDFRecord(pd.DataFrame([{
                "wavelength_nm": 500.0, "theta_i": 20.0, "phi_i": 0.0, "theta_r": 30.0, "phi_r": 180.0, "hemisphere": "R",
                "value": 0.12, "std": 0.001, "ci_lo": 0.11, "ci_hi": 0.13}]), {"specimen": "lambert:albedo=0.3",
                                                                                "bench_kind": "virtual"}))
            s.set_status(later, "completed")
        deadline = time.monotonic() + 60
        while not from_uri(info["uri"]).search(Key("start.run_id") == later) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert from_uri(info["uri"]).search(Key("start.run_id") == later), "a run stored after the start was not served"
        every = from_uri(info["uri"])
        assert len(every) == 3  # the stored run, the Bluesky run (once), the later one
        for served in every.values():  # the standard reader's loop never raises
            served["primary"].read()
    finally:
        server.terminate()
        server.wait(20)


@pytest.mark.slow  # imports tiled's catalog (~4 CPU-s)
def test_the_catalog_is_initialised_in_this_process(tmp_path, monkeypatch):
    """Tiled's own init runs `python -m tiled catalog init` in a second interpreter (about half of
    a 40-s `bench serve` start on a loaded 2-core machine): ours creates and stamps it here, once."""
    import sqlite3

    from bench.catalog import init_catalog

    def no_subprocess(*args, **kwargs):
        raise AssertionError(f"a subprocess was started: {args}")

    monkeypatch.setattr(subprocess, "run", no_subprocess)
    monkeypatch.setattr(subprocess, "Popen", no_subprocess)
    uri = f"sqlite:///{tmp_path / 'catalog.db'}"
    init_catalog(uri)
    with sqlite3.connect(tmp_path / "catalog.db") as db:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        (stamp,) = db.execute("SELECT version_num FROM alembic_version").fetchone()
    assert {"nodes", "alembic_version"} <= tables and stamp
    init_catalog(uri)  # an existing catalog is left as it is
    from tiled.catalog import from_uri

    from_uri(uri)  # and tiled opens it without initialising it again


def test_a_stored_runs_data_keys_name_the_instruments_that_measured_them(tmp_path, capsys):
    """A served stored run says where each value came from as the live devices do
    (``BODY://BENCH/ROLE/MODEL/SERIAL#KEY``): geometry from the goniometer, readings from the
    spectrometer; only the record's identity is the store's."""
    from bench.catalog import run_documents
    from bench.store import RunStore
    from tests.helpers.cli import run_main

    plan = tmp_path / "plan.toml"
    plan.write_text('name = "tiny"\nkind = "list"\nintegration_s = 0.02\npoints = [[30, 0, 20, 180]]\n')
    store = tmp_path / "s.sqlite"
    code, out, err = run_main(capsys, "scan", plan, "--bench", ROOT / "fixtures" / "benches" / "virtual.toml",
                              "--store", store, "--seed", 1, "--quiet")
    assert code == 0, err
    with RunStore(store, create=False, readonly=True) as s:
        docs = list(run_documents(s, out.strip().splitlines()[-1]))
    keys = next(doc for name, doc in docs if name == "descriptor")["data_keys"]
    assert keys["theta_r"]["source"].startswith("virtual://virtual/goniometer")
    assert keys["value"]["source"].startswith("virtual://virtual/spectrometer")
    assert keys["value"]["source"].endswith("#value") and keys["run_id"]["source"] == "goniobench-store#run_id"
