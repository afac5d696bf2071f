"""The leaf specimen: PROSPECT-D's R and T at 8 deg, energy per ray, reciprocity, the
cuticle's specular peak, extreme parameters, the fast path against ray counting, colour and compare.

Statistical tests use fixed seeds; each states its false-alarm rate, and the power of the
chi-square test is shown by a perturbed parameter.
"""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import prosail
import pytest

from bench.cli import main
from bench.core.errors import SpecimenError
from tests.helpers.stats import two_sample_p
from virtual.bounds import binomial_ci, hoeffding_rays
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.leaf_optics import cuticle_integrals
from virtual.specimens import Leaf, parse_specimen
from virtual.specimens.leaf import LEAF_LIBRARY
from virtual.spectrophotometer import VirtualSpectrophotometer

N_EQ35 = hoeffding_rays(0.005, 0.01)  # eq. 3.5, v = 0.005, delta = 0.01: 105,967 rays
PROSPECT_KEYS = ("n", "cab", "car", "cbrown", "cw", "cm")


def _prospect(spec: Leaf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PROSPECT-D straight from prosail (not through the specimen's cache)."""
    v = spec.values(550.0)
    return prosail.run_prospect(*(v[k] for k in PROSPECT_KEYS), ant=v["anth"], prospect_version="D", alpha=40.0)


def _direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


# --- declaration ---------------------------------------------------------------------------------


def test_declared_through_the_registry_with_its_ranges():
    s = parse_specimen("leaf:n=1.5,cab=40,car=8,anth=0,cbrown=0,cw=0.01,cm=0.009,roughness=0.3,eta=1.5")
    assert isinstance(s, Leaf) and s.has_density and s.reciprocal
    assert s.wavelength_range() == (400.0, 2500.0)
    a, eta, ks, rb, tb = s.params(550.0)
    assert (a, eta, ks) == (0.3, 1.5, 1.0) and 0 < rb < 1 and 0 < tb < 1
    for bad, word in [("n=0.5", "n must lie"), ("roughness=2", "roughness must lie"), ("eta=2.5", "eta must lie"),
                      ("cab=-1", "cab must lie"), ("cbrown=1.5", "cbrown must lie"), ("colour=3", "unknown parameter")]:
        with pytest.raises(SpecimenError, match=word):
            parse_specimen(f"leaf:{bad}")
    with pytest.raises(SpecimenError, match="400-2500 nm"):
        s.params(399.0)
    with pytest.raises(SpecimenError, match="400-2500 nm"):
        VirtualSpectrophotometer(s, rays=10, seed=1).measure("8/d", [380, 550])
    with pytest.raises(SpecimenError, match="must be a number"):
        Leaf(cab=([400.0, 700.0], [30.0, 40.0]))
    lossless = Leaf(cab=0, car=0, cw=0, cm=0)  # no absorber at all: PROSPECT-D gives R + T = 1
    a, eta, ks, rb, tb = lossless.params(550.0)
    assert rb + tb == pytest.approx(1.0, abs=1e-12)


def test_the_library_by_name_with_overrides():
    lib = tomllib.loads(LEAF_LIBRARY.read_text())["leaf"]  # the file itself, not our reader
    assert {"healthy", "pale", "senescent", "dry", "red"} <= set(lib)
    for name, entry in lib.items():
        assert entry["source"] and entry["description"]
        s = parse_specimen(f"leaf:{name}")
        assert all(s.values(550)[k] == pytest.approx(entry[k]) for k in ("n", "cab", "cw", "roughness"))
    s = parse_specimen("leaf:healthy,roughness=0.2,cab=60")
    assert s.values(550)["roughness"] == 0.2 and s.values(550)["cab"] == 60 and s.values(550)["cw"] == 0.01
    with pytest.raises(SpecimenError, match="unknown leaf 'oak'.*healthy"):
        parse_specimen("leaf:oak")


@pytest.mark.slow  # the cuticle quadrature at 2 x 3 orders (~8 CPU-s)
def test_cuticle_quadrature_is_converged_at_8_deg_and_near_grazing():
    for a in (1e-4, 0.05, 0.3, 1.0):
        for theta, tol in ((8.0, 1e-10), (60.0, 1e-8), (85.0, 3e-5), (89.9, 3e-5)):
            es, fb = cuticle_integrals(math.radians(theta), a, 1.5)
            es2, fb2 = cuticle_integrals(math.radians(theta), a, 1.5, nodes=96, scan=2048)
            assert abs(es - es2) < tol and abs(fb - fb2) < tol, (a, theta, es - es2, fb - fb2)
            assert 0.0 < es <= fb < 1.0
    # smooth cuticle: E_s = Fbar = Fresnel at the incidence; rough: masking keeps E_s below Fbar
    es, fb = cuticle_integrals(math.radians(8.0), 1e-4, 1.5)
    c = math.cos(math.radians(8.0))
    ct = math.sqrt(1 - (1 - c * c) / 2.25)
    fres = 0.5 * (((c - 1.5 * ct) / (c + 1.5 * ct)) ** 2 + ((1.5 * c - ct) / (1.5 * c + ct)) ** 2)
    assert es == pytest.approx(fres, abs=1e-8) and fb == pytest.approx(fres, abs=1e-8)
    es, fb = cuticle_integrals(math.radians(8.0), 1.0, 1.5)
    assert fb - es > 0.05


def test_the_cuticle_sums_of_every_azimuth_node_at_once_equal_those_of_each_node_alone():
    """The quadrature evaluates every azimuth node's r2 segments in one array; each node's sum must
    be the one a node-by-node evaluation gives, bit for bit (the leaf's tables, and so the kernel's
    pinned digests, rest on them), including nodes whose segments are all unlit."""
    from virtual.leaf_optics import _GRADED, _gl, _segment_sums

    xv, wv = _gl(8)
    u = np.array([0.02, 0.2, 0.45, 0.5])
    cuts = [_GRADED, np.unique(np.concatenate([_GRADED, [0.35, 0.77]])), np.array([0.0, 0.3, 0.3, 1.0]), _GRADED]
    for theta, a, eta, lit in ((0.3, 0.2, 1.45, True), (1.5, 0.9, 1.9, True), (1.2, 0.05, 1.3, False)):
        together = _segment_sums(theta, a, eta, u, cuts, xv, wv, lit)
        alone = [_segment_sums(theta, a, eta, u[k:k + 1], [cuts[k]], xv, wv, lit)[0] for k in range(len(u))]
        assert together == alone and all(isinstance(v, float) for v in together)
        assert len(set(together)) > 1  # the nodes differ: a mix-up of nodes would show


# --- application (a): PROSPECT-D at 8/d ----------------------------------------------------------


def _within_bonferroni(spec: str, wavelengths: str, seed: int) -> tuple[int, float]:
    """Measure at 8/d with a conical beam and eq. 3.5's N; every R_P, T_P inside the Clopper-Pearson
    interval at confidence 1 - 0.01 / (2 n_wavelengths) (Bonferroni over wavelengths and R, T:
    a correct model fails this with probability <= 0.01)."""
    s = parse_specimen(spec)
    sp = VirtualSpectrophotometer(s, rays=N_EQ35, beam="conical", seed=seed)
    m = sp.measure("8/d", wavelengths)
    wl = m.wavelengths
    w, rp, tp = _prospect(s)
    idx = np.searchsorted(w, wl)
    assert np.all(w[idx] == wl)
    delta = 0.01 / (2 * wl.size)
    counts = m.meta["counts"]
    k_r = np.array([c["reflected"] for c in counts])
    k_t = np.array([c["transmitted"] for c in counts])
    n = np.array([c["N"] - c["missed"] for c in counts])
    r_lo, r_hi = binomial_ci(k_r, n, delta)
    t_lo, t_hi = binomial_ci(k_t, n, delta)
    bad_r = wl[(rp[idx] < r_lo) | (rp[idx] > r_hi)]
    bad_t = wl[(tp[idx] < t_lo) | (tp[idx] > t_hi)]
    assert bad_r.size == 0 and bad_t.size == 0, (spec, bad_r, bad_t)
    return wl.size, float(max(np.abs(m.reflectance - rp[idx]).max(), np.abs(m.transmittance - tp[idx]).max()))


@pytest.mark.slow  # 421 wavelengths x 1e5 rays on the ray-by-ray leaf kernel (~25 CPU-s); make test has the 8 deg checks per leaf
def test_bench_spectro_8d_conical_reproduces_prospect_d_at_every_wavelength(capsys):
    # the acceptance command, N of eq. 3.5, the intervals printed at the Bonferroni confidence
    n_wl = 421
    code = main(["spectro", "--specimen", "leaf:n=1.5,cab=40,car=8,anth=0,cbrown=0,cw=0.01,cm=0.009",
                 "--geometry", "8/d", "--wavelengths", "400:2500:5", "--beam", "conical", "--rays", str(N_EQ35),
                 "--delta", str(0.01 / (2 * n_wl)), "--seed", "19", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    wl = np.array(out["wavelength_nm"])
    assert wl.size == n_wl and out["N"] == N_EQ35 and "conical" in json.dumps(out["beam"])
    w, rp, tp = prosail.run_prospect(1.5, 40, 8, 0, 0.01, 0.009, ant=0.0, prospect_version="D", alpha=40.0)
    idx = np.searchsorted(w, wl)
    r_ci, t_ci = np.array(out["reflectance_ci"]), np.array(out["transmittance_ci"])
    assert np.all((r_ci[:, 0] <= rp[idx]) & (rp[idx] <= r_ci[:, 1])), wl[(r_ci[:, 0] > rp[idx]) | (rp[idx] > r_ci[:, 1])]
    assert np.all((t_ci[:, 0] <= tp[idx]) & (tp[idx] <= t_ci[:, 1]))
    # and the colour line: a green leaf under D65
    col = out["colour"]
    r, g, b = col["reflectance"]["sRGB"]
    assert col["illuminant"] == "D65" and g > r and g > b
    assert col["reflectance"]["Lab"][1] < 0  # a* < 0: green


# make test runs the healthy leaf; make test-slow the other four (~4 CPU-s each, the ray-by-ray kernel)
@pytest.mark.parametrize("name, seed", [("healthy", 1), *(pytest.param(n, s, marks=pytest.mark.slow) for n, s in
                                                          (("pale", 2), ("senescent", 3), ("dry", 4), ("red", 5)))])
def test_every_library_leaf_matches_prospect_at_8_deg(name, seed):
    n_wl, worst = _within_bonferroni(f"leaf:{name}", "400:2500:25", seed)
    assert n_wl == 85 and worst < 0.01


def test_where_prospect_reflects_less_than_the_cuticle_the_specular_scale_takes_over():
    s = parse_specimen("leaf:cab=0,cw=0.05")
    scaled = s.tables().specular_scaled_nm
    assert scaled.size > 0 and 1940.0 in scaled  # the water band
    a, eta, ks, rb, tb = s.params(1940.0)
    assert ks < 1.0 and rb == 0.0
    _within_bonferroni("leaf:cab=0,cw=0.05", "1900:2000:20", 6)


# --- energy, reciprocity, the specular peak ------------------------------------------------------


def test_r_plus_t_plus_a_is_n_for_every_ray():
    s = parse_specimen("leaf:senescent")
    m = VirtualSpectrophotometer(s, rays=200_001, beam="conical", seed=8).measure("8/d", [450, 680, 1450, 2200])
    for c in m.meta["counts"]:
        assert c["reflected"] + c["transmitted"] + c["absorbed"] + c["missed"] == 200_001
        assert c["missed"] == 0 and c["absorbed"] > 0
    g = VirtualGoniophotometer("leaf:senescent", rays=300_001, seed=9, method="rays", wavelengths=[550, 1450])
    for w in (550.0, 1450.0):
        counts = g.simulate(70.0, 30.0, w)
        assert counts.dtype == np.int64 and int(counts.sum()) == 300_001


@pytest.mark.slow  # the leaf density at every pair of a grid (~6 CPU-s)
def test_reciprocity_density_symmetric_to_1e_12():
    rng = np.random.default_rng(5)
    s = parse_specimen("leaf:healthy")
    worst = 0.0
    for _ in range(60):
        a = rng.normal(size=3)
        b = rng.normal(size=3)
        a[2], b[2] = abs(a[2]), abs(b[2])  # reflection: both above
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        bt = b * np.array([1, 1, -1])  # transmission: wo below
        for w in (450.0, 800.0):
            for x, y in ((a, b), (a, bt)):
                f1 = s.bsdf(x, y[None, :], w)[0]
                f2 = s.bsdf(y, x[None, :], w)[0] if y[2] > 0 else s.bsdf(-y, -x[None, :], w)[0]
                assert f1 >= 0 and math.isfinite(f1)
                worst = max(worst, abs(f1 - f2) / max(abs(f1), 1e-300))
    assert worst < 1e-12
    # the check has teeth: the plastic coupling (rough entry, smooth exit) is not symmetric
    p = parse_specimen("plastic:alpha=0.3,eta=1.5,kd=0.5")
    x, y = _direction(0.0), _direction(70.0, 180.0)
    assert abs(p.bsdf(x, y[None], 550)[0] / p.bsdf(y, x[None], 550)[0] - 1.0) > 0.02


def test_specular_peak_in_the_mirror_direction_and_growing_toward_grazing():
    s = parse_specimen("leaf:healthy,roughness=0.1")
    theta_o = np.linspace(0.05, 89.95, 1799)
    view = np.stack([_direction(t, 180.0) for t in theta_o])
    # the peak sits at the mirror direction, shifted slightly toward grazing as incidence grows
    # (the off-specular peak of microfacet surfaces, Torrance & Sparrow 1967)
    for ti, shift in ((15.0, 0.5), (30.0, 1.0), (45.0, 1.5), (60.0, 3.0)):
        f = s.bsdf(_direction(ti), view, 550.0)
        assert ti - 0.1 <= theta_o[np.argmax(f)] <= ti + shift, (ti, theta_o[np.argmax(f)])
    peaks = [s.bsdf(_direction(t), _direction(t, 180.0)[None], 550.0)[0] for t in (10, 30, 50, 70, 80)]
    assert np.all(np.diff(peaks) > 0), peaks
    # the lobe's albedo (R minus the body's part) grows too
    spec = []
    for t in (10, 30, 50, 70, 85):
        r, tt = s.directional_rt(t, 550.0)
        a, eta, ks, rb, tb = s.params(550.0)
        spec.append((r - rb) / (1 - rb))  # = E(theta)
    assert np.all(np.diff(spec) > 0), spec
    # counted by rays: the brightest reflected patch holds the mirror direction
    g = VirtualGoniophotometer("leaf:healthy,roughness=0.1", collector="equal-psa:9x36", rays=2_000_000, seed=3,
                               method="rays", wavelengths=[550.0])
    rec = g.measure_bsdf(45.0, 0.0)
    t = rec.table
    top = t[t.hemisphere == "R"].sort_values("value").iloc[-1]
    assert top.theta_min <= 45.0 <= top.theta_max and top.phi_min <= 180.0 <= top.phi_max


# --- extreme parameters ---------------------------------------------------------------------------


# the two roughness limits cost ~9 CPU-s each (the cuticle quadrature's finest order): make test-slow
@pytest.mark.parametrize("override", ["n=1", "n=3", "cab=0", "cw=0.05",
                                      *(pytest.param(o, marks=pytest.mark.slow) for o in ("roughness=0.0001", "roughness=1"))])
def test_extreme_parameters_stay_finite_and_in_range(override):
    s = parse_specimen(f"leaf:healthy,{override}")
    for w in (400.0, 550.0, 1450.0, 1940.0, 2500.0):
        a, eta, ks, rb, tb = s.params(w)
        assert 0 <= ks <= 1 and 0 <= rb <= 1 and 0 <= tb <= 1 and rb + tb <= 1 + 1e-12
        for theta in (0.0, 8.0, 60.0, 89.9):
            r, t = s.directional_rt(theta, w)
            assert 0 <= r <= 1 and 0 <= t <= 1 and r + t <= 1 + 1e-12
    wi = _direction(89.9)
    wo = np.stack([_direction(t, p) for t in (0.0, 30.0, 89.9, 90.1, 150.0) for p in (0.0, 90.0, 180.0)])
    f = s.bsdf(wi, wo, 550.0)
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    g = VirtualGoniophotometer(s, collector="equal-psa:6x12", rays=200_000, seed=4, method="rays",
                               wavelengths=[550.0, 1940.0])
    rec = g.measure_bsdf(89.9, 0.0)
    for tot in rec.meta["totals"]:
        assert 0 <= tot["reflectance"] <= 1 and 0 <= tot["transmittance"] <= 1 and tot["N"] == 200_000
    assert np.all(np.isfinite(rec.table.value))


# --- the fast path against ray counting -----------------------------------------------------------


def _bins(spec: str, method: str, seed: int) -> np.ndarray:
    g = VirtualGoniophotometer(spec, collector="equal-psa:9x36", rays=2_000_000, seed=seed, method=method,
                               wavelengths=[680.0])
    return g.simulate(40.0, 0.0, 680.0)[:-1]  # R patches, T patches, absorbed (missed = 0)


def test_fast_path_matches_ray_counting_and_the_test_has_power():
    # the suite's two-sample chi-square over 648 patches + absorbed, one comparison: a correct
    # fast path fails with probability 1e-3 (fixed seeds: the outcome is fixed too)
    rays = _bins("leaf:healthy", "rays", 21)
    fast = _bins("leaf:healthy", "fast", 22)
    assert rays.sum() == fast.sum() == 2_000_000
    assert two_sample_p(rays, fast) > 1e-3
    # power: the fast path of a slightly smoother cuticle (alpha 0.3 -> 0.26) is told apart
    assert two_sample_p(rays, _bins("leaf:healthy,roughness=0.26", "fast", 22)) < 1e-6


# --- colour and compare ---------------------------------------------------------------------------


def test_compare_of_two_leaves_reports_ciede2000_and_rejects_equality(tmp_path, capsys):
    paths = []
    for cab, seed in ((20, 1), (60, 2)):
        p = tmp_path / f"cab{cab}.csv"
        assert main(["spectro", "--specimen", f"leaf:healthy,cab={cab}", "--wavelengths", "400:700:10",
                     "--rays", "100000", "--seed", str(seed), "--csv", str(p)]) == 0
        paths.append(str(p))
    text = capsys.readouterr().out
    assert "colour (D65, 2 deg): R XYZ" in text
    assert main(["compare", *paths, "--out", str(tmp_path / "report"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    s = summary["candidates"]["cab60"]
    assert s["delta_e2000_mean"] > 3.0  # a visible difference of colour
    assert s["p_value"] < 1e-6  # equality rejected
