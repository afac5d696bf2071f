"""Named regression cases at the boundaries: every bad input named here is refused with ONE line
and the exit status of the policy (2 bad input, 1 a run that failed on its own, 130 Ctrl-C, 70
internal error with a saved traceback), readers never change a store, and a run whose process was
killed is shown as gone and can be resumed."""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "fixtures"
VIRTUAL = str(FIX / "benches" / "virtual.toml")


def one_line(err: str) -> bool:
    return err.count("\n") == 1 and "Traceback" not in err


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()




# --- numbers, sizes, typos: exit 2 naming the option -------------------------------------------------

GONIO = ["gonio", "--specimen", "lambert:albedo=0.5"]
BAD_ARGS = {
    "rays 1e400": (GONIO + ["--rays", "1e400"], "--rays"),
    "rays 1e30": (GONIO + ["--rays", "1e30"], "--rays"),
    "rays 0": (GONIO + ["--rays", "0"], "--rays"),
    "seed -1": (GONIO + ["--seed", "-1"], "--seed"),
    "seed 2^63": (GONIO + ["--seed", str(2**63)], "--seed"),
    "incidence 30,nan": (GONIO + ["--incidence", "30,nan"], "--incidence"),
    "max-seconds nan": (GONIO + ["--max-seconds", "nan"], "--max-seconds"),
    "wavelengths step 1e-9": (["spectro", "--specimen", "lambert:reflectance=0.5", "--wavelengths", "400:700:1e-9"],
                              "--wavelengths"),
    "collector 1e10 patches": (GONIO + ["--collector", "equal-psa:100000x100000"], "--collector"),
    "rays 1e15 by ray counting": (GONIO + ["--rays", "1e15", "--method", "rays"], "--max-seconds"),
    "tradeoff repeats 0": (["tradeoff", str(FIX / "scenes" / "lambert-bare.toml"), "--repeats", "0"], "--repeats"),
    "emulate seconds nan": (["emulate", str(FIX / "benches" / "emulated.toml"), "--max-seconds", "nan"], "--max-seconds"),
    "sweep scheduler not a url": (["sweep", str(FIX / "sweeps" / "gonio-tasks.toml"), "--scheduler", "not a url"],
                                  "--scheduler"),
    "plot with an unknown format": (GONIO + ["--plot", "x.nosuchformat"], "nosuchformat"),
    "rays -u nan": (["rays", "-u", "nan", "-d", "0.01"], "--uncertainty"),
    "unknown option": (GONIO + ["--raays", "5"], "--raays"),
    "dashboard not an address": (["sweep", str(FIX / "sweeps" / "gonio-tasks.toml"), "--workers", "1",
                                  "--dashboard", "everywhere"], "--dashboard"),
    "lone -- as a value": (GONIO + ["--seed=--"], "--seed"),
}


@pytest.mark.parametrize("name", sorted(BAD_ARGS))
def test_bad_arguments_exit_2_naming_the_option(capsys, name):
    argv, needle = BAD_ARGS[name]
    code, out, err = run_main(capsys, *argv)
    assert code == 2, err
    assert one_line(err) and needle in err, err
    assert out == ""


def test_the_cli_collector_bound_is_the_core_one():
    from bench.cli.argtypes import MAX_PATCHES
    from bench.core.parsing import MAX_COLLECTOR_PATCHES

    assert MAX_PATCHES == MAX_COLLECTOR_PATCHES


def test_scan_with_a_refused_seed_leaves_no_run(capsys, tmp_path, scanned_store):
    _, _, plan = scanned_store
    db = tmp_path / "s.sqlite"
    code, _, err = run_main(capsys, "scan", plan, "--bench", VIRTUAL, "--store", db, "--seed", "-1")
    assert code == 2 and one_line(err)
    assert not db.exists()  # validated before the store was even opened: no run stuck at "running 0/N"


# --- unreadable inputs and unwritable outputs ------------------------------------------------------------

