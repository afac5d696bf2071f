"""compare/: alignment, statistics (hand-computed and against scipy/colour-science), consistency
of virtual records with themselves, and the physical checks.

Tolerances come from theory, and each check a correct model must pass has a false-alarm rate,
computed (not guessed) in ``test_the_stated_family_wise_rate_is_the_one_run``:
- chi-square p-values are uniform under the null: ``p > 1e-3`` fails with probability 1e-3
  (two such checks);
- the observed fraction of points with |z| <= 2 against compare's own band, nominal 0.9545
  +- 3 binomial standard errors: exact binomial tails 4.3e-3 for 324 points (both sides) and
  1.2e-2 for the 31 points of a spectrum (its lower side; the band is a normal approximation,
  wide of its nominal 2.7e-3 at so few points);
- the Bland-Altman bias within 3 standard errors: 2.7e-3;
- six physical checks of Lambertian records, each run at CHECK_ALPHA = 1e-3.
Family-wise (Bonferroni): FAMILY = 2.7e-2. The seeds are fixed, so the outcome is deterministic;
power: the same checks reject albedo 0.6 against 0.5 and doctored records (p < 1e-6).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sps

from bench.core.errors import InputError
from bench.core.records import Spectrum
from bench.core.records import BSDF_COLUMNS, BSDFRecord
from compare.align import NoOverlapError, QuantityMismatchError, align
from compare.checks import energy_conservation, isotropy, reciprocity
from compare.stats import (UncertaintyError, bland_altman, compare, delta_e2000, fraction_band, nominal_fraction,
                           rank)

RAYS = 200_000
CHECK_ALPHA = 1e-3  # level of the physical checks that a correct record must pass
FAMILY = 2.7e-2  # the module's family-wise false-alarm rate (computed in the test below)


# --- helpers -------------------------------------------------------------------------------


def spectrum(wl, r, *, std=None, quantity="reflectance", geometry="8/d", N=0, t=None):
    wl = np.asarray(wl, float)
    r = np.asarray(r, float)
    t = np.zeros_like(r) if t is None else np.asarray(t, float)
    meta = {"quantity": quantity, "specimen": "hand"}
    if std is not None:
        meta["reflectance_std"] = np.asarray(std, float)
    return Spectrum(geometry=geometry, wavelengths=wl, reflectance=r, transmittance=t,
                    reflectance_ci=np.column_stack([r, r]), transmittance_ci=np.column_stack([t, t]),
                    N=np.full(wl.shape, N, dtype=np.int64), seed=None, delta=0.05, meta=meta)


def bsdf(rows, meta=None):
    """rows: (wavelength, theta_i, phi_i, theta_r, phi_r, value, std)."""
    recs = []
    for w, ti, pi_, tr, pr, v, s in rows:
        recs.append({"wavelength_nm": w, "theta_i": ti, "phi_i": pi_, "theta_r": tr, "phi_r": pr,
                     "hemisphere": "R" if tr <= 90 else "T", "value": v, "std": s, "ci_lo": np.nan,
                     "ci_hi": np.nan, "theta_min": np.nan, "theta_max": np.nan, "phi_min": np.nan,
                     "phi_max": np.nan, "psa": np.nan, "count": np.nan, "N": 0})
    return BSDFRecord(pd.DataFrame(recs)[BSDF_COLUMNS], dict(meta or {}))


def no_nan(obj) -> bool:
    """True when no float anywhere in a nested summary is NaN or infinite."""
    if isinstance(obj, dict):
        return all(no_nan(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(no_nan(v) for v in obj)
    if isinstance(obj, float):
        return math.isfinite(obj)
    return True


@pytest.fixture(scope="module")
def gonio():
    from virtual.goniophotometer import VirtualGoniophotometer

    def measure(albedo: float, seed: int, theta_i: float = 30.0, phi_i: float = 0.0):
        g = VirtualGoniophotometer(f"lambert:albedo={albedo}", collector="equal-psa:9x36", rays=RAYS, seed=seed,
                                   method="rays")
        return g.measure_bsdf(theta_i, phi_i)

    return measure


@pytest.fixture(scope="module")
def spectro():
    from virtual.spectrophotometer import VirtualSpectrophotometer

    def measure(albedo: float, seed: int, wavelengths="400:700:10", rays=100_000):
        return VirtualSpectrophotometer(f"lambert:albedo={albedo}", rays=rays, seed=seed).measure("8/d", wavelengths)

    return measure


# --- hand-computed statistics ---------------------------------------------------------------


def test_tiny_spectrum_statistics_by_hand():
    actual = spectrum([450, 550, 650], [0.40, 0.50, 0.60])  # physical: no std of its own
    cand = spectrum([450, 550, 650], [0.41, 0.49, 0.63], std=[0.003, 0.004, 0.012])
    c = compare(actual, cand, instrument_uncertainty=0.005)
    s = c.summary
    d = np.array([0.01, -0.01, 0.03])
    u = np.sqrt(0.005 ** 2 + np.array([0.003, 0.004, 0.012]) ** 2)  # 0.0058310, 0.0064031, 0.013
    z = d / u
    chi2 = 0.0001 / 3.4e-5 + 0.0001 / 4.1e-5 + 0.0009 / 1.69e-4  # 10.705645
    assert s["n_points"] == 3
    assert s["mean_abs_discrepancy_pct"] == pytest.approx((2.5 + 2.0 + 5.0) / 3, rel=1e-9)
    assert s["rmse"] == pytest.approx(math.sqrt(11e-4 / 3), rel=1e-9)
    assert s["bias"] == pytest.approx(0.01, rel=1e-9)  # (0.01 - 0.01 + 0.03) / 3
    assert s["max_abs"] == pytest.approx(0.03, rel=1e-9)
    np.testing.assert_allclose(c.points.z.to_numpy(), z, rtol=1e-9)
    assert s["chi2"] == pytest.approx(chi2, rel=1e-9)
    assert s["dof"] == 3
    # chi-square with 3 dof in closed form: sf(x) = erfc(sqrt(x/2)) + sqrt(2x/pi) exp(-x/2)
    closed = math.erfc(math.sqrt(chi2 / 2)) + math.sqrt(2 * chi2 / math.pi) * math.exp(-chi2 / 2)
    assert s["p_value"] == pytest.approx(closed, rel=1e-9)
    assert s["p_value"] == pytest.approx(sps.chi2.sf(chi2, 3), rel=1e-12)
    assert s["fraction_within_uncertainty"] == pytest.approx(2 / 3)  # |z| = 1.71, 1.56, 2.31
    assert s["nominal_fraction"] == pytest.approx(sps.norm.cdf(2) - sps.norm.cdf(-2), rel=1e-12)
    sd = 0.02  # deviations from the bias 0, -0.02, 0.02: sqrt(8e-4 / 2)
    ba = s["bland_altman"]
    assert ba["bias"] == pytest.approx(0.01) and ba["sd"] == pytest.approx(sd)
    assert ba["lower"] == pytest.approx(0.01 - 1.96 * sd) and ba["upper"] == pytest.approx(0.01 + 1.96 * sd)
    assert s["uncertainty_model"] == {"instrument": 0.005, "kind": "absolute", "source": "given by the caller",
                                      "use_actual_std": True, "use_virtual_std": True}
    assert any("actual std missing for 3 of 3 points" in w for w in s["warnings"])
    assert no_nan(s)


def test_physical_records_get_the_seed_instrument_uncertainties():
    actual = spectrum([450, 550, 650], [0.40, 0.50, 0.60])
    c = compare(actual, spectrum([450, 550, 650], [0.41, 0.49, 0.63], std=[0, 0, 0]))
    assert c.uncertainty.instrument == 0.005 and c.uncertainty.kind == "absolute"
    np.testing.assert_allclose(c.points.z, [2.0, -2.0, 6.0])
    a = bsdf([(550, 30, 0, 10, 5, 0.2, np.nan), (550, 30, 0, 40, 5, 0.1, np.nan)])
    v = bsdf([(550, 30, 0, 10, 5, 0.201, 0.0), (550, 30, 0, 40, 5, 0.1, 0.0)], {"source": "virtual"})
    c = compare(a, v, match="nearest")
    assert c.uncertainty.kind == "relative" and c.uncertainty.instrument == 0.005
    np.testing.assert_allclose(c.points.u_combined, [0.001, 0.0005])  # 0.5 % of the actual value
    np.testing.assert_allclose(c.points.z, [1.0, 0.0], atol=1e-9)


def test_reference_zero_is_excluded_from_percent_and_counted():
    actual = spectrum([450, 550, 650, 750], [0.0, 0.5, 0.0, 0.2])
    cand = spectrum([450, 550, 650, 750], [0.01, 0.55, 0.0, 0.2], std=[0.01, 0.01, 0.01, 0.01])
    c = compare(actual, cand, instrument_uncertainty=0.0)
    s = c.summary
    assert s["n_reference_zero"] == 2
    assert s["mean_abs_discrepancy_pct"] == pytest.approx((10.0 + 0.0) / 2)
    assert c.points.rel_pct.isna().tolist() == [True, False, True, False]
    assert (c.points.rel_pct.isna() == c.points.reference_zero).all()
    assert s["n_both_zero"] == 1  # 650 nm: no information, no z
    assert s["dof"] == 3
    assert any("zero reference" in w for w in s["warnings"]) and any("zero in both" in w for w in s["warnings"])
    assert no_nan(s)
    every = compare(spectrum([450, 550], [0.0, 0.0]), spectrum([450, 550], [0.1, 0.0], std=[0.01, 0.01]),
                    instrument_uncertainty=0.0)
    assert every.summary["mean_abs_discrepancy_pct"] is None
    assert any("every reference value is zero" in w for w in every.summary["warnings"])


def test_missing_uncertainty_is_an_error_or_an_explicit_warning_never_nan():
    a = bsdf([(550, 30, 0, 10, 5, 0.2, np.nan), (550, 30, 0, 40, 5, 0.1, np.nan)])
    v = bsdf([(550, 30, 0, 10, 5, 0.21, np.nan), (550, 30, 0, 40, 5, 0.12, np.nan)])
    with pytest.raises(UncertaintyError, match="chi-square impossible"):
        compare(a, v, instrument_uncertainty=0.0, match="nearest")
    c = compare(a, v, instrument_uncertainty=0.0, match="nearest", allow_missing_uncertainty=True)
    s = c.summary
    assert s["chi2"] is None and s["p_value"] is None and s["fraction_within_uncertainty"] is None
    assert s["rmse"] == pytest.approx(math.sqrt((0.01 ** 2 + 0.02 ** 2) / 2))
    assert any("chi-square impossible" in w for w in s["warnings"])
    assert any("virtual std missing" in w for w in s["warnings"])
    assert s["n_no_uncertainty"] == 2
    assert (c.points.z_note == "no uncertainty").all()
    assert no_nan(s)


def test_bland_altman_and_band_helpers():
    ba = bland_altman(np.array([1.0, 2.0, 3.0]), np.array([1.5, 2.0, 3.1]))
    assert ba["bias"] == pytest.approx(0.2)
    assert ba["sd"] == pytest.approx(np.std([0.5, 0.0, 0.1], ddof=1))
    assert bland_altman(np.array([1.0]), np.array([2.0]))["lower"] is None
    assert nominal_fraction(1.0) == pytest.approx(0.682689492, rel=1e-8)
    lo, hi = fraction_band(2.0, 324)
    h = 3 * math.sqrt(0.9545 * 0.0455 / 324)
    assert lo == pytest.approx(0.9545 - h, abs=1e-4) and hi == pytest.approx(0.9545 + h, abs=1e-4)


# --- colour ---------------------------------------------------------------------------------


def _lab_by_definition(wl, values, illuminant="D65"):
    """CIELAB from CIE 015's definition, independent of compare.stats' path (colour-science's
    ASTM E308 weights): the reflectance interpolated linearly onto 1 nm, X = k sum S xbar R over
    the measured range with the 1 nm CIE 1931 tables, the white the same sums with R = 1, then
    the CIE 1976 formulas."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    ill = colour.SDS_ILLUMINANTS[illuminant]
    wl = np.asarray(wl, float)
    grid = np.arange(wl[0], wl[-1] + 0.5, 1.0)
    weights = np.interp(grid, ill.wavelengths, ill.values)[:, None] * cmfs[grid]  # S(l) xbar, ybar, zbar
    t = (weights * np.interp(grid, wl, values)[:, None]).sum(axis=0) / weights.sum(axis=0)  # X / Xn ...
    f = np.where(t > (6 / 29) ** 3, np.cbrt(t), t / (3 * (6 / 29) ** 2) + 4 / 29)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


