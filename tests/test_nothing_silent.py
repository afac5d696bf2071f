"""Nothing silently wrong: a beam the fast path does not model, a NaN in a
compared record, an empty or odd --out, a command failing on a broken store, an empty file given
as a store, an interrupted Bluesky run and an enormous value each give one capped line, exit 2,
and leave no `running` run and nothing written behind."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.cli.argtypes import MAX_ERROR_CHARS
from bench.config import load_bench
from bench.core.records import BSDF_COLUMNS, BSDFRecord, Spectrum
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore
from compare.align import MissingValueError, align
from tests.helpers.cli import run_main

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "fixtures" / "benches" / "virtual.toml"
PLAN = {"name": "two", "kind": "list", "integration_s": 0.01, "averages": 1, "white": "once",
        "points": [[20, 0, 30, 180], [20, 0, 40, 180]]}


def test_fast_path_refuses_a_conical_beam(capsys):
    code, out, err = run_main(capsys, "gonio", "--specimen", "lambert:albedo=0.5", "--method", "fast",
                              "--beam", "conical")
    assert code == 2 and out == ""
    assert "fast" in err and "conical" in err and err.count("\n") == 1


def _spectrum(r: np.ndarray, n: int = 0) -> Spectrum:
    wl = np.arange(400.0, 701.0, 50.0)
    return Spectrum(geometry="8/d", wavelengths=wl, reflectance=r, transmittance=np.zeros_like(r),
                    reflectance_ci=np.column_stack([r, r]), transmittance_ci=np.zeros((r.size, 2)),
                    N=np.full(wl.shape, n, dtype=np.int64), seed=None, delta=0.05,
                    meta={"quantity": "reflectance", "specimen": "s", "reflectance_std": np.full(r.shape, 0.01)})


@pytest.mark.parametrize("side", ["actual", "candidate"])
def test_a_nan_in_a_compared_spectrum_is_refused_not_left_out(side):
    r = np.linspace(0.4, 0.6, 7)
    holed = r.copy()
    holed[3] = np.nan
    a, c = (_spectrum(holed), _spectrum(r, 10**5)) if side == "actual" else (_spectrum(r), _spectrum(holed, 10**5))
    with pytest.raises(MissingValueError, match=rf"{side} record: 1 matched value.*550 nm"):
        align(a, c)
    align(_spectrum(r), _spectrum(r, 10**5))  # the same records without the hole align


def test_a_nan_in_a_compared_bsdf_is_refused():
    def rec(v):
        rows = [{"wavelength_nm": 550.0, "theta_i": 30.0, "phi_i": 0.0, "theta_r": tr, "phi_r": 180.0,
                 "hemisphere": "R", "value": x, "std": 0.01, "ci_lo": np.nan, "ci_hi": np.nan, "theta_min": np.nan,
                 "theta_max": np.nan, "phi_min": np.nan, "phi_max": np.nan, "psa": np.nan, "count": np.nan, "N": 0}
                for tr, x in zip((10.0, 40.0), v)]
        return BSDFRecord(pd.DataFrame(rows)[BSDF_COLUMNS], {})

    with pytest.raises(MissingValueError, match="theta_i/r 30/40"):
        align(rec([0.2, np.nan]), rec([0.2, 0.2]))


@pytest.mark.parametrize("out,why", [("", "empty path"), ("sub/", "names a folder"), (".", "names a folder"),
                                     ("a\nb.csv", "control characters")])
def test_export_refuses_an_empty_or_odd_out(tmp_path, capsys, monkeypatch, out, why):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(capsys, "export", "R1", "--out", out, "--store", tmp_path / "none.sqlite")
    assert code == 2 and why in err and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written, not even RUN.csv


def _broken_store(path: Path) -> None:
    RunStore(path).close()
    db = sqlite3.connect(path)
    db.execute("DROP TABLE points")
    db.commit()
    db.close()


def test_a_store_that_lost_a_table_gets_no_running_run(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    _broken_store(store)
    plan = tmp_path / "p.toml"
    plan.write_text('name = "two"\nkind = "list"\nintegration_s = 0.01\naverages = 1\nwhite = "once"\n'
                    'points = [[20, 0, 30, 180], [20, 0, 40, 180]]\n')
    code, _, err = run_main(capsys, "scan", plan, "--bench", BENCH, "--store", store)
    assert code == 2 and "missing table(s) points" in err
    assert sqlite3.connect(store).execute("SELECT COUNT(*) FROM runs").fetchone()[0] == 0


def test_a_run_failing_on_anything_else_is_marked_failed_not_running(tmp_path):
    def bug(k, idx):
        raise RuntimeError("a bug after the first point")

    with load_bench(BENCH, seed=1) as bench, RunStore(tmp_path / "s.sqlite") as store:
        with pytest.raises(RuntimeError):
            run_scan(bench, plan_from_dict(PLAN), store, seed=1, on_point=bug)
        info = store.run(store.runs()[-1]["run_id"])
        assert info["status"] == "failed" and "RuntimeError: a bug" in info["reason"]
        assert info["points_done"] == 1


@pytest.mark.parametrize("argv", [["sweep", "--resume", "R1"], ["resume", "R1"], ["show", "R1"]])
def test_an_empty_file_is_not_a_store_and_stays_empty(tmp_path, capsys, argv):
    store = tmp_path / "zero.sqlite"
    store.write_bytes(b"")
    code, _, err = run_main(capsys, *argv, "--store", store)
    assert code == 2 and "not a goniobench run store" in err or "not a complete" in err, err
    assert store.read_bytes() == b"" and sorted(p.name for p in tmp_path.iterdir()) == ["zero.sqlite"]


def test_resume_of_an_interrupted_bluesky_run_says_why_in_bluesky_terms(tmp_path, capsys):
    path = tmp_path / "s.sqlite"
    with RunStore(path) as store:
        rid = store.create_run(kind="bluesky", plan={"bluesky_plan": "count", "plan_args": {}}, n_planned=3)
        store.set_status(rid, "interrupted", "process ended")
    code, _, err = run_main(capsys, "resume", rid, "--store", path)
    assert code == 2 and "RunEngine" in err and "'count'" in err and "unknown key" not in err


def test_error_lines_are_capped(capsys):
    code, _, err = run_main(capsys, "gonio", "--specimen", "q" * 60_000)
    assert code == 2 and err.count("\n") == 1
    assert len(err) < MAX_ERROR_CHARS + 40 and "characters left out" in err


LONG_INT = "7" * 5000  # past int()'s 4300-digit limit: json.loads raises a plain ValueError, not a JSONDecodeError


def _parquet_with(tmp_path: Path, key: bytes, value: str) -> Path:
    import pyarrow.parquet as pq

    from bench.io import record_to_parquet

    rows = [{"wavelength_nm": 550.0, "theta_i": 30.0, "phi_i": 0.0, "theta_r": tr, "phi_r": 180.0, "hemisphere": "R",
             "value": 0.2, "std": 0.01, "ci_lo": 0.19, "ci_hi": 0.21, "theta_min": np.nan, "theta_max": np.nan,
             "phi_min": np.nan, "phi_max": np.nan, "psa": np.nan, "count": 0, "N": 0} for tr in (10.0, 40.0)]
    path = record_to_parquet(BSDFRecord(pd.DataFrame(rows)[BSDF_COLUMNS], {"specimen": "s"}), tmp_path / "p.parquet")
    table = pq.read_table(path)
    pq.write_table(table.replace_schema_metadata({**table.schema.metadata, key: value.encode()}), path)
    return path


@pytest.mark.parametrize("key, value, says", [
    (b"goniobench.meta", f'{{"x": {LONG_INT}}}', "metadata goniobench.meta is not valid JSON (an integer of 5000 digits"),
    (b"goniobench.units", f'{{"x": {LONG_INT}}}', "metadata goniobench.units is not valid JSON (an integer of 5000"),
    (b"PANDAS_ATTRS", f'{{"x": {LONG_INT}}}', "metadata PANDAS_ATTRS is not valid JSON (an integer of 5000 digits"),
    (b"goniobench.meta", '{"x": ', "metadata goniobench.meta is not valid JSON (Expecting value at character 6)"),
    (b"goniobench.meta", "[1]", "metadata goniobench.meta holds a JSON list, not an object"),
    (b"pandas", f'{{"x": {LONG_INT}}}', "not a readable Parquet file"),
])
def test_a_parquet_file_with_bad_json_metadata_exits_2_naming_the_key(tmp_path, capsys, key, value, says):
    path = _parquet_with(tmp_path, key, value)
    code, out, err = run_main(capsys, "export", path, "--format", "csv", "--out", tmp_path / "o.csv")
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert f"{path}: " in err and says in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.parquet"]  # nothing written


def test_a_mitsuba_specimen_holding_a_long_integer_exits_2(capsys):
    code, out, err = run_main(capsys, "gonio", "--specimen", f'mitsuba:{{"type": {LONG_INT}}}')
    assert code == 2 and out == "" and err.count("\n") == 1, err
    assert "invalid JSON (an integer of 5000 digits" in err


def test_a_replay_fixture_or_geometry_file_holding_a_long_integer_is_one_config_error(tmp_path):
    """Library readers no command reaches (a test's transcript, an emulator's geometry file)."""
    from bench.core.errors import ConfigError
    from drivers.transport import load_fixture
    from virtual.wire.ocean_model import file_geometry_source

    fixture = tmp_path / "f.jsonl"
    fixture.write_text('{"sent": "00", "reply": "00"}\n{"sent": "00", "reply": ' + LONG_INT + "}\n")
    with pytest.raises(ConfigError, match=r"f\.jsonl:2: not JSON \(an integer of 5000 digits") as e:
        load_fixture(fixture)
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"fixture .*missing\.jsonl does not exist"):
        load_fixture(tmp_path / "missing.jsonl")
    geometry = tmp_path / "g.json"
    geometry.write_text('{"theta_i": ' + LONG_INT + "}")
    with pytest.raises(ConfigError, match=r"g\.json: not JSON \(an integer of 5000 digits"):
        file_geometry_source(str(geometry))
    geometry.write_text('{"theta_i": 3')  # caught half-written: no geometry yet
    assert file_geometry_source(str(geometry)) is None
