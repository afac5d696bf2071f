"""Fixtures shared by several test files: one definition, one meaning each.

- ``scanned_store``: a run store holding one completed virtual scan, made once per module;
  ``(db, run_id, plan)``.
- ``RE``: a Bluesky RunEngine for the module; ``RE(plan)`` returns the run uids.
- ``RE_with_result``: the same whose ``RE(plan).plan_result`` is the plan's return value.
- ``virtual``: the virtual bench's Bluesky devices (seed 3) on the module's ``RE``.
- (autouse) ``GONIOBENCH_CACHE_DIR`` points at a folder of the session, so what the commands
  keep between starts (``bench serve``'s catalogs) never goes to the user's cache.

A fixture that means something else in one file keeps a name of its own there (``run_store``, an
open :class:`bench.store.RunStore`; ``known_store``, a store of known values; ...).
"""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import pytest

from bench.cli import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
#: three in-plane points at 0.05 s (the default 0.1 s would bring the twin's brightest reading
#: within 5 sd of full scale, refused)
SMALL_PLAN = ('name = "small"\nkind = "in-plane"\nintegration_s = 0.05\n[in_plane]\ntheta_i = [30]\n'
              'theta_r = [-20, 0, 40]\n')


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory: pytest.TempPathFactory):
    os.environ["GONIOBENCH_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    yield


@pytest.fixture(scope="module")
def scanned_store(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str, Path]:
    """A store holding one completed scan of SMALL_PLAN on the virtual bench (seed 3)."""
    d = tmp_path_factory.mktemp("store")
    plan = d / "small.toml"
    plan.write_text(SMALL_PLAN)
    db = d / "runs.sqlite"
    bench = str(FIXTURES / "benches" / "virtual.toml")
    assert main(["scan", str(plan), "--bench", bench, "--store", str(db), "-q", "--seed", "3"]) == 0
    with sqlite3.connect(db) as c:
        rid = c.execute("SELECT run_id FROM runs").fetchone()[0]
    return db, rid, plan


@pytest.fixture(scope="module")
def RE():
    """A RunEngine for the module (bluesky, the ``bluesky`` extra, imported only when asked for)."""
    bluesky = pytest.importorskip("bluesky")
    return bluesky.RunEngine({})


@pytest.fixture(scope="module")
def RE_with_result():
    """A RunEngine whose call returns a result carrying the plan's return value (``plan_result``)."""
    bluesky = pytest.importorskip("bluesky")
    return bluesky.RunEngine({}, call_returns_result=True)


@pytest.fixture(scope="module")
def virtual(RE):
    """The virtual bench's Bluesky devices (seed 3) on the module's RunEngine, closed after it."""
    connect = pytest.importorskip("bench.bluesky").connect
    devs = connect(FIXTURES / "benches" / "virtual.toml", run_engine=RE, seed=3)
    yield devs
    devs.close()
