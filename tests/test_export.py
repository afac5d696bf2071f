"""Exports and importers: round trips (tidy CSV, Parquet, ASTM, Zemax), the specular-centred
angles, resampling, atomic writes and clear errors for malformed files."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.core.errors import InputError
from bench.io import (atomic_write, export_record, export_run, from_specular, read_astm, read_parquet, read_record,
                      read_tidy_csv, read_zemax, record_to_astm, record_to_csv, record_to_parquet, record_to_zemax,
                      record_to_zemax_files, specular_frame, spectrum_to_csv, to_specular, zemax_grid)
from bench.core.records import BSDF_COLUMNS, BSDFRecord, with_keys
from bench.store import RunStore


def _meta_norm(meta):
    return json.loads(json.dumps(meta, default=str))


@pytest.fixture(scope="module")
def lambert():
    """A virtual Lambertian (R 0.6, T 0.2) record: 2 incidences x 2 wavelengths, both hemispheres."""
    from virtual.goniophotometer import VirtualGoniophotometer

    g = VirtualGoniophotometer("lambert:reflectance=0.6,transmittance=0.2", collector="equal-psa:6x24",
                               rays=50_000, seed=5, wavelengths=[450, 550], method="rays")
    a, b = g.measure_bsdf(30.0), g.measure_bsdf(50.0)
    return BSDFRecord(pd.concat([a.table, b.table], ignore_index=True), a.meta)


@pytest.fixture(scope="module")
def glossy(lambert):
    """The same patches with a lobe around the specular direction, so resampling can be checked."""
    t = lambert.table.copy()
    vals = np.empty(len(t))
    for (ti, pi_), part in t.groupby(["theta_i", "phi_i"]):
        trans = (part.hemisphere == "T").to_numpy()
        rad, _ = to_specular(ti, pi_, part.theta_r.to_numpy(), part.phi_r.to_numpy())
        rad_t, _ = to_specular(ti, pi_, part.theta_r.to_numpy(), part.phi_r.to_numpy(), transmission=True)
        r = np.where(trans, rad_t, rad)
        vals[part.index] = 0.05 + 3.0 * np.exp(-(r / 20.0) ** 2) * (1 + part.wavelength_nm.to_numpy() / 1e3)
    t["value"] = vals
    return BSDFRecord(t, dict(lambert.meta, specimen="synthetic lobe"))


# --- tidy CSV / Parquet --------------------------------------------------------------------


@pytest.mark.parametrize("meta_mode", ["header", "sidecar"])
def test_tidy_csv_round_trip_is_exact(tmp_path, lambert, meta_mode):
    import colour  # noqa: F401 - it sets numpy's legacy print options (12 digits); the export must not care

    path = record_to_csv(lambert, tmp_path / "r.csv", meta=meta_mode)
    back = read_tidy_csv(path)
    # the file carries the record's keys as columns (from its metadata: one specimen, one collector)
    pd.testing.assert_frame_equal(back.table, with_keys(lambert).table, check_exact=True)
    assert set(back.table.specimen) == {lambert.meta["specimen"]} and set(back.table.quantity) == {"BSDF"}
    assert set(back.table.collector) == {"equal-psa:6x24"}
    assert {k: v for k, v in back.meta.items() if k != "column_units"} == _meta_norm(lambert.meta)
    if meta_mode == "header":
        assert path.read_text().startswith("# goniobench-record 1\n# meta: {")
        assert back.meta["column_units"]["value"] == "1/sr" and back.meta["column_units"]["theta_i"] == "deg"
        assert back.meta["column_units"]["wavelength_nm"] == "nm" and back.meta["column_units"]["psa"] == "sr"
        plain = pd.read_csv(path, comment="#")  # what a user reading it with pandas gets
        assert list(plain.columns) == BSDF_COLUMNS + ["specimen", "collector", "quantity"]  # no geometry: none filled
        assert len(plain) == len(lambert)
    else:  # the default: plain pandas reads the table; metadata and units are in <file>.json
        assert json.loads(Path(str(path) + ".json").read_text()) == back.meta
        assert back.meta["column_units"]["value"] == "1/sr" and back.meta["column_units"]["theta_i"] == "deg"
        plain = pd.read_csv(path)
        assert list(plain.columns) == BSDF_COLUMNS + ["specimen", "collector", "quantity"]  # no geometry: none filled
        assert len(plain) == len(lambert) and set(plain.specimen) == {lambert.meta["specimen"]}


def test_parquet_round_trip_keeps_types_and_meta(tmp_path, lambert):
    import pyarrow.parquet as pq  # installed by make test (the [parquet] extra): a hard requirement here
    path = record_to_parquet(lambert, tmp_path / "r.parquet")
    back = read_parquet(path)
    pd.testing.assert_frame_equal(back.table, with_keys(lambert).table, check_dtype=False)
    assert back.table["count"].dtype == np.int64
    assert {k: v for k, v in back.meta.items() if k != "column_units"} == _meta_norm(lambert.meta)
    md = pq.read_schema(path).metadata
    assert b"goniobench.meta" in md and json.loads(md[b"goniobench.units"])["value"] == "1/sr"


def test_export_run_from_the_store_and_dispatch_by_suffix(tmp_path, lambert):
    with RunStore(tmp_path / "runs.sqlite") as s:
        rid = s.create_run("virtual")
        s.add_record(rid, lambert)
        out = export_run(s, rid, tmp_path / "run.parquet")
    back = read_record(out)
    pd.testing.assert_frame_equal(back.table[BSDF_COLUMNS], lambert.table, check_dtype=False)
    assert back.meta["run_id"] == rid and back.meta["seed"] == 5
    out2 = export_run(tmp_path / "runs.sqlite", rid, tmp_path / "run.csv")
    assert read_record(out2).meta["run_id"] == rid
    with pytest.raises(InputError, match="cannot tell the export format"):
        export_record(lambert, tmp_path / "r.xyz")


# --- ASTM ----------------------------------------------------------------------------------


def test_astm_layout_and_round_trip_to_printed_precision(tmp_path, lambert):
    path = record_to_astm(lambert, tmp_path / "r.astm", digits=7)
    lines = path.read_text().splitlines()
    v = next(i for i, line in enumerate(lines) if line.startswith("VARS "))
    head = dict(line.split(" ", 1) for line in lines[:v])
    assert head["SAMPLE_NAME"] == '"lambert:reflectance=0.6,transmittance=0.2"'
    assert head["SPECIMEN"] == head["SAMPLE_NAME"] and head["ANGLE_UNITS"] == "radians"
    assert re.fullmatch(r"\d{4}-\d\d-\d\d", head["MEAS_DATE"])
    n_geo = len(lambert.table) // 2
    assert head["NUM_POINTS"] == str(n_geo)
    assert lines[v] == "VARS theta_i,phi_i,theta_s,phi_s,450nm,550nm"
    first = [float(x) for x in lines[v + 1].split(",")]
    assert first[0] == pytest.approx(math.radians(30.0), abs=1e-15)  # radians in the file
    assert max(float(line.split(",")[2]) for line in lines[v + 1:]) <= math.pi
    back = read_astm(path).table
    key = ["theta_i", "phi_i", "theta_r", "phi_r", "wavelength_nm"]
    a = lambert.table.sort_values(key).reset_index(drop=True)
    b = back.sort_values(key).reset_index(drop=True)
    for c in ("theta_i", "phi_i", "theta_r", "phi_r"):
        np.testing.assert_allclose(b[c], a[c], rtol=0, atol=1e-10)
    expected = np.array([float(f"{v:.7g}") for v in a.value])
    assert np.array_equal(b.value.to_numpy(), expected)  # exactly the printed digits
    assert list(b.hemisphere) == list(a.hemisphere)
    assert read_astm(path).meta["seed"] == 5
    one = read_astm(record_to_astm(lambert, tmp_path / "r_only.astm", hemisphere="R")).table
    assert len(one) == len(lambert.table) // 2 and (one.theta_r <= 90).all()


def test_astm_reads_rgb_channels_and_refuses_duplicates(tmp_path, lambert):
    p = tmp_path / "rgb.astm"
    p.write_text("SAMPLE_NAME \"x\"\nNUM_POINTS 2\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n"
                 "0,0,0.5,3.14159,0.1,0.2,0.3\n0,0,0.6,3.14159,0.4,0.5,0.6\n")
    t = read_astm(p).table
    assert list(t.channel) == ["R", "G", "B"] * 2 and t.wavelength_nm.isna().all()
    assert t.theta_r.iloc[0] == pytest.approx(math.degrees(0.5))
    dup = BSDFRecord(pd.concat([lambert.table.iloc[:1]] * 2, ignore_index=True), {})
    with pytest.raises(InputError, match="two values for geometry"):
        record_to_astm(dup, tmp_path / "d.astm")


ASTM_OK = "SAMPLE_NAME \"s\"\nNUM_POINTS 2\nVARS theta_i,phi_i,theta_s,phi_s,550nm\n0,0,0.1,0,0.3\n0,0,0.2,0,0.4\n"


@pytest.mark.parametrize("text, line, what", [
    (ASTM_OK.replace("VARS theta_i,phi_i,theta_s,phi_s,550nm\n", ""), 3, "expected a header keyword"),
    (ASTM_OK.replace("VARS theta_i,phi_i,theta_s,phi_s,550nm", "VARS a,b,c,d,550nm"), 3, "expected 'VARS theta_i"),
    (ASTM_OK.replace("0,0,0.2,0,0.4", "0,0,0.2,0"), 5, "expected 5 comma-separated numbers"),
    (ASTM_OK.replace("0,0,0.2,0,0.4", "0,0,0.2,0,abc"), 5, "expected a number, got 'abc'"),
    (ASTM_OK.replace("NUM_POINTS 2", "NUM_POINTS 3"), 6, "NUM_POINTS says 3 rows, the file has 2"),
    (ASTM_OK.replace("0,0,0.2,0,0.4", "0,0,45,0,0.4"), 5, "outside \\[0, pi\\] radians"),
    ("SAMPLE_NAME \"s\"\n", 2, "expected a 'VARS"),
])
def test_malformed_astm_names_file_line_and_expectation(tmp_path, text, line, what):
    p = tmp_path / "bad.astm"
    p.write_text(text)
    with pytest.raises(InputError, match=rf"bad\.astm:{line}: .*{what}"):
        read_astm(p)


# --- Zemax ---------------------------------------------------------------------------------


def _libbsdf_out_dir(in_theta, in_phi, spec_theta, spec_phi):
    """libbsdf's SpecularCoordinateSystem::toOutDirXyz (radians), the frame its Zemax reader uses."""
    o = np.array([math.sin(spec_theta) * math.cos(spec_phi), math.sin(spec_theta) * math.sin(spec_phi),
                  math.cos(spec_theta)])
    rx = o[0] * math.cos(in_theta) - o[2] * math.sin(in_theta)
    rz = o[0] * math.sin(in_theta) + o[2] * math.cos(in_theta)
    return np.array([rx * math.cos(in_phi) - o[1] * math.sin(in_phi), rx * math.sin(in_phi) + o[1] * math.cos(in_phi), rz])