# The two integrations (ASTM E308 10 nm weights against 1 nm sums of the linear interpolant) differ
# by up to 0.15 in a* on the steep spectra below: Lab agrees within LAB_TOL and CIEDE2000 within
# 1 %, while an illuminant mixed up (A for D65) moves Lab by 3 to 7 units.
LAB_TOL = 0.3


def test_ciede2000_against_colour_science_and_physics():
    import colour

    wl = np.arange(400, 701, 10.0)
    red = 0.2 + 0.5 / (1 + np.exp(-(wl - 580) / 15))
    redder = 0.2 + 0.55 / (1 + np.exp(-(wl - 590) / 15))
    res = delta_e2000(wl, red, redder)
    expected = float(colour.delta_E(_lab_by_definition(wl, red), _lab_by_definition(wl, redder), method="CIE 2000"))
    assert res["delta_e2000"] == pytest.approx(expected, rel=0.01)
    np.testing.assert_allclose(res["lab_actual"], _lab_by_definition(wl, red), atol=LAB_TOL)
    np.testing.assert_allclose(res["lab_virtual"], _lab_by_definition(wl, redder), atol=LAB_TOL)
    assert np.abs(np.subtract(res["lab_actual"], _lab_by_definition(wl, red, "A"))).max() > 10 * LAB_TOL  # power
    assert res["delta_e2000"] > 1.0  # a visible difference
    # a flat 0.5 spectrum is neutral grey: L* = 116 * 0.5^(1/3) - 16, a* = b* = 0
    lab = delta_e2000(wl, np.full(wl.size, 0.5), np.full(wl.size, 0.5))["lab_actual"]
    assert lab[0] == pytest.approx(116 * 0.5 ** (1 / 3) - 16, abs=1e-6)
    assert abs(lab[1]) < 1e-9 and abs(lab[2]) < 1e-9
    # Sharma, Wu & Dalal (2005) test pair 1: the method string selects CIEDE2000
    assert float(colour.delta_E([50, 2.6772, -79.7751], [50, 0, -82.7485], method="CIE 2000")) == \
        pytest.approx(2.0425, abs=1e-4)
    # through compare(): per channel and mean, under a chosen illuminant
    c = compare(spectrum(wl, red), spectrum(wl, redder, std=np.full(wl.size, 0.002)), illuminant="A")
    expected_a = float(colour.delta_E(_lab_by_definition(wl, red, "A"), _lab_by_definition(wl, redder, "A"),
                                      method="CIE 2000"))
    assert c.summary["delta_e2000_mean"] == pytest.approx(expected_a, rel=0.01)
    assert c.summary["colour"]["illuminant"] == "A"
    # a spectrum over the full 360-780 nm uses the tabulated white point of the illuminant: a flat
    # one is grey to the 4 decimals of that white's chromaticity
    full = np.arange(360, 781, 5.0)
    lab_full = delta_e2000(full, np.full(full.size, 0.3), np.full(full.size, 0.3))["lab_actual"]
    np.testing.assert_allclose(lab_full, _lab_by_definition(full, np.full(full.size, 0.3)), atol=0.01)


