"""Exports hold only what was measured, in its own kind, with its units and identity where each
format's readers look -- checked against the README's description of each format, every file
read back with pandas' defaults (``pd.read_csv``, ``pd.read_parquet``)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from bench.cli import main
from bench.docs import documents
from bench.io import read_parquet, read_record
from helpers.cli import run_main
from helpers.export_records import SAMPLE_NAME, stored_runs_quietly

#: the README or the docs page that describes the formats
README = next(t for t in (p.read_text(encoding="utf-8") for p in documents(Path(__file__).resolve().parents[1]))
              if "Exports. `bench export RUN|FILE`" in t)
EXPORTS = README[README.index("Exports. `bench export RUN|FILE`"):]
EXPORTS = EXPORTS[:EXPORTS.index("\n\n")]


def _readme_list(before: str) -> list[str]:
    """The comma-separated backticked names the README's Exports paragraph gives after ``before``."""
    m = re.search(re.escape(before) + r"\s*`([^`]+)`", EXPORTS)
    assert m, f"README's Exports paragraph no longer says {before!r}"
    return [c.strip() for c in m.group(1).split(",")]


#: what the README says every row carries, and what pandas.read_parquet(...).attrs holds
IDENTITY = _readme_list("the identity of the record in every row:")
ATTRS = _readme_list("`pandas.read_parquet(\"run.parquet\").attrs` holds")
#: the measured columns the README lists first, in order
MEASURED = _readme_list("one row per reading with")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return stored_runs_quietly(tmp_path_factory, "export-identity", main)


def _export(capsys, runs, kind, out, *extra):
    store, ids = runs
    return run_main(capsys, "export", ids[kind], "--store", store, "--out", out, *extra)


@pytest.mark.parametrize("kind", ["gonio", "in-plane", "spectro", "spectro-sweep"])
def test_tidy_csv_is_what_the_readme_says(tmp_path, capsys, runs, kind):
    code, out, err = _export(capsys, runs, kind, tmp_path / "r.csv")
    assert code == 0, err
    df = pd.read_csv(tmp_path / "r.csv")  # pandas' defaults: one header row
    side = json.loads((tmp_path / "r.csv.json").read_text())
    cols = list(df.columns)
    # the measured columns first, in the README's order (those the record has), then the identity
    assert [c for c in cols if c in MEASURED] == [c for c in MEASURED if c in cols]
    assert cols.index("specimen") > max(cols.index(c) for c in cols if c in MEASURED)
    present = [c for c in IDENTITY if c in cols]
    assert {"specimen", "quantity", "run_id", "bench", "body", "plan"} <= set(present)
    # "Columns no row fills are left out": none is empty, and a key left out is empty in the record
    assert not [c for c in cols if df[c].isna().all()]
    for c in present:
        assert df[c].notna().all() and df[c].nunique() >= 1, c
    assert set(df.run_id) == {runs[1][kind]}
    units = side["column_units"]
    assert units["wavelength_nm"] == "nm" and units["theta_i"] == "deg"
    spectro = kind.startswith("spectro")
    assert units["value"] == ("1" if spectro else "1/sr")  # in its own kind
    if spectro:  # a reflectance: no viewing direction, no collector, its CIE geometry
        assert not {"theta_r", "phi_r", "collector"} & set(cols)
        assert set(df.quantity) <= {"reflectance", "reflectance factor", "transmittance"}
        assert set(df.geometry) == ({"8/d"} if kind == "spectro" else {"8/d", "45/0"})
        assert set(df.quantity[df.hemisphere == "T"]) == {"transmittance"}
    else:
        assert set(df.quantity) == {"BSDF"} and "geometry" not in cols
        assert set(df.sample_name) == {SAMPLE_NAME} and "plan` and `sample_name` (the bench's" in EXPORTS
    if kind == "spectro-sweep":  # a sweep's CSV says its bench and plan too
        assert set(df.plan) == {"spectro-cells"} and set(df.bench) == {"virtual-spectro"}