def test_specular_frame_conventions():
    s, e_1, e_2 = specular_frame(30.0, 0.0)
    np.testing.assert_allclose(s, [-0.5, 0.0, math.sqrt(3) / 2], atol=1e-15)
    np.testing.assert_allclose(e_2, [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.cross(e_1, e_2), s, atol=1e-15)  # right-handed about s
    # specular -> radial 0; normal -> radial theta_i at azimuth 0 (toward the normal);
    # further forward in the plane of incidence -> azimuth 180; +y -> 90, -y -> 270
    r, a = to_specular(30.0, 0.0, [30.0, 0.0, 50.0, 30.0, 30.0], [180.0, 0.0, 180.0, 90.0, 270.0])
    np.testing.assert_allclose(r[:3], [0.0, 30.0, 20.0], atol=1e-12)
    np.testing.assert_allclose(a[1:3], [0.0, 180.0], atol=1e-9)
    assert 0 < a[3] < 180 and 180 < a[4] < 360
    # normal incidence: the frame still follows phi_i
    r, a = to_specular(0.0, 90.0, [20.0], [90.0])
    assert r[0] == pytest.approx(20.0) and a[0] == pytest.approx(0.0, abs=1e-9)
    # the BTDF mirror: the straight-through direction is radial 0
    r, _ = to_specular(40.0, 10.0, [140.0], [190.0], transmission=True)
    assert r[0] == pytest.approx(0.0, abs=1e-6)
    # the same directions as libbsdf's specular coordinate system (its Zemax reader)
    rng = np.random.default_rng(3)
    for _ in range(50):
        ti, pi_, rad, az = rng.uniform(0, 80), rng.uniform(0, 360), rng.uniform(0, 90), rng.uniform(0, 360)
        th, ph = from_specular(ti, pi_, rad, az)
        v = np.array([math.sin(math.radians(th)) * math.cos(math.radians(ph)),
                      math.sin(math.radians(th)) * math.sin(math.radians(ph)), math.cos(math.radians(th))])
        np.testing.assert_allclose(v, _libbsdf_out_dir(*np.radians([ti, pi_, rad, az])), atol=1e-12)


def test_specular_angles_invert():
    rng = np.random.default_rng(0)
    for trans in (False, True):
        for _ in range(20):
            ti, pi_ = rng.uniform(0, 85), rng.uniform(0, 360)
            th = rng.uniform(0.5, 89.5, 50)
            th = 180.0 - th if trans else th
            ph = rng.uniform(0, 360, 50)
            r, a = to_specular(ti, pi_, th, ph, transmission=trans)
            th2, ph2 = from_specular(ti, pi_, r, a, transmission=trans)
            np.testing.assert_allclose(th2, th, atol=1e-9)
            d = (ph2 - ph + 180.0) % 360.0 - 180.0
            np.testing.assert_allclose(d, 0.0, atol=1e-8)


def test_zemax_grid_takes_the_value_of_the_patch_containing_each_node(lambert, glossy):
    g = zemax_grid(glossy, wavelength_nm=550)
    assert g.values.shape == (1, 2, 37, 46) and list(g.incidences) == [30.0, 50.0]
    assert g.azimuths[-1] == 360.0 and g.radials[-1] == 90.0
    t = glossy.table
    for j, inc in enumerate(g.incidences):
        part = t[(t.theta_i == inc) & (t.wavelength_nm == 550) & (t.hemisphere == "R")]
        A, R = np.meshgrid(g.azimuths, g.radials, indexing="ij")
        th, ph = from_specular(inc, 0.0, R, A)
        for a in range(0, 37, 4):
            for r in range(0, 46, 5):
                if th[a, r] > 90:
                    assert g.values[0, j, a, r] == 0.0
                    continue
                inside = ((part.theta_min <= th[a, r]) & (th[a, r] <= part.theta_max)
                          & (part.phi_min <= ph[a, r]) & (ph[a, r] < part.phi_max))
                assert g.values[0, j, a, r] in set(part.value[inside])
        # TIS from the collector: sum of value * PSA over the hemisphere
        assert g.tis[0, j] == pytest.approx(float((part.value * part.psa).sum()))
    lam = zemax_grid(lambert, wavelength_nm=450)
    tot = {round(x["wavelength_nm"]): x["reflectance"] for x in lambert.meta["totals"]}
    assert lam.tis[0, 0] == pytest.approx(tot[450], rel=1e-12)


def test_zemax_round_trip_at_the_grid_points(tmp_path, glossy):
    g = zemax_grid(glossy, wavelength_nm=450, symmetry="PlaneSymmetrical")
    assert g.azimuths[-1] == 180.0
    path = record_to_zemax(g, tmp_path / "r.bsdf", digits=6)
    text = path.read_text()
    for kw in ("Source  Measured", "Symmetry  PlaneSymmetrical", "SpectralContent  Monochrome",
               "ScatterType  BRDF", "SampleRotation  1", "AngleOfIncidence  2", "ScatterAzimuth  19",
               "ScatterRadial  46", "\n\nMonochrome\nDataBegin\nTIS  ", "DataEnd\n"):
        assert kw in text
    back = read_zemax(path)
    t = back.table
    assert back.meta["symmetry"] == "PlaneSymmetrical" and back.meta["scatter_type"] == "BRDF"
    assert (t.wavelength_nm == 450.0).all() and (t.hemisphere == "R").all() and (t.theta_r <= 90 + 1e-9).all()
    assert [x["tis"] for x in back.meta["tis"]] == [float(f"{v:.5e}") for v in g.tis[0]]
    j = {30.0: 0, 50.0: 1}
    a = {v: i for i, v in enumerate(g.azimuths)}
    r = {v: i for i, v in enumerate(g.radials)}
    expected = [float(f"{g.values[0, j[ti], a[az], r[rd]]:.5e}")
                for ti, az, rd in zip(t.theta_i, t.azimuth_deg, t.radial_deg)]
    assert np.array_equal(t.value.to_numpy(), np.array(expected))
    # the directions come back where the grid put them
    for ti in (30.0, 50.0):
        sub = t[t.theta_i == ti]
        rad, az = to_specular(ti, 0.0, sub.theta_r.to_numpy(), sub.phi_r.to_numpy())
        np.testing.assert_allclose(rad, sub.radial_deg, atol=1e-9)
        ok = sub.radial_deg > 0
        np.testing.assert_allclose(((az - sub.azimuth_deg + 180) % 360 - 180)[ok], 0.0, atol=1e-7)
    # exporting the re-read record again gives the same grid (nearest sample = the node itself)
    g2 = zemax_grid(back, symmetry="PlaneSymmetrical", azimuths=g.azimuths, radials=g.radials)
    inside = g.values > 0
    np.testing.assert_allclose(g2.values[inside], np.array([float(f"{v:.5e}") for v in g.values[inside]]),
                               rtol=0, atol=0)


def test_zemax_btdf_goes_to_the_transmission_side(tmp_path, lambert):
    path = record_to_zemax(lambert, tmp_path / "t.bsdf", wavelength_nm=550, scatter_type="BTDF")
    back = read_zemax(path)
    t = back.table
    assert (t.hemisphere == "T").all() and (t.theta_r >= 90 - 1e-9).all()
    tot = {round(x["wavelength_nm"]): x["transmittance"] for x in lambert.meta["totals"]}
    assert back.meta["tis"][0]["tis"] == pytest.approx(tot[550], rel=1e-5)
    # a Lambertian transmitter: every node near 0.2 / pi
    assert t.value.mean() == pytest.approx(0.2 / math.pi, rel=0.05)


def test_zemax_needs_one_wavelength_and_complete_pairs(tmp_path, lambert):
    with pytest.raises(InputError, match="one wavelength; pass wavelength_nm"):
        zemax_grid(lambert)
    with pytest.raises(InputError, match="no rows at 600 nm"):
        zemax_grid(lambert, wavelength_nm=600)
    t = lambert.table
    holey = BSDFRecord(t[~((t.theta_i == 50) & (t.phi_i == 0))].assign(
        phi_i=lambda d: np.where(d.wavelength_nm == 450, 90.0, d.phi_i)), {})
    with pytest.raises(InputError, match="needs every \\(rotation, incidence\\) pair"):
        zemax_grid(BSDFRecord(pd.concat([holey.table, t[t.theta_i == 50]]), {}), wavelength_nm=450)


ZEMAX_OK = """Source  Measured
Symmetry  PlaneSymmetrical
SpectralContent  Monochrome
ScatterType  BRDF
SampleRotation  1
0
AngleOfIncidence  1
10
ScatterAzimuth  2
0 180
ScatterRadial  3
0 10 20

Monochrome
DataBegin
TIS  0.5
1 2 3
4 5 6
DataEnd
"""


def test_zemax_reader_accepts_a_hand_written_file(tmp_path):
    p = tmp_path / "ok.bsdf"
    p.write_text(ZEMAX_OK)
    t = read_zemax(p).table
    assert list(t.value) == [1, 2, 3, 4, 5, 6]
    # row 0: the specular direction; azimuth 0, radial 20: 20 deg from specular toward the normal,
    # i.e. 10 deg on the source side; azimuth 180, radial 20: beyond the specular direction
    assert t.theta_r.iloc[0] == pytest.approx(10.0) and t.phi_r.iloc[0] == pytest.approx(180.0)
    assert t.theta_r.iloc[2] == pytest.approx(10.0) and t.phi_r.iloc[2] == pytest.approx(0.0, abs=1e-9)
    assert t.theta_r.iloc[5] == pytest.approx(30.0) and t.phi_r.iloc[5] == pytest.approx(180.0)


@pytest.mark.parametrize("old, new, line, what", [
    ("DataBegin\n", "", 15, "expected a Zemax BSDF header keyword .*DataBegin\\), got 'TIS'"),
    ("TIS  0.5", "TIS", 16, "expected 'TIS <value>' for rotation 0, incidence 10"),
    ("4 5 6", "4 5", 18, "expected 3 numbers \\(one per ScatterRadial\\) for azimuth 180"),
    ("DataEnd\n", "", 19, "expected 'DataEnd'"),
    ("ScatterRadial  3\n0 10 20", "ScatterRadial  3\n0 10", 14, "expected numbers for ScatterRadial, got 'Monochrome'"),
    ("ScatterAzimuth  2", "ScatterAzimuth  two", 9, "expected 'ScatterAzimuth <count>'"),
    ("Symmetry  PlaneSymmetrical", "Symetry  PlaneSymmetrical", 2, "expected a Zemax BSDF header keyword"),
])
def test_malformed_zemax_names_file_line_and_expectation(tmp_path, old, new, line, what):
    p = tmp_path / "bad.bsdf"
    p.write_text(ZEMAX_OK.replace(old, new, 1))
    with pytest.raises(InputError, match=r"bad\.bsdf:\d+: ") as e:
        read_zemax(p)
    assert re.search(what, str(e.value)), str(e.value)
    assert f"bad.bsdf:{line}:" in str(e.value), str(e.value)


# --- malformed tidy files, atomic writes, spectra ------------------------------------------


def test_malformed_tidy_csv_and_parquet(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("# goniobench-record 1\n# meta: {not json\nwavelength_nm,value\n550,0.1\n")
    with pytest.raises(InputError, match=r"bad\.csv:2: expected JSON"):
        read_tidy_csv(p)
    p.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match=r"bad\.csv:1: expected a column wavelength_nm"):
        read_tidy_csv(p)
    q = tmp_path / "bad.parquet"
    q.write_bytes(b"PAR1 nonsense")
    with pytest.raises(InputError, match=r"bad\.parquet: not a readable Parquet file"):
        read_parquet(q)
    with pytest.raises(InputError, match="no such file"):
        read_astm(tmp_path / "missing.astm")


LONG_INT = "7" * 5000  # past int()'s digit limit: json.loads raises a plain ValueError, not a JSONDecodeError


@pytest.mark.parametrize("name, text, where", [
    ("meta.csv", f"# goniobench-record 1\n# meta: {{\"x\": {LONG_INT}}}\nwavelength_nm,value\n550,0.1\n",
     r"meta\.csv:2: expected JSON after '# meta:'"),
    ("gonio.json", f'{{"N": {LONG_INT}}}\n', r"gonio\.json: not JSON"),
])
def test_a_json_number_longer_than_int_takes_is_refused_in_one_line(tmp_path, name, text, where):
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(InputError, match=where + r".*digits") as e:
        read_record(p)
    assert "\n" not in str(e.value)


def test_atomic_write_leaves_the_old_file_on_failure(tmp_path, lambert, monkeypatch):
    target = tmp_path / "r.csv"
    target.write_text("old\n")

    def half(tmp):
        Path(tmp).write_text("partial")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, half)
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]
    record_to_csv(lambert, target)
    assert target.read_text().startswith("wavelength_nm,") and Path(str(target) + ".json").is_file()