# --- alignment ------------------------------------------------------------------------------


def test_wavelength_interpolation_is_linear_and_recorded():
    actual = spectrum([380, 450, 500], [0.3, 0.3, 0.3])
    cand = spectrum([400, 500], [0.2, 0.4], std=[0.01, 0.02])
    al = align(actual, cand)
    p = al.pairs.set_index("wavelength_nm")
    assert p.loc[450, "virtual_value"] == pytest.approx(0.3)
    assert p.loc[450, "virtual_std"] == pytest.approx(math.sqrt(0.25 * 0.01 ** 2 + 0.25 * 0.02 ** 2))
    assert p.loc[450, "wavelength_method"] == "linear" and p.loc[500, "wavelength_method"] == "match"
    um = al.unmatched[al.unmatched.side == "actual"]
    assert um.wavelength_nm.tolist() == [380.0]
    assert "outside the candidate's range 400-500 nm" in um.reason.iloc[0]
    assert any("interpolated linearly" in w for w in al.warnings)
    # within the tolerance a nearby wavelength is taken as is
    al2 = align(spectrum([500.3], [0.3]), cand, wavelength_tol_nm=0.5)
    assert al2.pairs.wavelength_method.tolist() == ["match"] and al2.pairs.virtual_value.iloc[0] == 0.4


