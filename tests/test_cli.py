"""The CLI contract: outputs later checks rely on, JSON keys, exit status 2 for bad input."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.cli import run_main


def test_rays_prints_eq_3_5_and_eq_3_12(capsys):
    assert run_main(capsys, "rays", "--uncertainty", "0.005", "--delta", "0.01") == (0, "105967\n", "")
    assert run_main(capsys, "rays", "--uncertainty", "0.005", "--delta", "0.01", "--patches", "900")[1] == "95370300\n"
    code, out, _ = run_main(capsys, "rays", "-u", "0.005", "-d", "0.01", "--json")
    assert code == 0 and json.loads(out)["N"] == 105967


@pytest.mark.parametrize("argv,needle", [
    (["rays", "--uncertainty", "0", "--delta", "0.01"], "uncertainty"),
    (["rays", "--uncertainty", "-1", "--delta", "0.01"], "uncertainty"),
    (["rays", "--uncertainty", "0.01", "--delta", "1"], "delta"),
    (["rays", "--uncertainty", "0.01", "--delta", "0"], "delta"),
    (["spectro", "--specimen", "lambert:reflectance=0.5", "--geometry", "9/9", "--rays", "10"], "geometry"),
    (["spectro", "--specimen", "chalk", "--rays", "10"], "specimen"),
    (["spectro", "--specimen", "colorchecker:dark skin", "--wavelengths", "300:400:10", "--rays", "10"], "300"),
    (["spectro", "--specimen", "lambert:reflectance=0.5", "--uncertainty", "0", "--delta", "0.01"], "uncertainty"),
])
def test_bad_input_exits_2_with_a_one_line_message(capsys, argv, needle):
    code, out, err = run_main(capsys, *argv)
    assert code == 2
    assert needle in err and err.count("\n") == 1


def test_spectro_json_has_the_contract_keys(capsys):
    code, out, _ = run_main(capsys, "spectro", "--specimen", "lambert:reflectance=0.5,transmittance=0.3",
                       "--geometry", "8/d", "--wavelengths", "400:700:150", "--rays", "20000", "--seed", "7", "--json")
    assert code == 0
    d = json.loads(out)
    for key in ("N", "seed", "geometry", "wavelength_nm", "reflectance", "transmittance",
                "reflectance_ci", "transmittance_ci"):
        assert key in d
    assert d["N"] == 20000 and d["seed"] == 7 and d["wavelength_nm"] == [400.0, 550.0, 700.0]
    assert all(lo <= r <= hi for r, (lo, hi) in zip(d["reflectance"], d["reflectance_ci"]))


def test_spectro_writes_csv_and_plot(capsys, tmp_path):
    csv, png = tmp_path / "s.csv", tmp_path / "s.png"
    code, out, _ = run_main(capsys, "spectro", "--specimen", "colorchecker:dark skin", "--wavelengths", "400:700:20",
                       "--rays", "5000", "--seed", "1", "--csv", str(csv), "--plot", str(png))
    assert code == 0 and "dark skin" in out
    assert csv.read_text().splitlines()[0].startswith("wavelength_nm,reflectance")
    assert len(csv.read_text().splitlines()) == 1 + 16
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_console_script_runs_and_starts_without_heavy_imports():
    # `bench rays` must not import numba kernels, colour or matplotlib
    code = ("import sys; from bench.cli import main; main(['rays','-u','0.01','-d','0.05']); "
            "heavy = [m for m in ('colour', 'matplotlib', 'pandas', 'virtual.engine') if m in sys.modules]; "
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-1] == "[]"
    exe = Path(sys.executable).parent / "bench"
    if exe.exists():
        r = subprocess.run([str(exe), "rays", "-u", "0.005", "-d", "0.01"], capture_output=True, text=True)
        assert r.returncode == 0 and r.stdout == "105967\n"


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """One small in-plane run shared by the tests that only read it: (store, run id)."""
    import contextlib
    import io

    from bench.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        tmp = tmp_path_factory.mktemp("small-run")
        bench, plan = _small_run_files(tmp)
        store = tmp / "runs.sqlite"
        code = main(["scan", str(plan), "--bench", str(bench), "--store", str(store), "--seed", "5", "-q"])
    assert code == 0, err.getvalue()
    return store, out.getvalue().strip()


def _small_run_files(tmp_path, wavelengths="550"):
    bench = tmp_path / "bench.toml"
    bench.write_text('name = "v"\nkind = "virtual"\n[specimen]\nspec = "lambert:albedo=0.6"\n'
                     '[white]\nreflectance_factor = 0.99\nuncertainty = 0.005\ngeometry = [0, 0, 45, 180]\n'
                     '[virtual]\ncollector = "equal-psa:9x36"\nrays = 2000000\n'
                     f'wavelengths = "{wavelengths}"\n')
    plan = tmp_path / "plan.toml"
    plan.write_text('name = "p"\nkind = "in-plane"\nintegration_s = 0.01\naverages = 1\ndark = "once"\n'
                    'white = "once"\n[in_plane]\ntheta_i = [30]\ntheta_r = { start = -60, stop = 60, step = 20 }\n'
                    'phi_i = 0\n')
    return bench, plan


def _small_run(tmp_path, capsys, wavelengths="550"):
    """A small virtual in-plane run (one wavelength by default) in a fresh store: (store, run id)."""
    bench, plan = _small_run_files(tmp_path, wavelengths)
    store = tmp_path / "runs.sqlite"
    code, out, err = run_main(capsys, "scan", str(plan), "--bench", str(bench), "--store", str(store), "--seed", "5", "-q")
    assert code == 0, err
    return store, out.strip()


def test_bench_compare_reads_every_export_format_of_a_run(tmp_path, capsys, small_run):
    """Each file `bench export` writes is read back by `bench compare` (through bench.io's one
    loader registry) and compares with the run it came from: same points, no discrepancy for the
    lossless formats; the Zemax grid (resampled) compares with itself."""
    store, run_id = small_run
    for fmt in ("csv", "parquet", "astm", "zemax"):
        fill = ["--fill", "nearest"] if fmt == "zemax" else []  # an in-plane run: filling is asked for
        code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--format", fmt,
                             "--out", str(tmp_path / f"r.{fmt}.out"), *fill)
        assert code == 0, err
        path = out.strip()
        other = f"same={path}" if fmt == "zemax" else f"run={run_id}"
        code, out, err = run_main(capsys, "compare", f"file={path}", other, "--store", str(store), "--json",
                             "--out", str(tmp_path / f"report-{fmt}"), "--no-figures")
        assert code == 0, (fmt, err)
        s = json.loads(out)["candidates"]["same" if fmt == "zemax" else "run"]
        assert s["n_points"] > 0, fmt
        if fmt != "zemax":
            assert s["n_points"] == 7 and s["max_abs"] < 1e-9, (fmt, s)


def test_bench_compare_reads_a_spectro_csv(tmp_path, capsys):
    csv = tmp_path / "s.csv"
    code, _, err = run_main(capsys, "spectro", "--specimen", "lambert:reflectance=0.5", "--wavelengths", "400:700:50",
                       "--rays", "20000", "--seed", "2", "--csv", str(csv))
    assert code == 0, err
    code, out, err = run_main(capsys, "compare", str(csv), f"again={csv}", "--json", "--out", str(tmp_path / "rep"))
    assert code == 0, err
    d = json.loads(out)
    assert d["kind"] == "spectrum" and d["candidates"]["again"]["n_points"] == 7


def test_export_zemax_one_file_per_wavelength_or_the_one_asked_for(tmp_path, capsys):
    store, run_id = _small_run(tmp_path, capsys, wavelengths="450,550")
    # an in-plane run has no out-of-plane data: refused, with the reason and the way to opt in
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--out", str(tmp_path / "z.bsdf"))
    assert code == 2 and "in-plane" in err and "--fill nearest" in err and err.count("\n") == 1
    assert not list(tmp_path.glob("z*.bsdf"))
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--format", "zemax",
                         "--out", str(tmp_path / "z.bsdf"), "--fill", "nearest")
    assert code == 0, err
    assert [Path(p).name for p in out.split()] == ["z-450nm.bsdf", "z-550nm.bsdf"]
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--format", "zemax", "--wavelength", "550",
                         "--out", str(tmp_path / "one.bsdf"), "--fill", "nearest")
    assert code == 0 and out.split() == [str(tmp_path / "one.bsdf")]
    text = (tmp_path / "one.bsdf").read_text()
    assert "# wavelength_nm 550" in text and "# resampling fill nearest (asked for)" in text
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--format", "csv", "--wavelength", "550")
    assert code == 2 and "--wavelength" in err and err.count("\n") == 1


def test_a_cli_scan_keeps_its_identity_in_runs_show_and_every_export(tmp_path, capsys, small_run):
    """runs/show name specimen, bench, body and plan, values with their unit to the digits their
    uncertainty supports; --out's suffix picks the export format (a .parquet is Parquet), a
    different --format is one line (exit 2); a record file converts like a run; the CSV reads
    with plain pandas, identity filled."""
    import pandas as pd
    import pyarrow.parquet as pq

    store, run_id = small_run
    code, out, err = run_main(capsys, "runs", "--store", str(store))
    assert code == 0 and "lambert:albedo=0.6" in out and "v (virtual)" in out and " p " in out, out
    code, out, err = run_main(capsys, "show", run_id, "--store", str(store))
    assert code == 0 and "specimen lambert:albedo=0.6; bench v (virtual body); plan p" in out, out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("value "))
    assert " 1/sr (" in line and "smallest standard uncertainty" in line
    u = float(line.split("smallest standard uncertainty ")[1].split()[0])
    lo = line.split()[1]
    assert len(lo.split(".")[1]) == max(0, 1 - math.floor(math.log10(u))), line  # two digits of u
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--out", str(tmp_path / "r.parquet"))
    assert code == 0, err
    assert pq.read_table(tmp_path / "r.parquet").num_rows == 7
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--out", str(tmp_path / "x.parquet"),
                              "--format", "csv")
    assert code == 2 and "--format" in err and err.count("\n") == 1 and not (tmp_path / "x.parquet").exists()
    code, out, err = run_main(capsys, "export", run_id, "--store", str(store), "--out", str(tmp_path / "r.csv"))
    assert code == 0, err
    plain = pd.read_csv(tmp_path / "r.csv")
    assert len(plain) == 7 and plain.specimen.notna().all() and set(plain.run_id) == {run_id}
    assert set(plain.body) == {"virtual"} and plain["bench"].notna().all() and plain["plan"].notna().all()
    assert not [c for c in plain.columns if plain[c].isna().all() and c not in ("collector", "geometry")]
    units = json.loads((tmp_path / "r.csv.json").read_text())["column_units"]
    assert units["value"] == "1/sr" and units["signal"] == "counts" and units["white"] == "counts"
    code, out, err = run_main(capsys, "export", str(tmp_path / "r.csv"), "--out", str(tmp_path / "c.astm.csv"))
    assert code == 0, err
    astm = (tmp_path / "c.astm.csv").read_text()
    assert f"SAMPLE_NAME {plain.specimen[0]}" in astm.replace('"', "") and "SCATTER_TYPE BRDF" in astm


@pytest.mark.parametrize("value,hint", [("0.55", "0.55 looks like um (550 nm)"), ("5.5e-7", "looks like metres"),
                                        ("2e6", "pm or Angstrom"), ("50", "vacuum ultraviolet")])
def test_wavelengths_outside_100_nm_to_1e5_nm_are_refused_with_the_unit_they_look_like(capsys, value, hint):
    from bench.core.parsing import parse_wavelengths

    code, _, err = run_main(capsys, "spectro", "--specimen", "lambert:albedo=0.5", "--wavelengths", value,
                            "--rays", "1000", "--seed", "1")
    assert code == 2 and hint in err and err.count("\n") == 1, err
    assert list(parse_wavelengths("100,1e5")) == [100.0, 1e5]  # the bounds themselves pass


def test_angles_that_all_look_like_radians_are_warned_about_not_refused(capsys):
    from bench.core.parsing import looks_like_radians

    assert looks_like_radians([0.5, 1.2]) and looks_like_radians([1.2])
    assert not looks_like_radians([0, 30, 60]) and not looks_like_radians([0, 1, 2]) and not looks_like_radians([0])
    code, out, err = run_main(capsys, "gonio", "--specimen", "lambert:albedo=0.5", "--wavelengths", "550",
                              "--rays", "1000", "--seed", "1", "--collector", "equal-psa:3x8", "--incidence", "1.2")
    assert code == 0 and "warning: --incidence 1.2 taken as degrees" in err and "68.75 deg" in err
    code, out, err = run_main(capsys, "gonio", "--specimen", "lambert:albedo=0.5", "--wavelengths", "550",
                              "--rays", "1000", "--seed", "1", "--collector", "equal-psa:3x8", "--incidence", "30")
    assert code == 0 and "warning" not in err


def test_bench_specimens_prints_the_readme_tables_fields_for_every_family(capsys):
    """Generated from the declarations as the specimens page's table (docs/specimens.md) is: the convention (not a cut
    docstring), choices as choices, every family and the colorchecker/mitsuba forms, no markup."""
    from virtual.specimens import specimen_families
    from virtual.specimens.strings import RESERVED_FORMS

    code, out, _ = run_main(capsys, "specimens")
    assert code == 0 and ":class:" not in out and "``" not in out
    heads = [line for line in out.splitlines() if line and not line.startswith(" ") and ":" in line]
    for fam in specimen_families():
        assert f"{fam['name']}: {fam['convention']}" in heads
    for name, (form, _) in RESERVED_FORMS.items():
        assert f"{name}: {form}" in heads
    assert "  masking: correlated | separable, default correlated" in out
    assert "  nonlinear: false | true, default false" in out


def test_gonio_stores_its_record_and_writes_the_one_tidy_csv_and_spectro_names_its_specimen(tmp_path, capsys):
    import pandas as pd

    db, csv = tmp_path / "g.sqlite", tmp_path / "g.csv"
    code, out, err = run_main(capsys, "gonio", "--specimen", "lambert:albedo=0.5", "--rays", "100000", "--seed", "3",
                              "--collector", "equal-psa:3x8", "--store", str(db), "--csv", str(csv))
    assert code == 0, err
    rid = out.split()[1]
    plain = pd.read_csv(csv)  # the tidy CSV, as bench export writes it: plain pandas, identity in every row
    assert set(plain.specimen) == {"lambert:albedo=0.5"} and set(plain.body) == {"virtual"} and len(plain) == 24 * 2
    code, out, err = run_main(capsys, "export", rid, "--store", str(db), "--out", str(tmp_path / "e.csv"))
    assert code == 0, err
    exported = pd.read_csv(tmp_path / "e.csv")
    assert exported["value"].tolist() == plain["value"].tolist() and set(exported.run_id) == {rid}
    code, out, err = run_main(capsys, "show", rid, "--store", str(db))
    assert "specimen lambert:albedo=0.5; bench virtual-gonio (virtual body); plan gonio" in out
    code, _, err = run_main(capsys, "spectro", "--specimen", "lambert:albedo=0.5", "--wavelengths", "500,600",
                            "--rays", "1000", "--seed", "2", "--csv", str(tmp_path / "s.csv"))
    assert code == 0 and set(pd.read_csv(tmp_path / "s.csv").specimen) == {"lambert:albedo=0.5"}
    from bench.io import read_record

    assert read_record(tmp_path / "s.csv").meta["specimen"] == "lambert:albedo=0.5"
    code, out, err = run_main(capsys, "spectro", "--specimen", "lambert:albedo=0.5", "--wavelengths", "500,600",
                              "--rays", "1000", "--seed", "2", "--store", str(db), "--json")
    assert code == 0, err
    rid = json.loads(out)["run_id"]
    code, out, err = run_main(capsys, "export", rid, "--store", str(db), "--out", str(tmp_path / "sp.csv"))
    spectrum = pd.read_csv(tmp_path / "sp.csv").sort_values(["hemisphere", "wavelength_nm"])
    assert code == 0 and set(spectrum.specimen) == {"lambert:albedo=0.5"} and set(spectrum.geometry) == {"8/d"}
    assert list(spectrum.quantity) == ["reflectance"] * 2 + ["transmittance"] * 2