def test_spectrum_to_csv_still_works(tmp_path):
    from virtual.spectrophotometer import VirtualSpectrophotometer

    sp = VirtualSpectrophotometer("lambert:albedo=0.5", rays=2000, seed=1)
    s = sp.measure("8/d", [500, 600])
    with pytest.raises(InputError, match="does not exist"):  # no folder is created unasked
        spectrum_to_csv(s, tmp_path / "a" / "s.csv")
    assert not (tmp_path / "a").exists()
    (tmp_path / "a").mkdir()
    out = spectrum_to_csv(s, tmp_path / "a" / "s.csv")
    df = pd.read_csv(out)
    assert list(df.wavelength_nm) == [500, 600] and "reflectance_lo" in df.columns


def test_zemax_from_in_plane_point_samples(tmp_path):
    # an in-plane physical scan: no patch bounds, theta_r every 10 deg on both sides at theta_i 30
    tr = np.arange(-80.0, 81.0, 10.0)
    t = pd.DataFrame({"wavelength_nm": 550.0, "theta_i": 30.0, "phi_i": 0.0, "theta_r": np.abs(tr),
                      "phi_r": np.where(tr >= 0, 180.0, 0.0), "hemisphere": "R",
                      "value": 0.1 + np.exp(-((tr - 30.0) / 15.0) ** 2)})
    rec = BSDFRecord(t, {"specimen": "in-plane"})
    # in the plane of incidence the specular-centred grid hits the samples exactly
    g = zemax_grid(rec, symmetry="PlaneSymmetrical", azimuths=[0.0, 180.0], radials=np.arange(0.0, 111.0, 10.0))
    assert g.meta["zemax_resampling"]["method"] == "nearest sample"
    v = dict(zip(tr, t.value))
    # every node is a sample except the grazing one (azimuth 180, radial 60: theta_r = 90), 10 deg
    # from the last sample at 80
    assert g.meta["zemax_resampling"]["max_nearest_distance_deg"] == pytest.approx(10.0)
    assert g.values[0, 0, 1, 6] == v[80.0] and np.all(g.values[0, 0, 1, 7:] == 0.0)
    assert g.values[0, 0, 1, 0] == v[30.0]          # radial 0 = the specular sample
    assert g.values[0, 0, 1, 3] == v[60.0]          # azimuth 180: beyond specular
    assert g.values[0, 0, 0, 3] == v[0.0]           # azimuth 0: toward the normal
    assert g.values[0, 0, 0, 11] == v[-80.0]        # ... and on to the source side
    # off the plane nothing was measured: a distance limit leaves those nodes at 0 and says so
    full = zemax_grid(rec, max_distance_deg=5.0)
    res = full.meta["zemax_resampling"]
    assert res["nodes_unfilled"] > 0 and res["max_nearest_distance_deg"] > 5.0
    A, R = np.meshgrid(full.azimuths, full.radials, indexing="ij")
    assert np.all(full.values[0, 0][(np.abs(A - 90) < 1) & (R > 20)] == 0.0)
    back = read_zemax(record_to_zemax(full, tmp_path / "p.bsdf"))
    assert back.meta["symmetry"] == "Asymmetrical" and len(back.table) > 0