def test_nearest_direction_matching_reports_what_it_cannot_match():
    cand = bsdf([(550, 30, 0, 10, 5, 0.2, 0.01), (550, 30, 0, 40, 95, 0.1, 0.01), (550, 60, 0, 10, 5, 0.3, 0.01)])
    actual = bsdf([(550, 30.2, 0, 10.3, 5.5, 0.21, 0.01),   # 0.2 deg incidence, ~0.3 deg view: matched
                   (550, 30, 0, 40, 90, 0.1, 0.01),         # nearest candidate 3.8 deg away
                   (550, 45, 0, 10, 5, 0.1, 0.01)])          # no incidence within 1 deg
    al = align(actual, cand, angle_tol_deg=1.0, match="nearest")
    assert len(al.pairs) == 1 and al.pairs.virtual_value.iloc[0] == 0.2
    assert al.pairs.angle_distance_deg.iloc[0] < 1.0
    um = al.unmatched[al.unmatched.side == "actual"].set_index("theta_r")
    assert "no candidate direction within 1 deg" in um.loc[40.0, "reason"]
    assert "no candidate incidence within 1 deg of (45, 0)" in um.loc[10.0, "reason"]
    unused = al.unmatched[al.unmatched.side == "candidate"]
    assert unused.theta_i.tolist() == [60.0]  # the candidate incidence nobody used is named


