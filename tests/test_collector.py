"""Collector sphere: patch geometry (equal-PSA acceptance facts) and the exact lookup."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from virtual.kernels import jit

from bench.core.errors import InputError
from virtual.kernels.patch_lookup import ATAN_MAX_ERROR, _approx_phi, guess_bin, patch_of
from virtual.collector import SCHEMES, Collector, parse_collector


# --- geometry -----------------------------------------------------------------------------------


def test_equal_psa_9_rings_acceptance():
    c = Collector("equal-psa", 9, 36)
    k = np.arange(10)
    np.testing.assert_allclose(c.theta_edges, np.arcsin(np.sqrt(k / 9)), rtol=0, atol=1e-15)
    assert c.theta_edges[0] == 0.0 and c.theta_edges[-1] == math.pi / 2
    np.testing.assert_allclose(c.psa, math.pi / (9 * 36), rtol=1e-13)
    assert c.psa.shape == (2 * 9 * 36,)
    # each hemisphere sums to pi
    assert c.psa[: c.n_patches].sum() == pytest.approx(math.pi, rel=1e-13)
    assert c.psa[c.n_patches:].sum() == pytest.approx(math.pi, rel=1e-13)
    assert c.n_patches == 324 and c.n_bins == 648


@pytest.mark.parametrize("scheme", list(SCHEMES))
@pytest.mark.parametrize("n_theta,n_phi", [(1, 1), (9, 36), (18, 36), (30, 7)])
def test_psa_and_solid_angle_sum_and_closed_forms(scheme, n_theta, n_phi):
    c = Collector(scheme, n_theta, n_phi)
    up = slice(0, c.n_patches)
    assert c.psa[up].sum() == pytest.approx(math.pi, rel=1e-12)
    assert c.solid_angle[up].sum() == pytest.approx(2 * math.pi, rel=1e-12)
    # PSA = dphi/2 (cos^2 tb - cos^2 te), evaluated independently from the theta edges
    t = c.theta_edges
    ring = (math.pi / n_phi) * (np.cos(t[:-1]) ** 2 - np.cos(t[1:]) ** 2)
    np.testing.assert_allclose(c.ring_psa, ring, rtol=1e-10, atol=1e-15)
    if scheme == "equal-solid-angle":
        np.testing.assert_allclose(c.solid_angle, 2 * math.pi / (n_theta * n_phi), rtol=1e-12)
    if scheme == "equal-angle":
        np.testing.assert_allclose(np.diff(c.theta_edges_deg), 90.0 / n_theta, rtol=1e-12)
    # centres are unit vectors inside their own bins
    np.testing.assert_allclose(np.linalg.norm(c.centres, axis=1), 1.0, rtol=1e-14)
    np.testing.assert_array_equal(c.index(c.centres), np.arange(c.n_bins))


def test_describe_and_parse():
    c = parse_collector("equal-psa:9x36")
    assert c == Collector("equal-psa", 9, 36)
    d = c.describe()
    assert d["scheme"] == "equal-psa" and d["n_theta"] == 9 and d["n_phi"] == 36
    assert d["n_patches"] == 324 and d["hemisphere_psa"] == pytest.approx(math.pi)
    assert len(d["theta_edges_deg"]) == 10 and d["horizon"] == "upper"
    assert parse_collector(" Equal-Angle : 18X36 ").scheme == "equal-angle"


@pytest.mark.parametrize("bad", ["", "equal-psa", "equal-psa:9", "equal-psa:0x36", "equal-psa:9x0",
                                 "equal-psi:9x36", "equal-psa:9x36x2", "equal-psa:-9x36", "9x36"])
def test_parse_collector_rejects_bad_text(bad):
    with pytest.raises(InputError):
        parse_collector(bad)


def test_collector_rejects_bad_counts():
    with pytest.raises(InputError, match="n_theta"):
        Collector("equal-psa", 0, 36)
    with pytest.raises(InputError, match="n_phi"):
        Collector("equal-psa", 9, 2.5)  # type: ignore[arg-type]


# --- lookup edge cases ----------------------------------------------------------------------------

C = Collector("equal-psa", 9, 36)
NP = C.n_patches


def idx(x, y, z, c: Collector = C) -> int:
    return int(c.index(np.array([[x, y, z]]))[0])


@pytest.mark.parametrize("scheme", list(SCHEMES))
def test_pole(scheme):
    c = Collector(scheme, 9, 36)
    # x = y = 0: atan2(0, -0.0) = pi would put a naive lookup in sector 18; we document sector 0
    for x, y in [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0)]:
        assert idx(x, y, 1.0, c) == 0
        assert idx(x, y, -1.0, c) == c.n_patches
    # |z| rounding past 1 (acos(1 + 1e-16) is NaN -> a naive acos-based lookup crashes or
    # returns garbage); here only the ratio matters
    assert idx(0.0, 0.0, 1.0 + 2.2e-16, c) == 0
    assert idx(1e-9, 0.0, 1.0 + 2.2e-16, c) == 0
    assert idx(0.0, 0.0, -(1.0 + 2.2e-16), c) == c.n_patches


def test_horizon():
    # z = 0 and z = -0.0 both count as the upper hemisphere's outermost ring (documented);
    # a naive `z > 0` test would send z = +0.0 to T, a sign-bit test would send -0.0 to T.
    assert idx(1.0, 0.0, 0.0) == 8 * 36
    assert idx(1.0, 0.0, -0.0) == 8 * 36
    assert idx(0.0, 1.0, 0.0) == 8 * 36 + 9
    # just below the horizon: outermost ring of T
    assert idx(1.0, 0.0, -1e-300) == NP + 8 * 36
    # sin^2 theta that would round past 1 for a naive (x^2+y^2) on an unnormalised vector
    assert idx(3.0, 4.0, 0.0) == 8 * 36 + int(math.atan2(4, 3) / (2 * math.pi / 36))


def test_phi_wraps_to_last_sector():
    # phi = atan2(-tiny, 1) + 2 pi rounds to exactly 2 pi: floor(phi / dphi) = n_phi, one past
    # the end (a naive lookup writes into the next ring's sector 0 or out of bounds)
    assert idx(1.0, -1e-300, 0.5) == 35 + 36 * int(9 * 0.8)  # sin^2 = 1/1.25 = 0.8 -> ring 7
    assert idx(1.0, -1e-17, 1.0) < 36 * 9
    assert idx(1.0, -1e-17, 1.0) % 36 == 35
    # phi exactly 0 with y = -0.0: atan2(-0.0, 1) = -0.0, must stay in sector 0, not 35
    assert idx(1.0, -0.0, 1.0) % 36 == 0
    # phi = pi from y = +0.0 and from y = -0.0 (atan2 = -pi then +2 pi = pi)
    assert idx(-1.0, 0.0, 1.0) % 36 == 18
    assert idx(-1.0, -0.0, 1.0) % 36 == 18
    # quarter-turn edges are exact: (0, 1) is phi = 90 deg -> first sector of the second quarter
    assert idx(0.0, 1.0, 1.0) % 36 == 9 and idx(-1e-300, 1.0, 1.0) % 36 == 9
    assert idx(1e-300, 1.0, 1.0) % 36 == 8
    assert idx(0.0, -1.0, 1.0) % 36 == 27


@pytest.mark.parametrize("n_phi", [1, 2, 3, 4, 5, 36, 1000])
def test_sector_partition_small_and_large_n_phi(n_phi):
    c = Collector("equal-psa", 3, n_phi)
    a = (np.arange(20000) + 0.5) * (2 * np.pi / 20000)  # never on an edge for these n_phi
    d = np.column_stack([np.cos(a), np.sin(a), np.full_like(a, 0.5)])
    sec = c.index(d) % n_phi
    assert sec.min() >= 0 and sec.max() < n_phi
    assert np.all(np.diff(sec) >= 0)  # monotone in phi: a cross-product test that picked the
    # antipodal half-plane (n_phi = 2, sectors >= pi wide) would jump back
    expected = np.minimum((a / (2 * np.pi / n_phi)).astype(int), n_phi - 1)
    np.testing.assert_array_equal(sec, expected)


def _subnormals_work() -> bool:
    return bool((np.array([5e-324]) * 2.0)[0] > 0.0)


def test_unnormalised_and_degenerate_vectors():
    d = np.array([0.3, -0.2, 0.7])
    ref = idx(*d)
    for scale in (1e-300, 1e-170, 1e-20, 1.0, 1e20, 1e170, 1e300):
        # 1e-170**2 underflows to 0 (naive: pole); 1e170**2 overflows to inf (naive: NaN)
        assert idx(*(d * scale)) == ref, scale
    assert idx(0.0, 0.0, 0.0) == 0
    assert idx(math.nan, 0.0, 1.0) in range(C.n_bins)
    assert idx(math.inf, 1.0, 1.0) in range(C.n_bins)
    if _subnormals_work():  # some libraries switch on flush-to-zero/denormals-are-zero at import
        assert idx(5e-324, 5e-324, 5e-324) == idx(1.0, 1.0, 1.0)  # 1/5e-324 = inf: must divide
    else:
        assert idx(5e-324, 5e-324, 5e-324) in range(C.n_bins)
    assert idx(math.inf, 0.0, 0.0) == idx(1.0, 0.0, 0.0)
    assert idx(0.0, 0.0, -math.inf) == C.n_patches


def test_exact_boundaries_follow_stored_edges():
    # a direction exactly on a ring edge goes to the outer ring (edges are [tb, te))
    c = Collector("equal-psa", 4, 4)
    # sin^2 = 1/4 exactly: x = 1, y = 0, z = sqrt(3) has rho2/r2 = 1/4 in floating point
    assert 1.0 / (1.0 + 3.0) == 0.25
    assert idx(1.0, 0.0, math.sqrt(3.0), c) in (4, 0)  # rounding of sqrt(3)^2 decides, never 8
    assert idx(1.0, 0.0, 1.0, c) == 2 * 4  # sin^2 = 1/2 exactly: ring 2
    # equal-angle and equal-solid-angle with their closed-form guesses off by one are corrected
    for scheme in ("equal-angle", "equal-solid-angle"):
        cc = Collector(scheme, 90, 4)
        t = cc.theta_edges
        for k in range(1, 90):
            for eps, ring in ((-1e-9, k - 1), (1e-9, k)):
                th = t[k] + eps
                assert idx(math.sin(th), 0.0, math.cos(th), cc) == ring * 4


# --- property test: fast lookup == slow reference away from edges --------------------------------


def slow_reference(c: Collector, v: np.ndarray) -> int:
    x, y, z = (float(a) for a in v)
    theta = math.atan2(math.hypot(x, y), abs(z))  # mirrored zenith in [0, pi/2]
    phi = math.atan2(y, x) % (2 * math.pi)
    ring = int(np.searchsorted(c.theta_edges, theta, side="right") - 1)
    ring = min(ring, c.n_theta - 1)
    sector = min(int(np.searchsorted(c.phi_edges, phi, side="right") - 1), c.n_phi - 1)
    return ring * c.n_phi + sector + (c.n_patches if z < 0 else 0)


def near_edge(c: Collector, v: np.ndarray, tol: float = 1e-9) -> bool:
    x, y, z = v
    theta = math.atan2(math.hypot(x, y), abs(z))
    phi = math.atan2(y, x) % (2 * math.pi)
    return bool(np.min(np.abs(c.theta_edges - theta)) < tol or np.min(np.abs(c.phi_edges - phi)) < tol
                or math.hypot(x, y) < tol or abs(z) < tol)


COLLECTORS = [Collector(s, nt, npf) for s in SCHEMES for nt, npf in ((9, 36), (18, 7), (1, 3), (45, 72))]


@settings(max_examples=400, deadline=None)
@given(st.integers(0, len(COLLECTORS) - 1),
       st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False) for _ in range(3)]),
       st.floats(1e-3, 1e3))
def test_lookup_matches_slow_reference(ci, v, scale):
    c = COLLECTORS[ci]
    v = np.array(v) * scale
    if np.linalg.norm(v) < 1e-6 or near_edge(c, v / np.linalg.norm(v)):
        return
    assert idx(*v, c) == slow_reference(c, v)


def test_lookup_many_random_directions_matches_reference():
    rng = np.random.default_rng(12)
    d = rng.normal(size=(20000, 3))
    for c in COLLECTORS:
        got = c.index(d)
        assert got.min() >= 0 and got.max() < c.n_bins
        keep = [i for i in range(2000) if not near_edge(c, d[i] / np.linalg.norm(d[i]))]
        assert np.array_equal(got[keep], [slow_reference(c, d[i]) for i in keep])
        # uniform directions on the sphere: every bin's frequency ~ solid angle / 4 pi
        counts = np.bincount(got, minlength=c.n_bins)
        p = c.solid_angle / (4 * math.pi)
        assert p.sum() == pytest.approx(1.0)
        if c.n_bins <= 100:
            chi2 = float(np.sum((counts - len(d) * p) ** 2 / (len(d) * p)))
            from scipy.stats import chi2 as chi2_dist

            assert chi2_dist.sf(chi2, c.n_bins - 1) > 1e-4


@jit
def _kernel_use(dirs, scheme_code, n_theta, n_phi, sin2_edges, phi_cs):
    out = np.zeros(2 * n_theta * n_phi, dtype=np.int64)
    for i in range(dirs.shape[0]):
        out[patch_of(dirs[i, 0], dirs[i, 1], dirs[i, 2], scheme_code, n_theta, n_phi, sin2_edges, phi_cs)] += 1
    return out


def test_patch_of_inlines_into_other_kernels():
    rng = np.random.default_rng(3)
    d = rng.normal(size=(1000, 3))
    hist = _kernel_use(d, *C.kernel_args())
    np.testing.assert_array_equal(hist, np.bincount(C.index(d), minlength=C.n_bins))


# --- the branch-free guess of the block kernel -----------------------------------------------------


@jit(error_model="numpy")  # as compiled in the block kernel
def _guesses(dirs, scheme_code, n_theta, n_phi, ring_margin, sector_margin):
    out = np.empty(dirs.shape[0], dtype=np.int64)
    for i in range(dirs.shape[0]):
        out[i] = guess_bin(dirs[i, 0], dirs[i, 1], dirs[i, 2], scheme_code, n_theta, n_phi, ring_margin,
                           sector_margin)
    return out


def _edge_directions(c: Collector) -> np.ndarray:
    """Directions on and a few ulps around every ring and sector edge, poles, the horizon."""
    rng = np.random.default_rng(c.n_theta * 1000 + c.n_phi)
    t_mid = 0.5 * (c.theta_edges[1:] + c.theta_edges[:-1])
    p_mid = 0.5 * (c.phi_edges[1:] + c.phi_edges[:-1])
    rows = []
    for th in c.theta_edges:  # ring edges at random azimuths
        for d in (-4, -1, 0, 1, 4):
            t = th + d * np.spacing(max(th, 1e-300))
            ph = rng.choice(p_mid)
            rows.append((math.sin(t) * math.cos(ph), math.sin(t) * math.sin(ph), math.cos(t)))
    for ph in c.phi_edges:  # sector edges at random zeniths
        for d in (-4, -1, 0, 1, 4):
            p = ph + d * np.spacing(max(ph, 1e-300))
            t = rng.choice(t_mid)
            rows.append((math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)))
    rows += [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1e-300, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, -1e-300, 1.0),
             (1.0, -0.0, 0.5), (1e200, 1e200, 1e200), (1e-200, 1e-200, 1e-200), (0.0, 0.0, 0.0)]
    d = np.array(rows)
    return np.vstack([d, d * [1.0, 1.0, -1.0]])


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("n_theta, n_phi", [(1, 1), (2, 2), (9, 36), (30, 30), (90, 360), (1000, 3600)])
def test_guess_bin_is_patch_of_whenever_it_is_sure(scheme, n_theta, n_phi):
    # The guess may decline (-1) but must never disagree with the exact lookup: checked on
    # 200,000 random directions and on directions on and a few ulps around every edge.
    c = Collector(scheme, n_theta, n_phi)
    rng = np.random.default_rng(n_theta + n_phi)
    for d in (rng.normal(size=(200_000, 3)), _edge_directions(c)):
        g = _guesses(d, c.scheme_code, c.n_theta, c.n_phi, *c.guess_margins())
        sure = g >= 0
        np.testing.assert_array_equal(g[sure], c.index(d[sure]))
    # and it declines rarely: on random directions at most 2 (margins) x edges per ray, < 1e-3 here
    g = _guesses(rng.normal(size=(200_000, 3)), c.scheme_code, c.n_theta, c.n_phi, *c.guess_margins())
    assert np.mean(g < 0) < 1e-3


def test_polynomial_atan_is_within_its_stated_error():
    @jit
    def phis(x, y):
        out = np.empty(x.shape[0])
        for i in range(x.shape[0]):
            out[i] = _approx_phi(x[i], y[i])
        return out

    a = np.linspace(0.0, 2 * math.pi, 2_000_001)[:-1]
    got = phis(np.cos(a), np.sin(a))
    ref = np.arctan2(np.sin(a), np.cos(a)) % (2 * math.pi)
    err = np.abs(got - ref)
    err = np.minimum(err, 2 * math.pi - err)  # 0 and 2 pi are the same azimuth
    assert err.max() < ATAN_MAX_ERROR