# --- exports read by others: parsers written here from the formats' public descriptions (ASTM
# E2387 CSV as libbsdf reads it; Zemax OpticStudio tabular BSDF), not our importers


def _parse_astm(text):
    """ASTM CSV: free keyword lines, a VARS line, then comma-separated rows, angles in radians."""
    keywords, vars_, rows = {}, None, []
    for line in text.splitlines():
        if vars_ is None:
            key, _, rest = line.partition(" ")
            if key == "VARS":
                vars_ = rest.split(",")
            else:
                keywords[key] = rest
        elif line.strip():
            rows.append([float(x) for x in line.split(",")])
    return keywords, vars_, np.array(rows)


def _parse_zemax(text):
    """Zemax tabular BSDF: keyword lines (``Key value`` or ``Key n`` + a line of n values), a blank
    line, ``Monochrome``, ``DataBegin``, per (rotation, incidence) ``TIS v`` and an azimuth x radial
    block, ``DataEnd``. Comment lines start with #."""
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    head, lists, i = {}, {}, 0
    while lines[i].strip():
        key, value = lines[i].split(None, 1)
        if key in ("SampleRotation", "AngleOfIncidence", "ScatterAzimuth", "ScatterRadial"):
            lists[key] = [float(x) for x in lines[i + 1].split()]
            assert len(lists[key]) == int(value)
            i += 2
        else:
            head[key] = value.strip()
            i += 1
    assert lines[i + 1] == "Monochrome" and lines[i + 2] == "DataBegin"
    i += 3
    n_az, n_rad = len(lists["ScatterAzimuth"]), len(lists["ScatterRadial"])
    blocks, tis = [], []
    while lines[i] != "DataEnd":
        key, value = lines[i].split()
        assert key == "TIS"
        tis.append(float(value))
        block = np.array([[float(x) for x in lines[i + 1 + a].split()] for a in range(n_az)])
        assert block.shape == (n_az, n_rad)
        blocks.append(block)
        i += 1 + n_az
    assert len(blocks) == len(lists["SampleRotation"]) * len(lists["AngleOfIncidence"])
    return head, lists, np.array(tis), np.array(blocks)


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_every_export_is_readable_by_an_independent_parser_and_by_others(tmp_path, lambert, umask_022):
    # tidy CSV as described: "#" header lines, then a plain CSV whose floats are shortest
    # round-trip reprs (Python's csv module and float() read them back exactly)
    import csv as csv_module

    csv = record_to_csv(lambert, tmp_path / "r.csv")
    body = [line for line in csv.read_text().splitlines() if not line.startswith("#")]
    table = list(csv_module.DictReader(body))
    assert len(table) == len(lambert.table)
    assert [float(r["value"]) for r in table] == lambert.table.value.tolist()
    # Parquet through pyarrow itself, metadata under goniobench.meta
    import pyarrow.parquet as pq

    pqt = pq.read_table(record_to_parquet(lambert, tmp_path / "r.parquet"))
    assert json.loads(pqt.schema.metadata[b"goniobench.meta"])["seed"] == 5 and pqt.num_rows == len(lambert.table)
    # ASTM: radians, one row per measured geometry, NUM_POINTS rows, no all-NaN fill rows
    astm = record_to_astm(lambert, tmp_path / "r.astm")
    kw, vars_, rows = _parse_astm(astm.read_text())
    assert vars_[:4] == ["theta_i", "phi_i", "theta_s", "phi_s"] and vars_[4:] == ["450nm", "550nm"]
    assert int(kw["NUM_POINTS"]) == len(rows) == len(lambert.table.groupby(["theta_i", "phi_i", "theta_r", "phi_r"]))
    assert rows[:, [0, 2]].max() <= math.pi + 1e-12 and rows[:, [1, 3]].max() < 2 * math.pi  # radians
    assert not np.isnan(rows[:, 4:]).all(axis=1).any()
    t = lambert.table
    one = t[(t.wavelength_nm == 550)].iloc[7]
    hit = rows[np.all(np.isclose(rows[:, :4], np.radians([one.theta_i, one.phi_i, one.theta_r, one.phi_r])), axis=1)]
    assert len(hit) == 1 and hit[0, 5] == pytest.approx(one.value, rel=1e-8)
    # Zemax: the grid as described, with the resampling said in the header
    zem = record_to_zemax(lambert, tmp_path / "r.bsdf", wavelength_nm=550)
    text = zem.read_text()
    head, lists, tis, blocks = _parse_zemax(text)
    g = zemax_grid(lambert, wavelength_nm=550)
    assert head == {"Source": "Measured", "Symmetry": "Asymmetrical", "SpectralContent": "Monochrome",
                    "ScatterType": "BRDF"}
    assert lists["AngleOfIncidence"] == [30.0, 50.0] and lists["SampleRotation"] == [0.0]
    np.testing.assert_allclose(blocks, g.values.reshape(blocks.shape), rtol=1e-5)
    np.testing.assert_allclose(tis, g.tis.ravel(), rtol=1e-5)
    assert "# resampling containing patch" in text and "# resampling farthest node from its sample" in text
    # files people share are written like any other file: 0644 under umask 022
    for path in (csv, tmp_path / "r.parquet", astm, zem):
        assert (path.stat().st_mode & 0o777) == 0o644, path