def test_patch_lookup_puts_each_direction_in_exactly_one_patch(gonio):
    cand = gonio(0.5, 11)
    rng = np.random.default_rng(5)
    n = 300
    theta = np.degrees(np.arccos(rng.uniform(0, 1, n)))
    theta[:3] = [0.0, 90.0, 19.47122063449069]  # pole, horizon, a ring boundary
    phi = rng.uniform(0, 360, n)
    phi[3:6] = [0.0, 10.0, 359.999]  # sector boundaries
    actual = bsdf([(550, 30, 0, t, p, 0.16, 0.001) for t, p in zip(theta, phi)])
    al = align(actual, cand)
    assert al.meta["match_method"] == "patch" and len(al.pairs) == n and al.unmatched.side.eq("actual").sum() == 0
    tab = cand.table
    for r in al.pairs.itertuples():
        in_theta = (tab.theta_min <= r.theta_r) & ((r.theta_r < tab.theta_max)
                                                   | ((tab.theta_max == 90) & (r.theta_r == 90)))
        in_phi = (r.phi_r - tab.phi_min) % 360 < (tab.phi_max - tab.phi_min)
        inside = (tab.hemisphere == "R") & in_theta & in_phi
        assert int(inside.sum()) == 1, (r.theta_r, r.phi_r)
        assert tab.index[inside][0] == r.virtual_index
        assert r.virtual_value == tab.value[r.virtual_index]


def test_no_overlap_and_mismatched_quantities_are_clear_errors(gonio):
    a = spectrum([400, 410], [0.5, 0.5])
    with pytest.raises(NoOverlapError, match="outside the candidate's range 500-600 nm"):
        align(a, spectrum([500, 600], [0.5, 0.5]))
    with pytest.raises(QuantityMismatchError, match="'reflectance factor'"):
        align(spectrum([400], [0.5], quantity="reflectance factor", geometry="45/0"),
              spectrum([400], [0.5], geometry="45/0"))
    with pytest.raises(QuantityMismatchError, match="geometry mismatch"):
        align(spectrum([400], [0.5]), spectrum([400], [0.5], geometry="0/d"))
    rec = gonio(0.5, 1)
    with pytest.raises(QuantityMismatchError, match="cannot compare a spectrum record with a bsdf record"):
        align(spectrum([550], [0.5]), rec)
    rf = BSDFRecord(rec.table, {**rec.meta, "quantity": "reflectance factor"})
    with pytest.raises(QuantityMismatchError, match="BRDF vs reflectance factor"):
        align(rf, rec)
    with pytest.raises(NoOverlapError, match="no candidate incidence within 1 deg of \\(60, 0\\)"):
        align(gonio(0.5, 2, theta_i=60.0), rec)
    assert issubclass(NoOverlapError, InputError) and issubclass(QuantityMismatchError, InputError)


def test_a_hemisphere_zero_in_the_actual_is_still_compared_when_the_candidate_is_not(gonio):
    opaque = gonio(0.5, 1)
    t = gonio(0.5, 2).table.copy()
    leak = t.hemisphere == "T"
    t.loc[leak, "value"] = 0.05  # a candidate that predicts transmission the actual did not see
    t.loc[leak, "std"] = 0.005
    al = align(opaque, BSDFRecord(t, {"source": "virtual"}))
    assert al.meta["channels"] == ["R", "T"]
    c = compare(opaque, BSDFRecord(t, {"source": "virtual"}))
    assert c.summary["n_reference_zero"] == 324 and c.summary["p_value"] < 1e-10
    # both zero in T: nothing to learn there, so the hemisphere is left out and said so
    assert align(opaque, gonio(0.5, 2)).meta["channels"] == ["R"]