@pytest.mark.parametrize("kind", ["gonio", "in-plane", "spectro-sweep"])
def test_parquet_is_the_same_table_with_units_and_identity_in_attrs(tmp_path, capsys, runs, kind):
    assert _export(capsys, runs, kind, tmp_path / "r.csv")[0] == 0
    assert _export(capsys, runs, kind, tmp_path / "r.parquet")[0] == 0
    csv = pd.read_csv(tmp_path / "r.csv")
    pqt = pd.read_parquet(tmp_path / "r.parquet")  # pandas' defaults
    assert list(pqt.columns) == list(csv.columns)  # the same columns: no all-null extras
    pd.testing.assert_frame_equal(pqt.astype(object).where(pqt.notna(), None),
                                  csv.astype(object).where(csv.notna(), None), check_dtype=False)
    side = json.loads((tmp_path / "r.csv.json").read_text())
    assert set(ATTRS) <= set(pqt.attrs) and pqt.attrs["column_units"] == side["column_units"]
    for key in ATTRS[1:]:
        assert pqt.attrs[key] == str(csv[key].iloc[0]), key
    # "with that JSON in its schema metadata": the sidecar's metadata, and the project's reader agrees
    meta = json.loads(pq.read_schema(tmp_path / "r.parquet").metadata[b"goniobench.meta"])
    assert {k: v for k, v in side.items() if k != "column_units"} == meta
    assert read_parquet(tmp_path / "r.parquet").table.attrs == pqt.attrs


@pytest.mark.parametrize("kind", ["gonio", "in-plane"])
def test_astm_says_its_units_and_identity(tmp_path, capsys, runs, kind):
    code, out, err = _export(capsys, runs, kind, tmp_path / "r.astm.csv")
    assert code == 0, err
    lines = (tmp_path / "r.astm.csv").read_text().splitlines()
    kw = {ln.split(" ", 1)[0]: ln.split(" ", 1)[1] for ln in lines if re.match(r"^[A-Z_]+ ", ln)}
    # the README: radians, as the format has them, and the file says so; values in 1/sr
    assert "radians" in EXPORTS and kw["ANGLE_UNITS"] == "radians" and kw["VALUE_UNITS"] == "1/sr"
    assert kw["SAMPLE_NAME"] == f'"{SAMPLE_NAME}"' and kw["SPECIMEN"] == '"lambert:albedo=0.5"'
    assert kw["RUN_ID"] == f'"{runs[1][kind]}"' and kw["BODY"] and kw["PLAN"] and kw["BENCH"] == '"shelf-bench"'
    rows = np.array([[float(x) for x in ln.split(",")] for ln in lines[lines.index(next(
        ln for ln in lines if ln.startswith("VARS"))) + 1:]])
    assert np.allclose(rows[:, 0], math.radians(30.0))  # theta_i = 30 deg, written in radians
    back = read_record(tmp_path / "r.astm.csv")  # and read back in degrees
    assert np.allclose(back.table.theta_i, 30.0) and back.meta["astm_run_id"] == runs[1][kind]


def test_zemax_header_says_its_identity(tmp_path, capsys, runs):
    code, out, err = _export(capsys, runs, "gonio", tmp_path / "r.bsdf", "--wavelength", "550")
    assert code == 0, err
    head = [ln for ln in (tmp_path / "r.bsdf").read_text().splitlines() if ln.startswith("# ")]
    for line in ("# specimen lambert:albedo=0.5", f"# run_id {runs[1]['gonio']}", "# bench shelf-bench",
                 "# plan hemisphere", f"# sample_name {SAMPLE_NAME}", "# quantity BSDF (1/sr)"):
        assert line in head
    back = read_record(tmp_path / "r.bsdf")
    assert back.meta["run_id"] == runs[1]["gonio"] and back.meta["plan_name"] == "hemisphere"


@pytest.mark.parametrize("kind", ["spectro", "spectro-sweep"])
@pytest.mark.parametrize("suffix", ["astm.csv", "bsdf"])
def test_a_reflectance_is_never_written_as_a_brdf(tmp_path, capsys, runs, kind, suffix):
    code, out, err = _export(capsys, runs, kind, tmp_path / f"r.{suffix}")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "reflectance" in err and "not a BSDF" in err and "8/d" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("out", ["run.xlsx", "run.txt", "run"])
def test_an_unknown_suffix_is_refused_and_nothing_written(tmp_path, capsys, runs, out):
    code, stdout, err = _export(capsys, runs, "gonio", tmp_path / out)
    assert code == 2 and stdout == "" and len(err.strip().splitlines()) == 1 and "--format" in err
    assert list(tmp_path.iterdir()) == []
    code, stdout, err = _export(capsys, runs, "gonio", tmp_path / out, "--format", "csv")  # named: written
    assert code == 0 and len(pd.read_csv(tmp_path / out)) == 2 * 6 * 24
