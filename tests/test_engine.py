"""The ray engine: per-ray accounting, determinism whatever the thread count, beams."""

import math

import numpy as np
import pytest

from bench.core.errors import GeometryError, InputError
from virtual.beam import Beam, rotation_to
from virtual.engine import chunking, measurement_seed, spectro_counts
from tests.helpers.kernels import kernel_counts, on_one_and_all_threads
from tests.helpers.stats import family_rate, two_sample_p, z_two_sided
from virtual.specimens import Lambertian


def _count(specimen, beam, n, seed=1, theta=8.0, wl=550.0):
    return spectro_counts(specimen.model, specimen.params(wl), beam.code, beam.disk_code,
                          beam.kernel_args(theta, 0.0), n, measurement_seed(seed))


def test_chunking_depends_on_n_only_and_sums_to_n():
    for n in (0, 1, 7, 1 << 20, (1 << 20) + 1, 10**9):
        sizes = chunking(n)
        assert sizes.sum() == n and sizes.dtype == np.int64
        assert sizes.max() - sizes.min() <= 1


@pytest.mark.parametrize("kind", ["collimated", "conical"])
def test_every_ray_is_reflected_transmitted_absorbed_or_missed(kind):
    t = _count(Lambertian(0.5, 0.3), Beam(kind), 300_001)
    assert t.reflected + t.transmitted + t.absorbed + t.missed == t.N


def test_result_is_identical_whatever_the_thread_count():
    spec, beam = Lambertian(0.375, 0.2), Beam("conical")
    n = 5 * (1 << 20) + 3  # several chunks
    one, many = on_one_and_all_threads(lambda: _count(spec, beam, n, seed=99))
    assert one == many
    assert _count(spec, beam, n, seed=100) != one


def _beam_z(spec, n):
    """|z| of collimated against conical for R and T: two independent binomial estimates of the
    same fraction, their difference over its standard error (at spec's R and T) is N(0, 1)."""
    a = _count(spec, Beam("collimated"), n, seed=5)
    b = _count(spec, Beam("conical"), n, seed=6)
    z = []
    for field, p in (("reflected", 0.375), ("transmitted", 0.25)):
        pa, pb = getattr(a, field) / a.hits, getattr(b, field) / b.hits
        z.append(abs(pa - pb) / math.sqrt(p * (1 - p) * (1 / a.hits + 1 / b.hits)))
    return z


# two z tests (R and T share the rays): family-wise false-alarm rate at most 2 x 5e-4 = 1e-3
BEAM_ALPHA = 5e-4


def test_collimated_and_conical_lambertian_agree_statistically():
    assert max(_beam_z(Lambertian(0.375, 0.25), 2_000_000)) < z_two_sided(BEAM_ALPHA)  # 3.48


def test_the_beam_comparison_has_power_against_a_reflectance_off_by_0_003():
    # a beam whose specimen reflects 0.378 instead of 0.375: |z| ~ 6 at these N
    a = _count(Lambertian(0.375, 0.25), Beam("collimated"), 2_000_000, seed=5)
    b = _count(Lambertian(0.378, 0.25), Beam("conical"), 2_000_000, seed=6)
    z = abs(a.reflected / a.hits - b.reflected / b.hits) / math.sqrt(0.375 * 0.625 * (1 / a.hits + 1 / b.hits))
    assert z > z_two_sided(BEAM_ALPHA)


@pytest.mark.parametrize("disk", ["polar", "rejection"])
def test_wide_conical_beam_near_grazing_misses_some_rays_but_never_nans(disk):
    # disks larger than their distance, axis at 85 deg: part of the emitter sits below the
    # specimen plane. Those rays are counted as missed, not scattered from behind.
    beam = Beam("conical", emitter_radius_mm=40.0, specimen_radius_mm=12.5, distance_mm=20.0, disk_sampling=disk)
    t = _count(Lambertian(0.8), beam, 200_000, theta=85.0)
    assert 0 < t.missed < t.N
    assert t.reflected + t.absorbed + t.missed == t.N
    # the rays that did hit behave like any Lambertian: R = 0.8 within 4 binomial sigma
    # (false-alarm rate 2 * Phi(-4) = 6.3e-5 per case)
    assert abs(t.reflected / t.hits - 0.8) < 4 * math.sqrt(0.16 / t.hits)