def test_compare_package_imports_lazily_and_never_virtual():
    import ast
    import pathlib
    import subprocess
    import sys

    code = "import sys, compare; assert 'compare.report' not in sys.modules; compare.compare_records; " \
           "assert not [m for m in sys.modules if m.startswith(('virtual', 'drivers'))], 'virtual imported'"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=pathlib.Path(__file__).parents[1])
    for f in pathlib.Path(__file__).parents[1].joinpath("compare").glob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                assert not any(n.split(".")[0] in ("virtual", "drivers") for n in names), (f, names)


def test_the_stated_family_wise_rate_is_the_one_run():
    p = nominal_fraction(2.0)
    lo, hi = fraction_band(2.0, 324)
    band_324 = sps.binom.cdf(math.ceil(lo * 324) - 1, 324, p) + sps.binom.sf(math.floor(hi * 324), 324, p)
    band_31 = sps.binom.cdf(math.ceil(fraction_band(2.0, 31)[0] * 31) - 1, 31, p)  # lower side only
    rates = [1e-3, 1e-3, band_324, band_31, 2 * sps.norm.sf(3)] + [CHECK_ALPHA] * 6
    assert band_324 == pytest.approx(4.3e-3, abs=0.05e-3) and band_31 == pytest.approx(1.23e-2, abs=0.05e-2)
    assert sum(rates) == pytest.approx(FAMILY, abs=0.05e-2)


# --- virtual against virtual ----------------------------------------------------------------


def test_same_specimen_different_seeds_is_consistent(gonio, spectro):
    c = compare(gonio(0.5, 1), gonio(0.5, 2))
    s = c.summary
    assert s["n_points"] == 324 and s["n_unmatched"] == 0  # reflection hemisphere (the actual has no T)
    assert s["uncertainty_model"]["instrument"] == 0.0  # a virtual actual carries its own MC std
    assert s["p_value"] > 1e-3
    lo, hi = s["fraction_band"]
    assert lo <= s["fraction_within_uncertainty"] <= hi
    assert abs(s["bland_altman"]["bias"]) < 3 * s["bland_altman"]["sd"] / math.sqrt(s["n_points"])
    by_wl, by_inc = c.by_wavelength, c.by_incidence
    assert by_wl.n_points.tolist() == [324] and by_inc.n_points.tolist() == [324]
    assert by_inc.chi2.iloc[0] == pytest.approx(s["chi2"])
    sp = compare(spectro(0.5, 1), spectro(0.5, 2))
    assert len(sp.by_wavelength) == 31 and (sp.by_wavelength.n_points == 1).all()
    assert sp.summary["p_value"] > 1e-3
    assert sp.summary["fraction_band"][0] <= sp.summary["fraction_within_uncertainty"]
    # colour difference of two noisy greys is far below a just-noticeable difference
    assert sp.summary["delta_e2000_mean"] < 0.5


def test_different_specimen_is_flagged(gonio, spectro):
    s = compare(gonio(0.5, 1), gonio(0.6, 3)).summary
    assert s["p_value"] < 1e-10
    assert s["fraction_within_uncertainty"] < s["fraction_band"][0]
    assert s["bias"] == pytest.approx(0.1 / math.pi, rel=0.1)  # albedo 0.6 vs 0.5: BRDF + 0.1/pi
    sp = compare(spectro(0.5, 1), spectro(0.6, 3)).summary
    assert sp["p_value"] < 1e-10 and sp["delta_e2000_mean"] > 3


def test_ranking_orders_candidates_by_the_primary_metric(gonio):
    actual = gonio(0.5, 1)
    summaries = {name: compare(actual, rec).summary for name, rec in
                 (("albedo 0.6", gonio(0.6, 3)), ("albedo 0.5", gonio(0.5, 2)), ("albedo 0.55", gonio(0.55, 4)))}
    r = rank(summaries, "chi2_per_dof")
    assert [x["name"] for x in r] == ["albedo 0.5", "albedo 0.55", "albedo 0.6"]
    assert [x["rank"] for x in r] == [1, 2, 3]
    assert r[0]["mean_abs_discrepancy_pct"] is not None and r[0]["primary"] == "chi2_per_dof"
    r2 = rank(summaries, "mean_abs_discrepancy_pct")
    assert r2[0]["name"] == "albedo 0.5"
    r3 = rank(summaries, "delta_e2000_mean")  # BSDF: not available, so unranked with a note
    assert all(x["rank"] is None and "not available" in x["note"] for x in r3)
    with pytest.raises(InputError, match="primary metric"):
        rank(summaries, "p_value")