def test_astm_of_an_in_plane_record_has_no_fill_rows(tmp_path):
    tr = np.arange(-60.0, 61.0, 20.0)
    t = pd.DataFrame({"wavelength_nm": 550.0, "theta_i": 30.0, "phi_i": 0.0, "theta_r": np.abs(tr),
                      "phi_r": np.where(tr >= 0, 180.0, 0.0), "hemisphere": "R", "value": 0.1 + 0.01 * tr})
    kw, _, rows = _parse_astm(record_to_astm(BSDFRecord(t, {}), tmp_path / "p.astm").read_text())
    assert len(rows) == len(t) == int(kw["NUM_POINTS"]) and not np.isnan(rows[:, 4]).any()


def test_zemax_writes_one_file_per_wavelength_or_the_one_asked_for(tmp_path, lambert):
    paths = record_to_zemax_files(lambert, tmp_path / "z.bsdf")
    assert [p.name for p in paths] == ["z-450nm.bsdf", "z-550nm.bsdf"]
    for p, w in zip(paths, (450.0, 550.0)):
        back = read_zemax(p)
        assert (back.table.wavelength_nm == w).all() and "# resampling containing patch" in p.read_text()
    only = record_to_zemax_files(lambert, tmp_path / "one.bsdf", wavelength_nm=550)
    assert [p.name for p in only] == ["one.bsdf"] and (read_zemax(only[0]).table.wavelength_nm == 550).all()


def test_read_record_tells_the_format_from_the_first_line(tmp_path, lambert):
    """The one loader registry: content first (our CSV header, ASTM keywords, Zemax keywords, a
    spectrum table), then the suffix; a file it cannot place is one clear InputError."""
    from bench.io import infer_format

    astm = record_to_astm(lambert, tmp_path / "a.astm")
    misnamed = tmp_path / "astm-data.csv"
    misnamed.write_text(astm.read_text())
    assert infer_format(misnamed, reading=True) == "astm" and len(read_record(misnamed)) == len(lambert.table)
    z = tmp_path / "z.txt"
    z.write_text(ZEMAX_OK)
    assert infer_format(z, reading=True) == "zemax" and len(read_record(z)) > 0
    tidy = record_to_csv(lambert, tmp_path / "t.data")
    assert infer_format(tidy, reading=True) == "csv"
    with pytest.raises(InputError, match="cannot tell the import format"):
        read_record(tmp_path / "nothing.xyz")
