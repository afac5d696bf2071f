"""A corpus of damaged run stores: each case damages one field of a stored scan the way an edit, a
bad copy or a bit flip would, and every command that reads it (`show`, `show --json`, `export`,
`fit`, `runs`) must exit 2 with ONE line naming the run, the point and the field -- never exit 70,
never a number computed from the damage (a garbled budget ignored, a text read as NaN). `bench
runs` lists a damaged run with its reason beside the others. Then `bench fit`'s own refusals: an
unfinished run without --partial, a record with no degrees of freedom, and the readings it leaves
out said aloud.

Fast: one 4-point virtual scan (12 readings) is made once; each case copies the file and runs
commands in this process; no fit runs past its refusal except the three that check what it says.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from bench.config import load_bench
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore
from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "fixtures" / "benches" / "virtual.toml"
PLAN = {"name": "four", "kind": "list", "integration_s": 0.01, "averages": 1, "white": "once",
        "points": [[20, 0, 30, 180], [20, 0, 40, 180], [20, 0, 50, 180], [20, 0, 60, 180]]}
MODEL = "lambert:albedo=?"


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """(store path, damaged-to-be run id, an intact run id): two completed scans."""
    path = tmp_path_factory.mktemp("damage") / "s.sqlite"
    with load_bench(BENCH, seed=1) as bench, RunStore(path) as store:
        victim = run_scan(bench, plan_from_dict(PLAN), store, seed=1).run_id
        intact = run_scan(bench, plan_from_dict(PLAN), store, seed=2).run_id
    return path, victim, intact


@pytest.fixture()
def damage(pristine, tmp_path):
    """damage(sql) -> (path, run id, intact run id): a copy of the store with ``sql`` applied to
    the victim run (``:r`` is its id)."""
    src, victim, intact = pristine

    def apply(sql: str) -> tuple[Path, str, str]:
        path = tmp_path / "d.sqlite"
        shutil.copy(src, path)
        db = sqlite3.connect(path)
        db.execute("PRAGMA foreign_keys = OFF")
        for stmt in sql.split(";"):
            if stmt.strip():
                db.execute(stmt, {"r": victim} if ":r" in stmt else {})
        db.commit()
        db.close()
        return path, victim, intact

    return apply


READS = ("show", "show-json", "export", "fit")
ONE = "AND idx = 1 AND wavelength_nm = 550"
#: name: (the damage, the commands that must refuse it, what the line names besides the run)
CORPUS = {
    "meta not JSON": ("UPDATE runs SET meta = '{not json' WHERE run_id = :r", READS, ["runs.meta", "not JSON"]),
    "calibration not JSON": ("UPDATE runs SET calibration = '{' WHERE run_id = :r", READS, ["runs.calibration"]),
    "plan a JSON list": ("UPDATE runs SET plan = '[1, 2]' WHERE run_id = :r", READS, ["runs.plan", "list"]),
    "bench a number": ("UPDATE runs SET bench = '3' WHERE run_id = :r", READS, ["runs.bench"]),
    "created_epoch text": ("UPDATE runs SET created_epoch = 'yesterday' WHERE run_id = :r", READS,
                           ["runs.created_epoch"]),
    "kind unknown": ("UPDATE runs SET kind = '' WHERE run_id = :r", READS, ["runs.kind"]),
    "n_planned negative": ("UPDATE runs SET n_planned = -3 WHERE run_id = :r", READS, ["runs.n_planned"]),
    "extra not JSON": (f"UPDATE readings SET extra = 'garbage' WHERE run_id = :r {ONE}", READS,
                       ["point 1", "550 nm", "readings.extra"]),
    "extra a list": (f"UPDATE readings SET extra = '[]' WHERE run_id = :r {ONE}", READS, ["point 1", "readings.extra"]),
    # JSON that json.loads refuses with a plain ValueError, not a JSONDecodeError: an integer longer than int() takes
    "meta a 5000-digit integer": ("UPDATE runs SET meta = '{\"x\": ' || printf('%.5000c', '7') || '}' WHERE run_id = :r",
                                READS, ["runs.meta", "not JSON", "digits"]),
    "extra a 5000-digit integer": (f"UPDATE readings SET extra = printf('%.5000c', '7') WHERE run_id = :r {ONE}", READS,
                                 ["point 1", "readings.extra", "digits"]),
    "budget a string": (f"UPDATE readings SET extra = json_set(extra, '$.uncertainty_budget', 'xx') WHERE run_id = :r "
                        f"{ONE}", READS, ["point 1", "uncertainty_budget", "'xx'"]),
    "budget combined text": (f"UPDATE readings SET extra = json_set(extra, '$.uncertainty_budget.combined', 'abc') "
                             f"WHERE run_id = :r {ONE}", READS, ["point 1", "uncertainty_budget.combined"]),
    "budget combined shrunk": (f"UPDATE readings SET extra = json_set(extra, '$.uncertainty_budget.combined', 1e-9) "
                               f"WHERE run_id = :r {ONE}", READS, ["point 1", "combined", "disagrees", "std"]),
    "budget component negative": (f"UPDATE readings SET extra = json_set(extra, "
                                  f"'$.uncertainty_budget.components[0].standard_uncertainty', -1) WHERE run_id = :r "
                                  f"{ONE}", READS, ["point 1", "components[0].standard_uncertainty"]),
    "budget k zero": (f"UPDATE readings SET extra = json_set(extra, '$.uncertainty_budget.k', 0) WHERE run_id = :r "
                      f"{ONE}", READS, ["point 1", "uncertainty_budget.k"]),
    "budget without components": (f"UPDATE readings SET extra = json_remove(extra, '$.uncertainty_budget.components') "
                                  f"WHERE run_id = :r {ONE}", READS, ["point 1", "components"]),
    "value NULL beside its std": (f"UPDATE readings SET value = NULL WHERE run_id = :r {ONE}", READS,
                                  ["point 1", "value is missing"]),
    "value infinite": (f"UPDATE readings SET value = 9e999 WHERE run_id = :r {ONE}", READS, ["point 1", "value"]),
    "value text": (f"UPDATE readings SET value = 'high' WHERE run_id = :r {ONE}", READS, ["point 1", "value", "'high'"]),
    "std negative": (f"UPDATE readings SET std = -0.01 WHERE run_id = :r {ONE}", READS, ["point 1", "std"]),
    "patch count negative": (f"UPDATE readings SET count = -5, N = 100 WHERE run_id = :r {ONE}", READS,
                             ["point 1", "count", "-5"]),
    "count above N": (f"UPDATE readings SET count = 500, N = 100 WHERE run_id = :r {ONE}", READS,
                      ["point 1", "count 500", "N 100"]),
    "saturated not a flag": (f"UPDATE readings SET saturated = 7 WHERE run_id = :r {ONE}", READS,
                             ["point 1", "saturated"]),
    "wavelength negative": (f"UPDATE readings SET wavelength_nm = -550 WHERE run_id = :r {ONE}", READS,
                            ["point 1", "wavelength_nm"]),
    "wavelength NULL": (f"UPDATE readings SET wavelength_nm = NULL WHERE run_id = :r {ONE}", READS,
                        ["point 1", "wavelength_nm", "missing"]),
    "theta_i out of range": ("UPDATE points SET theta_i = 500 WHERE run_id = :r AND idx = 1", READS,
                             ["point 1", "theta_i", "500"]),
    "theta_i text": ("UPDATE points SET theta_i = 'abc' WHERE run_id = :r AND idx = 1", READS,
                     ["point 1", "theta_i", "'abc'"]),
    "phi_r infinite": ("UPDATE points SET phi_r = -9e999 WHERE run_id = :r AND idx = 2", READS, ["point 2", "phi_r"]),
    "a reading lost": (f"DELETE FROM readings WHERE run_id = :r {ONE}", READS, ["point 1", "n_readings", "2 are stored"]),
    "readings of no point": ("DELETE FROM points WHERE run_id = :r AND idx = 3", READS,
                             ["point 3", "no points row"]),
}


def _argv(command: str, path: Path, rid: str, tmp_path: Path) -> list[object]:
    if command == "show-json":
        return ["show", rid, "--json", "--store", path]
    if command == "export":
        return ["export", rid, "--out", tmp_path / "out.csv", "--store", path]
    if command == "fit":
        return ["fit", rid, "--model", MODEL, "--store", path]
    return [command, rid, "--store", path]


@pytest.mark.parametrize("case", list(CORPUS))
def test_a_damaged_store_is_refused_in_one_line_naming_run_point_and_field(case, damage, capsys, tmp_path):
    sql, commands, named = CORPUS[case]
    path, rid, intact = damage(sql)
    before = path.read_bytes()
    for command in commands:
        code, out, err = run_main(capsys, *_argv(command, path, rid, tmp_path))
        assert code == 2, (case, command, code, err)
        assert err.count("\n") == 1 and "Traceback" not in err and "internal error" not in err, (case, command, err)
        assert f"run {rid}" in err and all(n in err for n in named), (case, command, err)
        assert out == "" or command == "export", (case, command, out)
    assert not (tmp_path / "out.csv").exists()  # nothing half-written
    assert path.read_bytes() == before  # reading never "repairs" the file
    code, out, err = run_main(capsys, "show", intact, "--json", "--store", path)
    assert code == 0 and json.loads(out)["run_id"] == intact  # the damage stays with its run


@pytest.mark.parametrize("case", ["meta not JSON", "created_epoch text", "plan a JSON list"])
def test_bench_runs_lists_a_damaged_run_with_its_reason_and_the_others_as_usual(case, damage, capsys):
    path, rid, intact = damage(CORPUS[case][0])
    code, out, err = run_main(capsys, "runs", "--store", path, "--json")
    assert code == 2 and err.count("\n") == 1 and rid in err and CORPUS[case][2][0] in err, err
    runs = {r["run_id"]: r for r in json.loads(out)}
    assert runs[rid]["damaged"] and CORPUS[case][2][0] in runs[rid]["damaged"]
    assert runs[intact]["damaged"] is None and runs[intact]["status"] == "completed"
    assert runs[intact]["specimen"] is not None and runs[intact]["points_done"] == 4
    code, out, err = run_main(capsys, "runs", "--store", path)
    lines = {line.split()[0]: line for line in out.splitlines()[1:]}
    assert code == 2 and "damaged" in lines[rid] and "completed" in lines[intact]


def test_a_run_id_that_is_not_the_stores_format_is_listed_damaged_and_never_created(damage, capsys):
    path, rid, intact = damage("UPDATE runs SET run_id = '../../etc/x' WHERE run_id = :r")
    code, out, err = run_main(capsys, "runs", "--store", path, "--json")
    runs = {r["run_id"]: r for r in json.loads(out)}
    assert code == 2 and "../../etc/x" in err and "format" in runs["../../etc/x"]["damaged"]
    assert runs[intact]["damaged"] is None
    with RunStore(path) as store, pytest.raises(Exception, match="not of the store's format"):
        store.create_run("scan", run_id="../up")


# --- bench fit's own refusals --------------------------------------------------------------


def test_fit_refuses_an_interrupted_run_unless_partial(damage, capsys):
    path, rid, _ = damage("UPDATE runs SET status = 'interrupted', n_planned = 9 WHERE run_id = :r")
    code, out, err = run_main(capsys, "fit", rid, "--model", MODEL, "--store", path)
    assert code == 2 and err.count("\n") == 1 and "interrupted (4 of 9 points" in err and "--partial" in err
    code, out, err = run_main(capsys, "fit", rid, "--model", MODEL, "--store", path, "--partial", "--json")
    assert code == 0 and "--partial" in err and json.loads(out)["dof"] == 11


def test_fit_says_how_many_readings_it_left_out_and_why(damage, capsys):
    masked = ("UPDATE readings SET value = NULL, std = NULL, ci_lo = NULL, ci_hi = NULL, extra = json_set("
              "json_remove(extra, '$.uncertainty_budget'), '$.extra.mask', 'saturated') WHERE run_id = :r AND idx = 1;"
              "UPDATE readings SET value = NULL, std = NULL, extra = NULL WHERE run_id = :r AND idx = 2 "
              "AND wavelength_nm = 450")
    path, rid, _ = damage(masked)
    code, out, err = run_main(capsys, "fit", rid, "--model", MODEL, "--store", path, "--json")
    assert code == 0, err
    assert "left out 4 of 12 readings" in err and "saturated 3" in err and "no value 1" in err
    assert json.loads(out)["dof"] == 12 - 4 - 1  # the dof counts only what was fitted


def test_fit_refuses_a_record_without_degrees_of_freedom(damage, capsys):
    keep_one = ("UPDATE readings SET value = NULL, std = NULL, ci_lo = NULL, ci_hi = NULL, extra = json_set("
                "json_remove(extra, '$.uncertainty_budget'), '$.extra.mask', 'saturated') WHERE run_id = :r "
                "AND NOT (idx = 0 AND wavelength_nm = 550)")
    path, rid, _ = damage(keep_one)
    code, out, err = run_main(capsys, "fit", rid, "--model", MODEL, "--store", path)
    lines = err.splitlines()
    assert code == 2 and out == "" and "dof <= 0" in lines[-1] and "1 readings for 1 free" in lines[-1]
    assert "Traceback" not in err and len(lines) == 2  # the left-out note, then the refusal