# --- physical checks ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def multi(gonio):
    recs = [gonio(0.5, 7, theta_i=t) for t in (0.0, 24.0, 45.0, 60.0)]
    return BSDFRecord(pd.concat([r.table for r in recs], ignore_index=True), dict(recs[0].meta))


def test_checks_pass_on_a_lambertian_record(multi):
    rec = reciprocity(multi, alpha=CHECK_ALPHA)
    assert rec.tested and rec.passed and rec.n == 6  # every pair of 4 incidences
    assert {"f_12", "f_21", "z"} <= set(rec.evidence.columns)
    en = energy_conservation(multi, alpha=CHECK_ALPHA)
    assert en.tested and en.passed and en.n == 4
    assert en.evidence.albedo.to_numpy() == pytest.approx(0.5, abs=0.01)
    assert en.evidence.psa_R.to_numpy() == pytest.approx(math.pi)  # full hemisphere coverage
    iso = isotropy(multi, alpha=CHECK_ALPHA)
    assert iso.tested and iso.passed and (iso.evidence.test == "mirror").all()
    assert iso.n == 4 * 9 * 18  # 9 rings x 18 mirrored sector pairs per incidence; T is zero in both


def test_checks_flag_doctored_records(multi, gonio):
    t = multi.table.copy()
    t.loc[t.theta_i == 45.0, ["value", "std"]] *= 1.5
    r = reciprocity(BSDFRecord(t, multi.meta), alpha=CHECK_ALPHA)
    assert not r.passed and r.p_value < 1e-6 and len(r.offending) > 0
    t = multi.table.copy()
    t[["value", "std"]] *= 2.2  # albedo 1.1
    e = energy_conservation(BSDFRecord(t.drop(columns=["count"]), {}), instrument_uncertainty=0.005,
                            alpha=CHECK_ALPHA)
    assert not e.passed and len(e.offending) == 4 and e.evidence.u_method.iloc[0] == "sum of patch std"
    single = gonio(0.5, 8)
    t = single.table.copy()
    t.loc[(t.phi_r > 0) & (t.phi_r < 180), "value"] *= 1.2  # one side of the plane brighter
    i = isotropy(BSDFRecord(t, single.meta), alpha=CHECK_ALPHA)
    assert not i.passed and i.max_z > 3
    # rotation test: the same theta_i at two phi_i
    rot = BSDFRecord(pd.concat([single.table, gonio(0.5, 9, phi_i=90.0).table], ignore_index=True), single.meta)
    ri = isotropy(rot, alpha=CHECK_ALPHA)
    assert ri.passed and (ri.evidence.test == "rotation").all() and ri.n == 324


def test_isotropy_detects_an_anisotropic_specimen():
    from virtual.goniophotometer import VirtualGoniophotometer

    def rec(spec, phi_i):
        return VirtualGoniophotometer(spec, rays=500_000, seed=1, method="rays").measure_bsdf(45.0, phi_i)

    aniso = "aniso-ggx:alpha_x=0.15,alpha_y=0.5"
    bad = isotropy(rec(aniso, 30.0), alpha=CHECK_ALPHA)  # plane of incidence not a symmetry plane of the specimen
    assert not bad.passed and bad.p_value < 1e-10 and len(bad.offending) > 10
    # with the plane of incidence along the specimen's X axis the mirror test cannot see it (documented)
    assert isotropy(rec(aniso, 0.0), alpha=CHECK_ALPHA).passed
    assert isotropy(rec("ggx:alpha=0.3", 30.0), alpha=CHECK_ALPHA).passed


def test_checks_say_when_there_is_nothing_to_test(gonio):
    r = reciprocity(gonio(0.5, 1))
    assert r.passed and not r.tested and "no reciprocal pairs" in r.message
    e = energy_conservation(bsdf([(550, 30, 0, 10, 5, 0.2, 0.01)]))
    assert not e.tested and "psa" in e.message