def test_grazing_incidence_exactly_90_is_a_clear_error():
    with pytest.raises(GeometryError, match="grazing"):
        Beam("collimated").kernel_args(90.0, 0.0)
    Beam("collimated").kernel_args(89.9, 0.0)  # legal, if extreme


@pytest.mark.parametrize("theta", [0.0, 180.0])
def test_rotation_is_exact_at_the_poles(theta):
    r = rotation_to(theta, 123.0)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-15)
    assert r[2, 2] == (1.0 if theta == 0.0 else -1.0)


def test_incidence_from_below_reflects_downward():
    t = _count(Lambertian(0.6, 0.1), Beam("collimated"), 100_000, theta=180.0)
    assert t.missed == 0
    assert abs(t.reflected / t.N - 0.6) < 4 * math.sqrt(0.24 / t.N)


def test_bad_beams_are_refused():
    with pytest.raises(InputError, match="distance_mm"):
        Beam("conical", distance_mm=0.0)
    with pytest.raises(InputError, match="beam must be"):
        Beam("laser")


# --- the block kernel against the ray-by-ray kernel (every family: tests/test_block_families.py) ----

from virtual.collector import Collector  # noqa: E402
from virtual.engine import gonio_kernel_for  # noqa: E402
from virtual.specimens import parse_specimen  # noqa: E402


def test_kernel_choice_follows_the_model_and_the_disk_sampling():
    lam, rejection = parse_specimen("lambert:albedo=0.5"), Beam("conical", disk_sampling="rejection").disk_code
    for spec in ("lambert:albedo=0.5", "phong:exponent=20", "plastic", "dielectric", "oren-nayar"):
        assert gonio_kernel_for(parse_specimen(spec).model, Beam("conical").disk_code) == "block"
    assert gonio_kernel_for(lam.model, rejection) == "ray"
    assert gonio_kernel_for(-1, Beam("conical").disk_code) == "ray"  # no kernel model at all
    with pytest.raises(ValueError, match="block kernel"):
        gonio_kernel_for(lam.model, rejection, "block")
    with pytest.raises(ValueError, match="kernel must be"):
        gonio_kernel_for(lam.model, Beam("conical").disk_code, "simd")


MIRROR_THETAS = [0.0, 89.5, 180.0]
MIRROR_ALPHA = -np.expm1(np.log1p(-1e-3) / len(MIRROR_THETAS))  # Sidak: family-wise 1e-3


def test_the_near_mirror_family_rate_is_1e_3():
    assert family_rate(MIRROR_ALPHA, len(MIRROR_THETAS)) == pytest.approx(1e-3, rel=1e-9)


@pytest.mark.parametrize("theta", MIRROR_THETAS)
def test_block_kernel_on_a_near_mirror_at_the_pole_and_at_grazing(theta):
    # alpha = 1e-3: nearly every ray lands in one or two patches -- at the pole (theta 0 and 180,
    # where the bin guess always declines and the exact lookup decides) or at the horizon. The
    # counts still match the ray-by-ray kernel's: three two-sample chi-squares at MIRROR_ALPHA,
    # family-wise 1e-3; power: the same comparison rejects a slightly darker conductor.
    col, beam = Collector("equal-psa", 9, 24), Beam("collimated")
    a = kernel_counts("ggx:alpha=0.001,eta=0.2,k=3", beam, col, 200_000, 21, "block", theta=theta, phi=0.0)
    b = kernel_counts("ggx:alpha=0.001,eta=0.2,k=3", beam, col, 200_000, 22, "ray", theta=theta, phi=0.0)
    assert a.sum() == b.sum() == 200_000 and a.min() >= 0
    assert two_sample_p(a, b) > MIRROR_ALPHA
    rings = a[:-2].reshape(2, 9, 24).sum(axis=2)
    assert rings.max() > 0.9 * rings.sum()  # the lobe really is that narrow: one ring (pole cap or horizon)


def test_the_near_mirror_comparison_has_power_against_a_slightly_darker_conductor():
    # k = 2.5 instead of 3: normal reflectance 0.896 instead of 0.923 (more rays absorbed)
    col, beam = Collector("equal-psa", 9, 24), Beam("collimated")
    a = kernel_counts("ggx:alpha=0.001,eta=0.2,k=3", beam, col, 200_000, 21, "block", theta=0.0, phi=0.0)
    b = kernel_counts("ggx:alpha=0.001,eta=0.2,k=2.5", beam, col, 200_000, 22, "ray", theta=0.0, phi=0.0)
    assert two_sample_p(a, b) < 1e-6
