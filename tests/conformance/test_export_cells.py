"""Conformance cells of the exports: record kind x format -> written and read back equal (with
pandas' defaults where the format is a table, with the project's reader for every format), or
refused in one line (exit 2, nothing written).

A record goes only to a format that can say what it is: a BSDF (1/sr per viewing direction) to
every format; a spectrophotometer's reflectance (8/d, 45/0: unitless, no viewing direction) to the
tidy CSV and Parquet only; an in-plane scan to Zemax only with ``--fill nearest`` (a hemisphere
grid would be invented otherwise).
"""

from __future__ import annotations


import numpy as np
import pandas as pd
import pytest

from bench.cli import main
from bench.io import read_record
from helpers.cli import run_main
from helpers.export_records import LAMBERT_BRDF, stored_runs_quietly

KINDS = ("gonio", "in-plane", "spectro", "spectro-sweep")
FORMATS = {"csv": "r.csv", "parquet": "r.parquet", "astm": "r.astm.csv", "zemax": "r.bsdf"}

#: (kind, format) -> the words of the one-line refusal; every other cell is written
REFUSED = {("in-plane", "zemax"): "in-plane scan", ("spectro", "astm"): "reflectance",
           ("spectro", "zemax"): "reflectance", ("spectro-sweep", "astm"): "reflectance",
           ("spectro-sweep", "zemax"): "reflectance"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return stored_runs_quietly(tmp_path_factory, "export-cells", main)


def _stored_rows(store, run_id) -> pd.DataFrame:
    """What the store holds of the run, as the export's reference (tidy CSV of the run itself)."""
    from bench.io import run_records, tidy_table
    from bench.store import RunStore

    with RunStore(store, create=False, readonly=True) as s:
        (_, rec), = run_records(s, run_id)
    return tidy_table(rec).reset_index(drop=True)


@pytest.mark.parametrize("fmt", list(FORMATS))
@pytest.mark.parametrize("kind", KINDS)
def test_export_cell(tmp_path, capsys, runs, kind, fmt):
    store, ids = runs
    out = tmp_path / FORMATS[fmt]
    extra = ("--wavelength", "550") if fmt == "zemax" else ()
    code, stdout, err = run_main(capsys, "export", ids[kind], "--store", store, "--out", out, *extra)
    if (kind, fmt) in REFUSED:
        assert code == 2 and stdout == "" and len(err.strip().splitlines()) == 1, err
        assert REFUSED[(kind, fmt)] in err
        assert list(tmp_path.iterdir()) == []  # nothing written
        return
    assert code == 0, err
    ref = _stored_rows(store, ids[kind])
    if fmt == "csv":
        back = pd.read_csv(out)  # pandas' defaults
        pd.testing.assert_frame_equal(back, ref.astype({c: object for c in ref if ref[c].dtype == bool}),
                                      check_dtype=False, check_exact=True)
    elif fmt == "parquet":
        back = pd.read_parquet(out)  # pandas' defaults
        pd.testing.assert_frame_equal(back.astype(object).where(back.notna(), None),
                                      ref.astype(object).where(ref.notna(), None), check_dtype=False)
        assert back.attrs["column_units"]["value"] == ("1" if kind.startswith("spectro") else "1/sr")
    elif fmt == "astm":
        back = read_record(out).table  # to the printed precision (9 digits), degrees again
        cols = ["wavelength_nm", "theta_i", "phi_i", "theta_r", "phi_r"]
        key = lambda t: t.sort_values(cols).reset_index(drop=True)  # noqa: E731
        a, b = key(back[cols + ["value"]]), key(ref[cols + ["value"]])
        np.testing.assert_allclose(a[cols].to_numpy(float), b[cols].to_numpy(float), atol=1e-9)
        np.testing.assert_allclose(a.value, b.value, rtol=1e-8)
    else:  # zemax: the Lambertian's constant BRDF at every grid node, TIS its albedo
        rec = read_record(out)
        assert np.allclose(rec.table.value, LAMBERT_BRDF, rtol=1e-5)
        assert [t["tis"] for t in rec.meta["tis"]] == pytest.approx([0.5], rel=1e-5)
        assert rec.meta["run_id"] == ids[kind]


def test_a_spectrum_csv_goes_nowhere_as_a_bsdf(tmp_path, capsys):
    """``bench spectro --csv`` writes a spectrum table; ``bench export`` converts BSDF records and
    refuses it in one line whatever the format."""
    spec = tmp_path / "s.csv"
    code, _, err = run_main(capsys, "spectro", "--specimen", "lambert:reflectance=0.5", "--wavelengths", "550",
                            "--rays", "2000", "--seed", "1", "--csv", spec)
    assert code == 0, err
    for fmt, name in FORMATS.items():
        code, out, err = run_main(capsys, "export", spec, "--out", tmp_path / f"x-{name}")
        assert code == 2 and len(err.strip().splitlines()) == 1 and "spectrum table" in err, (fmt, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv"]