def _inputs(tmp: Path) -> dict[str, Path]:
    (tmp / "latin1.toml").write_bytes(b'kind = "in-plane"\nname = "\xe9t\xe9"\n')
    (tmp / "adir").mkdir()
    (tmp / "afile").write_text("x")
    (tmp / "loop1").symlink_to(tmp / "loop2")
    (tmp / "loop2").symlink_to(tmp / "loop1")
    (tmp / "typo.toml").write_text('kind = "in-plane"\navrages = 4\n')
    (tmp / "inf.toml").write_text('kind = "in-plane"\naverages = inf\n')
    (tmp / "white.toml").write_text('kind = "virtual"\nwhite = "spectralon"\n[specimen]\nspec = "lambert:albedo=0.5"\n')
    return {"non-UTF-8": tmp / "latin1.toml", "a directory": tmp / "adir", "a symlink loop": tmp / "loop1",
            "a path under a file": tmp / "afile" / "x.toml", "a typo": tmp / "typo.toml",
            "averages inf": tmp / "inf.toml"}


@pytest.mark.parametrize("case", ["non-UTF-8", "a directory", "a symlink loop", "a path under a file", "a typo",
                                  "averages inf"])
def test_unreadable_or_malformed_plans_exit_2(capsys, tmp_path, case):
    path = _inputs(tmp_path)[case]
    code, _, err = run_main(capsys, "plan", path, "--bench", VIRTUAL)
    assert code == 2 and one_line(err), err
    assert str(path.name) in err or "avrages" in err


def test_a_bench_config_with_white_as_a_string_exits_2(capsys, tmp_path, scanned_store):
    _inputs(tmp_path)
    _, _, plan = scanned_store
    code, _, err = run_main(capsys, "plan", plan, "--bench", tmp_path / "white.toml")
    assert code == 2 and one_line(err) and "key white" in err


@pytest.mark.parametrize("where", ["under a file", "a directory"])
def test_outputs_that_cannot_be_written_exit_2_before_any_work(capsys, tmp_path, scanned_store, where):
    db, rid, _ = scanned_store
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    out = tmp_path / ("afile/x.csv" if where == "under a file" else "adir")
    code, _, err = run_main(capsys, "export", rid, "--store", db, "--out", out)
    assert code == 2 and one_line(err), err


# --- stores --------------------------------------------------------------------------------------

def test_readers_never_change_the_store(capsys, tmp_path, scanned_store):
    db, rid, _ = scanned_store
    before = digest(db)
    for argv in (["runs"], ["show", rid], ["export", rid, "--out", tmp_path / "r.csv"], ["runs", "--json"]):
        code, _, err = run_main(capsys, *argv, "--store", db)
        assert code == 0, err
    assert digest(db) == before


def test_a_foreign_sqlite_file_is_refused_before_anything_is_written(capsys, tmp_path, scanned_store):
    _, _, plan = scanned_store
    db = tmp_path / "foreign.sqlite"
    with sqlite3.connect(db) as c:
        c.execute("CREATE TABLE t (x)")
    before = digest(db)
    for argv in (["runs", "--store", db], ["scan", plan, "--bench", VIRTUAL, "--store", db]):
        code, _, err = run_main(capsys, *argv)
        assert code == 2 and one_line(err) and "not a goniobench run store" in err
    assert digest(db) == before
    with sqlite3.connect(db) as c:
        assert c.execute("PRAGMA journal_mode").fetchone()[0] == "delete"  # no WAL switch


@pytest.mark.parametrize("damage", ["dropped points", "corrupted page", "not SQLite", "missing", "a directory"])
def test_damaged_or_missing_stores_exit_2(capsys, tmp_path, scanned_store, damage):
    src, rid, _ = scanned_store
    db = tmp_path / "d.sqlite"
    if damage == "a directory":
        db.mkdir()
    elif damage == "not SQLite":
        db.write_bytes(b"hello, not a database" * 100)
    elif damage != "missing":
        db.write_bytes(src.read_bytes())
        if damage == "dropped points":
            with sqlite3.connect(db) as c:
                c.execute("DROP TABLE points")
        else:
            with open(db, "r+b") as f:  # overwrite the b-tree pages after the schema page
                f.seek(4096)
                f.write(b"\x07" * 4096 * 3)
    for argv in (["runs"], ["show", rid], ["export", rid, "--out", tmp_path / "x.csv"]):
        code, _, err = run_main(capsys, *argv, "--store", db)
        assert code == 2 and one_line(err), (argv, err)


@pytest.mark.parametrize("argv", [["show", "nope"], ["resume", "nope"], ["export", "nope"],
                                  ["show", "x\udcff"]])
def test_unknown_or_malformed_run_ids_exit_2(capsys, scanned_store, argv):
    db, _, _ = scanned_store
    code, _, err = run_main(capsys, *argv, "--store", db)
    assert code == 2 and one_line(err), err


