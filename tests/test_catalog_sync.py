"""`bench serve` hardened: its API key checked before anything starts, damaged runs never turned
into requests, and a kept catalog (`--catalog`) in step with the store -- a run served while
interrupted is served again whole once `bench resume` completed it, and a copy cut short by a kill
(no stop document) is written again whole at the next start.

Fast: the key refusals (argparse refuses before Tiled is imported). Slow (real Tiled servers, ~10
CPU-s of imports and start-ups): the catalog kept in step.
"""

from __future__ import annotations


import pytest

from bench.store import RunStore
from tests.helpers.cli import run_main


@pytest.mark.parametrize("key,why", [("", "empty key"), ("has space1", "letters and digits"), ("a/../b", "letters and digits"),
                                     ("caf\u00e9caf\u00e9caf\u00e9", "letters and digits"), ("k" * 300, "1 to 256")])
def test_a_bad_api_key_is_one_line_before_anything_starts(key, why, tmp_path, capsys):
    code, out, err = run_main(capsys, "serve", "--store", tmp_path / "none.sqlite", "--api-key", key, "--port", "0")
    assert code == 2 and out == "" and err.count("\n") == 1 and why in err and "--api-key" in err, err
    assert not (tmp_path / "none.sqlite").exists()


def _rows(n: int = 2) -> list[dict]:
    return [{"wavelength_nm": 500.0 + 100 * k, "theta_r": 30.0, "phi_r": 180.0, "value": 0.1, "std": 0.01}
            for k in range(n)]


def _point(store: RunStore, rid: str, i: int) -> None:
    store.add_point(rid, i, {"theta_i": 10.0 * i, "phi_i": 0.0, "theta_r": 30.0, "phi_r": 180.0}, _rows())


def _served(server, rid: str) -> tuple[int, str | None]:
    """(rows served in primary, the stop document's exit_status or None) of stored run ``rid``."""
    from bench.catalog import run_uid

    node = server.client()[run_uid({"run_id": rid, "meta": {}})]
    stop = node.metadata.get("stop")
    rows = len(node["primary"].read().to_dataframe()) if "primary" in node else 0
    return rows, None if not stop else stop["exit_status"]


@pytest.mark.slow  # three Tiled servers in this process (~10 CPU-s)
def test_a_kept_catalog_follows_the_store_and_redoes_a_cut_write(tmp_path):
    from bluesky_tiled_plugins import TiledWriter

    from bench.catalog import CatalogServer, run_documents, run_uid

    path, cat = tmp_path / "s.sqlite", tmp_path / "catalog"
    with RunStore(path) as s:
        rid = s.create_run("scan", n_planned=4, meta={"specimen": "lambert:albedo=0.3"})
        for i in range(2):
            _point(s, rid, i)
        s.set_status(rid, "interrupted", "killed")
        s._db.execute("PRAGMA foreign_keys = OFF")
        bad = s.create_run("scan", n_planned=1)
        _point(s, bad, 0)
        s.set_status(bad, "completed")
        s._db.execute("UPDATE runs SET run_id = '../../etc/x' WHERE run_id = ?", (bad,))
    with RunStore(path, create=False, readonly=True) as s, CatalogServer(0, cat) as server:
        assert server.add_runs(s) == [rid] and _served(server, rid) == (4, "abort")
        assert "format" in server.damaged["../../etc/x"]  # listed, never requested
        assert not any(n.metadata["start"].get("run_id") == "../../etc/x" for n in server.client().values())
    with RunStore(path) as s:  # `bench resume` completes it
        s.set_status(rid, "running")
        for i in range(2, 4):
            _point(s, rid, i)
        s.set_status(rid, "completed")
        third = s.create_run("scan", n_planned=1)
        _point(s, third, 0)
        s.set_status(third, "completed")
    with RunStore(path, create=False, readonly=True) as s, CatalogServer(0, cat) as server:
        # a writer killed before the third run's stop document: start, descriptor and rows only
        writer = TiledWriter(server.client(write=True))
        for name, doc in run_documents(s, third):
            if name == "stop":
                break
            writer(name, doc)
        assert server.client()[run_uid({"run_id": third, "meta": {}})].metadata.get("stop") is None
    with RunStore(path, create=False, readonly=True) as s, CatalogServer(0, cat) as server:
        written = server.add_runs(s)
        assert sorted(written) == sorted([rid, third]) and sorted(server.replaced) == sorted([rid, third])
        assert _served(server, rid) == (8, "success")  # the whole resumed run, not the 4 rows served before
        assert _served(server, third) == (2, "success")  # the cut copy written again whole
        assert server.add_runs(s) == []  # in step: the poll writes nothing
        assert len(list(server.client().values())) == 2  # one copy of each run, no duplicate


def _completed_run(path, n_points: int = 2) -> str:
    with RunStore(path) as s:
        rid = s.create_run("scan", n_planned=n_points, meta={"specimen": "lambert:albedo=0.3"})
        for i in range(n_points):
            _point(s, rid, i)
        s.set_status(rid, "completed")
    return rid


@pytest.mark.slow  # four Tiled servers (~15 CPU-s)
def test_bench_serve_starts_from_the_catalog_it_kept_for_the_store_and_writes_only_new_runs(tmp_path, capsys):
    import json

    from bluesky_tiled_plugins import TiledWriter

    from bench.catalog import CatalogServer, run_documents
    from bench.cli.serve import catalog_cache

    path = tmp_path / "s.sqlite"
    first = [_completed_run(path), _completed_run(path)]
    serve = ["serve", "--store", path, "--port", "0", "--json", "--max-seconds", "0"]
    code, out, _ = run_main(capsys, *serve)
    assert code == 0 and sorted(json.loads(out)["runs"]) == sorted(first)
    later = _completed_run(path)
    code, out, _ = run_main(capsys, *serve)
    info = json.loads(out)
    assert code == 0 and info["runs"] == [later], "the kept runs were written again"
    assert info["served"] == sorted([*first, later])
    code, out, _ = run_main(capsys, *serve, "--no-cache")  # power: without the kept catalog every run is written
    assert code == 0 and sorted(json.loads(out)["runs"]) == sorted([*first, later])

    # the kept catalog reads back whole, and a run the store does not hold (a RunEngine wrote it
    # alone into the served catalog) is deleted at the next start
    with RunStore(path, create=False, readonly=True) as s, CatalogServer(0, catalog_cache(path)) as server:
        assert all(_served(server, rid) == (4, "success") for rid in [*first, later])
        writer = TiledWriter(server.client(write=True))
        alone = "0b6c5a36-4c5d-4a57-9a3f-3f0e8c1d2e7f"
        for name, doc in run_documents(s, later):
            if name == "start":
                doc = {**doc, "uid": alone, "run_id": "re-only"}
            elif "run_start" in doc:
                doc = {**doc, "run_start": alone}
            writer(name, doc)
        assert len(list(server.client())) == 4
        assert server.keep_only(s) == [alone]
        assert len(list(server.client())) == 3
