"""Uniformity of the emitter/specimen samplers (virtual/sampling.py; seed eqs. 3.3, 3.4, 3.10, 3.11).

Goodness of fit is Pearson's chi-square (scipy.stats.chisquare) against equal expected counts in
equal-area cells, at significance ALPHA = 1e-3 with fixed seeds: a uniform sampler passes each
check with probability 0.999. Equal-area cells of the disk of radius r are the annuli between
radii r*sqrt(k/K) (area pi r^2 / K each) and equal angular sectors; crossing them gives K*S
equal-area cells. The same checks fail for deliberately wrong samplers written in this file
(r*u without the square root, eq. 3.4 read as Cartesian, a triangle warp without the square
root), which shows the tests have power.

Stratified strategies (jittered, Sobol) produce *more* even counts than a multinomial, so their
chi-square statistic is small; the upper-tail test still applies (it rejects non-uniformity),
and their advantage is shown separately as a smaller estimation error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from bench.core.errors import InputError
from virtual.sampling import DISK_STRATEGIES, sample_disk, sample_triangle, uniforms
from virtual.kernels.warps import sincos_2pi

ALPHA = 1e-3
N = 16384  # 2^14: a power of two keeps Sobol's balance properties; 256 per cell below
K_ANNULI = 8
S_SECTORS = 8
# Points computed as rho*cos(phi), rho*sin(phi) with rho <= r can land a few ulps outside the
# circle by rounding; "inside" allows 8 ulps of relative error.
ULPS = 8 * np.finfo(float).eps


def _disk_cells(pts: np.ndarray, radius: float, k: int = K_ANNULI, s: int = S_SECTORS) -> np.ndarray:
    """Counts in the k*s equal-area cells: annulus index floor(k rho^2/r^2), sector floor(s phi/2pi)."""
    rho2 = (pts[:, 0] ** 2 + pts[:, 1] ** 2) / radius**2
    ring = np.minimum((rho2 * k).astype(int), k - 1)
    phi = np.mod(np.arctan2(pts[:, 1], pts[:, 0]), 2 * math.pi)
    sector = np.minimum((phi / (2 * math.pi) * s).astype(int), s - 1)
    return np.bincount(ring * s + sector, minlength=k * s)


def _gof_pvalue(counts: np.ndarray) -> float:
    return float(stats.chisquare(counts).pvalue)


def _inside_disk(pts: np.ndarray, radius: float) -> bool:
    return bool(np.all(np.hypot(pts[:, 0], pts[:, 1]) <= radius * (1 + ULPS)))


# --- the four disk strategies ------------------------------------------------------------------


@pytest.mark.parametrize("strategy", DISK_STRATEGIES)
@pytest.mark.parametrize("radius", [1.0, 0.0125])
def test_disk_strategies_are_uniform_in_annuli_and_sectors(strategy, radius):
    seed = 1000 + DISK_STRATEGIES.index(strategy) + (radius != 1.0)
    pts = sample_disk(N, radius, strategy, seed=seed)
    assert pts.shape == (N, 2) and _inside_disk(pts, radius)
    cells = _disk_cells(pts, radius)
    assert _gof_pvalue(cells.reshape(K_ANNULI, S_SECTORS).sum(axis=1)) > ALPHA  # annuli
    assert _gof_pvalue(cells.reshape(K_ANNULI, S_SECTORS).sum(axis=0)) > ALPHA  # sectors
    assert _gof_pvalue(cells) > ALPHA  # the 64 annulus x sector cells jointly


@pytest.mark.parametrize("strategy", DISK_STRATEGIES)
def test_disk_is_centred_and_isotropic(strategy):
    """Moments of the uniform disk: E[x] = E[y] = 0, E[x^2] = E[y^2] = r^2/4, E[xy] = 0.

    Under uniformity sd(x) = r/2, so the sample mean has standard error r/(2 sqrt N); sd(x^2)
    = r^2 sqrt(1/6 - 1/16) = 0.3227 r^2. Bounds are 4 standard errors (two-sided p ~ 6e-5).
    """
    r = 2.0
    pts = sample_disk(N, r, strategy, seed=77)
    se_mean = r / 2 / math.sqrt(N)
    se_sq = 0.3227 * r**2 / math.sqrt(N)
    assert abs(pts[:, 0].mean()) < 4 * se_mean and abs(pts[:, 1].mean()) < 4 * se_mean
    assert abs((pts[:, 0] ** 2).mean() - r**2 / 4) < 4 * se_sq
    assert abs((pts[:, 1] ** 2).mean() - r**2 / 4) < 4 * se_sq
    assert abs((pts[:, 0] * pts[:, 1]).mean()) < 4 * r**2 / 4 / math.sqrt(N)  # sd(xy) <= r^2/4


def test_sobol_disk_has_one_point_per_equal_area_annulus_and_sector():
    """Scrambled Sobol points form a (0, m, 2)-net in base 2: each coordinate alone puts exactly
    one of 2^m points in every interval [i/2^m, (i+1)/2^m). Through the polar warp u1 -> sector,
    u2 -> annulus of equal area, so with 1024 points each of 1024 annuli and each of 1024
    sectors holds exactly one point. (A point lying exactly on a cell edge could be moved
    across by rounding; with 30-bit Sobol values that has probability ~1e-3 for a seed.)"""
    m = 1024
    pts = sample_disk(m, 1.0, "sobol", seed=11)
    assert np.all(_disk_cells(pts, 1.0, k=m, s=1) == 1)
    assert np.all(_disk_cells(pts, 1.0, k=1, s=m) == 1)


def test_jittered_uniforms_fill_every_stratum_once():
    for n, a, b in ((64, 8, 8), (4096, 64, 64)):  # n = a*b: full stratification
        u = uniforms(n, "jittered", seed=5)
        cell = np.floor(u[:, 0] * a).astype(int) + a * np.floor(u[:, 1] * b).astype(int)
        assert np.all(np.bincount(cell, minlength=a * b) == 1)
    u = uniforms(60, "jittered", seed=6)  # 8 x 8 grid, 60 distinct cells
    cell = np.floor(u[:, 0] * 8).astype(int) + 8 * np.floor(u[:, 1] * 8).astype(int)
    assert len(np.unique(cell)) == 60


# --- the tests have power: wrong samplers fail them -----------------------------------------------


def _naive_polar_without_sqrt(n: int, r: float, rng: np.random.Generator) -> np.ndarray:
    u = rng.random((n, 2))
    rho = r * u[:, 1]  # wrong: needs r*sqrt(u2); density piles up at the centre
    phi = 2 * math.pi * u[:, 0]
    return np.column_stack((rho * np.cos(phi), rho * np.sin(phi)))


def _eq34_read_as_cartesian(n: int, r: float, rng: np.random.Generator) -> np.ndarray:
    u = rng.random((n, 2))
    return np.column_stack((2 * math.pi * u[:, 0], r * np.sqrt(u[:, 1])))  # (x, y) = (2 pi xi1, r sqrt xi2)


def test_annulus_test_rejects_the_naive_polar_mapping():
    pts = _naive_polar_without_sqrt(N, 1.0, np.random.default_rng(1))
    annuli = _disk_cells(pts, 1.0).reshape(K_ANNULI, S_SECTORS).sum(axis=1)
    # innermost annulus (rho < sqrt(1/8) = 0.354) gets 35% of points instead of 12.5%
    assert _gof_pvalue(annuli) < 1e-100
    assert _inside_disk(pts, 1.0)  # inside, yet wrong: only the distribution test catches it


def test_literal_eq34_as_cartesian_fails_containment_and_uniformity():
    pts = _eq34_read_as_cartesian(N, 1.0, np.random.default_rng(2))
    assert not _inside_disk(pts, 1.0)
    inside = pts[np.hypot(pts[:, 0], pts[:, 1]) <= 1.0]
    sectors = _disk_cells(inside, 1.0).reshape(K_ANNULI, S_SECTORS).sum(axis=0)
    assert _gof_pvalue(sectors) < ALPHA  # only the first quadrant is ever hit


# --- discrepancy advantage of jittered and Sobol ------------------------------------------------


def _area_fraction_rmse(sampler, n: int, seeds: range, truth: float, region) -> float:
    errs = [np.mean(region(sampler(n, seed))) - truth for seed in seeds]
    return float(np.sqrt(np.mean(np.square(errs))))


@pytest.mark.parametrize("strategy", DISK_STRATEGIES)
def test_stratified_strategies_estimate_area_better_than_random(strategy):
    """Fraction of the unit disk inside the disk of radius 1/2 centred at (0.3, 0.2) (wholly
    inside: 0.36 + 0.5 < 1), truth 1/4, estimated from n = 4096 points over 30 seeds.

    Independent points (rejection, polar) give an unbiased binomial estimate with standard error
    se = sqrt(p (1-p) / n); 30 squared errors / se^2 follow chi-square(30), whose 0.1% and 99.9%
    quantiles give RMSE/se in [0.62, 1.41]. Stratification removes the variance of all strata
    wholly inside or outside the region; only the O(sqrt n) strata crossed by its (warped)
    boundary contribute, each O(1/n^2), so the variance is O(n^-3/2) instead of O(1/n) --
    about 0.15 se here for jittered and Sobol. If they were no better than random,
    RMSE/se < 0.5 would have probability P(chi2_30 < 7.5) ~ 1e-5.
    """
    n, truth = 4096, 0.25
    se = math.sqrt(truth * (1 - truth) / n)

    def region(p: np.ndarray) -> np.ndarray:
        return (p[:, 0] - 0.3) ** 2 + (p[:, 1] - 0.2) ** 2 < 0.25

    rmse = _area_fraction_rmse(lambda n_, s: sample_disk(n_, 1.0, strategy, seed=s), n, range(30), truth, region)
    lo = math.sqrt(stats.chi2.ppf(ALPHA, 30) / 30)
    hi = math.sqrt(stats.chi2.ppf(1 - ALPHA, 30) / 30)
    if strategy in ("rejection", "polar"):
        assert lo * se < rmse < hi * se
    else:
        assert rmse < 0.5 * se


@pytest.mark.parametrize("strategy", ["jittered", "sobol"])
def test_stratified_triangle_estimates_area_better_than_random(strategy):
    """Same argument on the triangle: fraction of the unit right triangle below x + y = 1/sqrt 2
    is exactly 1/2 (area scales with the square of the size)."""
    n, truth = 4096, 0.5
    se = math.sqrt(truth * (1 - truth) / n)
    tri = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))

    def region(p: np.ndarray) -> np.ndarray:
        return p.sum(axis=1) < math.sqrt(0.5)

    rmse = _area_fraction_rmse(lambda n_, s: sample_triangle(n_, *tri, strategy=strategy, seed=s),
                               n, range(30), truth, region)
    rmse_random = _area_fraction_rmse(lambda n_, s: sample_triangle(n_, *tri, seed=s), n,
                                      range(30), truth, region)
    assert rmse_random > math.sqrt(stats.chi2.ppf(ALPHA, 30) / 30) * se  # the random baseline is honest
    assert rmse < 0.5 * se


# --- triangles (eqs. 3.10, 3.11) and the square specimen -----------------------------------------


def _barycentric(pts: np.ndarray, q0, q1, q2) -> np.ndarray:
    """(s, t) with q = q0 + s (q1 - q0) + t (q2 - q0)."""
    q0, q1, q2 = (np.asarray(q, dtype=float) for q in (q0, q1, q2))
    basis = np.column_stack((q1 - q0, q2 - q0))
    return np.linalg.solve(basis, (pts - q0).T).T


def _subtriangle_cells(st_: np.ndarray, levels: int) -> np.ndarray:
    """Counts in the 4^levels equal-area triangles of ``levels`` midpoint subdivisions.

    In barycentric coordinates the subdivision is the lattice of step 1/g (g = 2^levels): cell
    (i, j) = (floor(g s), floor(g t)) is split by its anti-diagonal into an upright triangle
    (frac sums < 1) and an inverted one; that gives g^2 equal-area triangles."""
    g = 2**levels
    s, t = st_[:, 0] * g, st_[:, 1] * g
    i, j = np.floor(s).astype(int), np.floor(t).astype(int)
    inverted = (s - i) + (t - j) >= 1.0
    # index upright and inverted cells with i + j < g (upright) / i + j < g - 1 (inverted)
    idx = (i * g + j) * 2 + inverted
    _, counts = np.unique(idx, return_counts=True)
    assert len(counts) == g * g  # every one of the g^2 cells is hit (n >> g^2)
    return counts


def _naive_triangle(n: int, q0, q1, q2, rng: np.random.Generator) -> np.ndarray:
    u = rng.random((n, 2))
    xp = u[:, 0]  # wrong: needs 1 - sqrt(1 - u3); x' uniform puts half the points in s > 1/2
    yp = (1 - xp) * u[:, 1]
    q0, q1, q2 = (np.asarray(q, dtype=float) for q in (q0, q1, q2))
    return q0 + xp[:, None] * (q1 - q0) + yp[:, None] * (q2 - q0)


TRIANGLE = ((0.2, -1.0), (3.0, 0.5), (-0.7, 2.2))


@pytest.mark.parametrize("strategy", ["random", "jittered", "sobol"])
def test_triangle_sampler_is_uniform_over_subtriangles(strategy):
    pts = sample_triangle(N, *TRIANGLE, strategy=strategy, seed=21)
    st_ = _barycentric(pts, *TRIANGLE)
    tol = 1e-12
    assert np.all(st_ >= -tol) and np.all(st_.sum(axis=1) <= 1 + tol)  # inside
    assert _gof_pvalue(_subtriangle_cells(st_, 1)) > ALPHA  # 4 midpoint triangles
    assert _gof_pvalue(_subtriangle_cells(st_, 3)) > ALPHA  # 64 triangles, 256 points each


def test_subtriangle_test_rejects_the_naive_triangle_warp():
    pts = _naive_triangle(N, *TRIANGLE, np.random.default_rng(3))
    st_ = _barycentric(pts, *TRIANGLE)
    assert np.all(st_ >= -1e-12) and np.all(st_.sum(axis=1) <= 1 + 1e-12)  # inside, but ...
    assert _gof_pvalue(_subtriangle_cells(st_, 1)) < 1e-100  # ... the q1 corner gets 1/2, not 1/4


def test_bad_arguments_raise_input_errors():
    with pytest.raises(InputError):
        sample_disk(10, 0.0)
    with pytest.raises(InputError):
        sample_disk(10, float("nan"))
    with pytest.raises(InputError):
        sample_disk(10, 1.0, "hexagonal")
    with pytest.raises(InputError):
        uniforms(-1)


def test_same_seed_same_points():
    for strategy in DISK_STRATEGIES:
        np.testing.assert_array_equal(sample_disk(100, 1.0, strategy, seed=9), sample_disk(100, 1.0, strategy, seed=9))


# --- properties for any radius and count ---------------------------------------------------------


@settings(max_examples=80, deadline=None)
@given(
    radius=st.floats(min_value=1e-6, max_value=1e6, allow_nan=False, allow_infinity=False),
    n=st.integers(min_value=0, max_value=2000),
    strategy=st.sampled_from(DISK_STRATEGIES),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_disk_points_always_inside(radius, n, strategy, seed):
    pts = sample_disk(n, radius, strategy, seed=seed)
    assert pts.shape == (n, 2) and np.all(np.isfinite(pts))
    assert _inside_disk(pts, radius)


@settings(max_examples=60, deadline=None)
@given(
    corners=st.lists(st.floats(min_value=-100, max_value=100, allow_nan=False), min_size=6, max_size=6),
    n=st.integers(min_value=0, max_value=2000),
    strategy=st.sampled_from(["random", "jittered", "sobol"]),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_triangle_points_always_inside(corners, n, strategy, seed):
    q0, q1, q2 = np.array(corners).reshape(3, 2)
    e1, e2 = q1 - q0, q2 - q0
    area2 = abs(e1[0] * e2[1] - e1[1] * e2[0])
    scale = max(1.0, float(np.abs(corners).max()))
    if area2 < 1e-3 * scale**2:  # nearly degenerate: barycentric coordinates are ill-conditioned
        return
    pts = sample_triangle(n, q0, q1, q2, strategy=strategy, seed=seed)
    assert pts.shape == (n, 2)
    if n:
        st_ = _barycentric(pts, q0, q1, q2)
        tol = 1e-9
        assert np.all(st_ >= -tol) and np.all(st_.sum(axis=1) <= 1 + tol)


def test_sincos_2pi_is_accurate_to_two_ulp_and_exact_at_quarter_turns():
    # Reference in 80-bit long double (x86-64), whose own error (~1e-19) is far below the bound.
    from virtual.kernels import jit

    @jit
    def both(u):
        c = np.empty_like(u)
        s = np.empty_like(u)
        for i in range(u.shape[0]):
            c[i], s[i] = sincos_2pi(u[i])
        return c, s

    rng = np.random.default_rng(4)
    u = np.concatenate([rng.random(400_000), np.linspace(0.0, 1.0, 100_001)[:-1],
                        np.nextafter(np.array([0.125, 0.375, 0.625, 0.875, 1.0]), 0.0)])
    c, s = both(u)
    two_pi = np.longdouble("6.283185307179586476925286766559005768")
    ul = u.astype(np.longdouble) * two_pi
    assert np.max(np.abs(c - np.cos(ul))) <= 2.3e-16
    assert np.max(np.abs(s - np.sin(ul))) <= 2.3e-16
    cq, sq = both(np.array([0.0, 0.25, 0.5, 0.75]))
    np.testing.assert_array_equal(cq, [1.0, 0.0, -1.0, 0.0])
    np.testing.assert_array_equal(sq, [0.0, 1.0, 0.0, -1.0])