def test_resuming_a_completed_run_exits_2(capsys, scanned_store):
    db, rid, _ = scanned_store
    code, _, err = run_main(capsys, "resume", rid, "--store", db)
    assert code == 2 and one_line(err) and "completed" in err


def test_a_killed_run_shows_process_gone_and_resumes(capsys, tmp_path):
    """A run whose owning process died (here: a child that creates the run and exits without a
    word, as SIGKILL would leave it) is listed as interrupted (process gone); resume finishes it."""
    db = tmp_path / "k.sqlite"
    code = ("import sys; from bench.store import RunStore; from bench.plans import plan_from_dict\n"
            f"plan = plan_from_dict({{'name': 'k', 'kind': 'in-plane', 'in_plane': {{'theta_i': [30], 'theta_r': [-20, 0, 40]}}}})\n"
            "import tomllib\n"
            f"bench = tomllib.load(open({VIRTUAL!r}, 'rb'))\n"
            f"s = RunStore({str(db)!r})\n"
            "rid = s.create_run('scan', plan=plan.as_dict(), bench=bench, seed=5, n_planned=3, meta={'order': [0, 1, 2]})\n"
            "print(rid, flush=True)\nimport os; os._exit(9)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rid = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         timeout=120).stdout.strip()
    assert rid
    c, out, err = run_main(capsys, "runs", "--store", db)
    assert c == 0 and "interrupted" in out and "process gone" in out, out
    c, out, _ = run_main(capsys, "runs", "--store", db, "--json")
    assert json.loads(out)[0]["process_gone"] is True
    c, out, err = run_main(capsys, "resume", rid, "--store", db, "-q")
    assert c == 0, err
    c, out, _ = run_main(capsys, "runs", "--store", db, "--json")
    row = json.loads(out)[0]
    assert row["status"] == "completed" and row["points_done"] == 3 and row["process_gone"] is False


def test_a_running_run_of_a_live_process_is_not_gone(tmp_path):
    from bench.store import RunStore

    with RunStore(tmp_path / "l.sqlite") as s:
        s.create_run("scan", n_planned=1)
        assert s.runs()[0]["process_gone"] is False


# --- policy: internal errors, Ctrl-C, broken pipes, help -----------------------------------------------------

def _rays_raising(capsys, monkeypatch, exc: BaseException) -> tuple[int, str]:
    """``bench rays`` with its command raising ``exc``: (exit status, stderr), stderr one line."""
    import bench.cli.measure as measure

    def raising(args):
        raise exc

    monkeypatch.setattr(measure, "cmd_rays", raising)
    code, _, err = run_main(capsys, "rays", "-u", "0.1", "-d", "0.1")
    assert one_line(err), err
    return code, err


def test_an_internal_error_is_one_line_naming_a_saved_traceback(capsys, monkeypatch):
    code, err = _rays_raising(capsys, monkeypatch, ZeroDivisionError("a bug"))
    assert code == 70 and "ZeroDivisionError" in err
    path = err.split("traceback saved to ")[1].split(";")[0]
    assert "ZeroDivisionError: a bug" in Path(path).read_text()
    Path(path).unlink()


def test_ctrl_c_exits_130(capsys, monkeypatch):
    assert _rays_raising(capsys, monkeypatch, KeyboardInterrupt())[0] == 130


def test_a_device_fault_exits_1(capsys, monkeypatch):
    from bench.core.errors import HardwareError

    code, err = _rays_raising(capsys, monkeypatch, HardwareError("overload on axis 2"))
    assert code == 1 and "overload" in err


def test_a_broken_pipe_exits_quietly():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    code = ("import sys, bench.cli.measure as m\n"
            "def many(args):\n    [print('x' * 100) for _ in range(20000)]\n    return 0\n"
            "m.cmd_rays = many\nfrom bench.cli import main\nsys.exit(main(['rays', '-u', '0.1', '-d', '0.1']))\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    p.stdout.read(10)
    p.stdout.close()  # the `head` that stopped reading
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 0 and err == "", err


def test_help_lists_every_command_with_a_description_and_version(capsys):
    code, out, _ = run_main(capsys, "--help")
    assert code == 0 and "exit status" in out
    for cmd in ("rays", "spectro", "gonio", "plan", "scan", "resume", "runs", "show", "export", "demo", "compare",
                "tradeoff", "sweep", "emulate", "specimens"):
        line = next(ln for ln in out.splitlines() if ln.strip().startswith(cmd + " "))
        assert len(line.split(None, 1)[1]) > 10
    code, out, _ = run_main(capsys, "--version")
    assert code == 0 and out.startswith("bench (goniobench) ")


def test_every_option_has_a_help_string_with_its_default():
    import argparse

    from bench.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = []
    for name, p in sub.choices.items():
        for a in p._actions:
            if isinstance(a, argparse._HelpAction) or not a.option_strings or a.help == argparse.SUPPRESS:
                continue  # help, positionals, and retired spellings (refused: tests/test_flag_meanings.py)
            h = a.help or ""
            takes_value = a.nargs != 0
            if not h or (takes_value and not a.required and "default" not in h):
                missing.append(f"{name} {a.option_strings[0]}")
    assert not missing, missing


def test_the_dask_dashboard_binds_loopback(monkeypatch):
    pytest.importorskip("distributed")
    import distributed

    from bench.sweep import dask_client

    seen = {}

    class FakeCluster:
        def __init__(self, **kw):
            seen.update(kw)

        def __enter__(self):
            return self

        def __exit__(self, *a):
            return None

    class FakeClient(FakeCluster):
        def __init__(self, cluster, **kw):
            pass

    monkeypatch.setattr(distributed, "LocalCluster", FakeCluster)
    monkeypatch.setattr(distributed, "Client", FakeClient)
    with dask_client(None, 1):
        pass
    assert seen["dashboard_address"].startswith("127.0.0.1:") and seen["host"] == "127.0.0.1"


def test_bench_specimens_lists_every_family_and_parameter(capsys):
    from virtual.specimens import specimen_families

    fams = specimen_families()
    code, out, err = run_main(capsys, "specimens")
    assert code == 0 and err == ""
    for fam in fams:
        assert f"{fam['name']}:" in out
        for p in fam["parameters"]:
            assert f"  {p['name']}" in out
    code, out, _ = run_main(capsys, "specimens", "--json")
    assert code == 0 and [f["name"] for f in json.loads(out)] == [f["name"] for f in fams]
    code, out, _ = run_main(capsys, "specimens", "--markdown")
    from virtual.specimens import specimen_table_markdown

    assert code == 0 and out.strip() == specimen_table_markdown().strip()


def test_ctrl_c_during_a_scan_exits_130_and_the_run_resumes(capsys, tmp_path, scanned_store, monkeypatch):
    import bench.runner as runner

    _, _, plan = scanned_store
    db = tmp_path / "c.sqlite"
    real_rows = runner.point_rows
    calls = []

    def rows_then_ctrl_c(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_rows(*a, **kw)

    monkeypatch.setattr(runner, "point_rows", rows_then_ctrl_c)
    code, _, err = run_main(capsys, "scan", plan, "--bench", VIRTUAL, "--store", db, "-q", "--seed", "2")
    assert code == 130 and one_line(err) and "bench resume" in err
    monkeypatch.undo()
    rid = err.split("bench resume ")[1].split()[0]
    code, out, err = run_main(capsys, "resume", rid, "--store", db, "-q")
    assert code == 0, err


def test_the_first_kernel_compilation_is_announced_once(capsys, monkeypatch):
    """Off a terminal: one header, then one line per kernel family that compiles (with its
    estimate), nothing for other functions, and nothing once the command has ended."""
    import numba

    import bench.cli.common as common

    monkeypatch.setattr(common, "_ANNOUNCED", [])
    common.announce_compilation()

    @numba.njit(cache=False)
    def gonio_fx_chunk(x):  # named as a kernel family
        return 2 * x

    @numba.njit(cache=False)
    def spectro_fx_chunk(x):
        return 3 * x

    @numba.njit(cache=False)
    def not_a_kernel(x):
        return 4 * x

    assert gonio_fx_chunk(2) == 4 and spectro_fx_chunk(2) == 6 and not_a_kernel(2) == 8
    common.stop_announcing()

    @numba.njit(cache=False)
    def gonio_block_chunk(x):
        return 5 * x

    assert gonio_block_chunk(2) == 10  # after the command: not announced
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "compiling kernels (first run only)..."
    assert err[1].startswith("  compiling the goniophotometer kernel (ray by ray, scene effects by flag) (about ")
    assert err[2].startswith("  compiling the spectrophotometer kernel (ray by ray, scene effects by flag) (about ")
    assert len(err) == 3
