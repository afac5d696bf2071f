"""Mitsuba's ``roughplastic`` and the leaf on the float32 block kernel
(:mod:`virtual.kernels.block32_coat`): ``auto`` routes them there, it counts the distribution of
the ray-by-ray kernel, and its float64 redo of the rays in doubt
(:func:`~virtual.kernels.block32_coat.redo_coat_ray64`) counts it too.

Agreement cases are two-sample chi-squares (tests/helpers/stats.py) over the patches plus
absorbed and missed; the module runs ``len(AGREE) + len(REDO)`` of them at ``EACH`` (Sidak),
family-wise false-alarm rate ``FAMILY`` = 1e-3, fixed seeds. Power: a perturbed parameter (the
roughplastic's roughness, the leaf body's reflectance) fails the same comparison with p < 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.kernels import agreement_with_rays, kernel_counts
from tests.helpers.stats import family_rate, two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_counts, gonio_kernel_for, measurement_params, measurement_seed
from virtual.kernels import jit
from virtual.kernels.block32_coat import redo_coat_ray64
from virtual.kernels.emit import BEAM_COLLIMATED, BEAM_CONICAL
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels.xoshiro import fill_uniforms32
from virtual.model_ids import MODEL_ROUGHPLASTIC
from virtual.rng import lane_states32, stream_states
from virtual.specimens import parse_specimen

N = 400_000
PSA = Collector("equal-psa", 9, 24)
CONICAL, COLLIMATED = Beam("conical"), Beam("collimated")
RP = "roughplastic:alpha=0.3,eta=1.5,kd=0.5"
LEAF = "leaf:healthy"

# the ray kernel's roughplastic tables at 60 and 80 deg conical: 2.2 and 3.3 s; each case ~1 CPU-s
_SLOW = pytest.mark.slow
AGREE = [(spec, beam, theta) for spec in (RP, LEAF) for beam in (COLLIMATED, CONICAL) for theta in (0.0, 30.0, 60.0, 80.0)]
AGREE_MARKED = [case if case[2] == 30.0 else pytest.param(*case, marks=_SLOW) for case in AGREE]
REDO = [(RP, COLLIMATED), (RP, CONICAL), (LEAF, CONICAL)]
FAMILY = 1e-3
EACH = -np.expm1(np.log1p(-FAMILY) / (len(AGREE) + len(REDO)))


def test_the_stated_family_wise_rate_is_the_one_run():
    assert family_rate(EACH, len(AGREE) + len(REDO)) == pytest.approx(FAMILY, rel=1e-9)


def test_auto_routes_both_families_to_block32_where_float32_resolves_them():
    for spec in (RP, LEAF):
        sp = parse_specimen(spec)
        assert gonio_kernel_for(sp.model, CONICAL.disk_code, params=sp.params(550.0)) == "block32"
    for spec in ("roughplastic:alpha=0.005,eta=1.5,kd=0.5", "leaf:roughness=0.005"):
        sp = parse_specimen(spec)
        assert gonio_kernel_for(sp.model, CONICAL.disk_code, params=sp.params(550.0)) == "block"
    sp = parse_specimen(RP)
    q = sp.params(550.0).copy()
    q[10] = 1.5  # a coat transmittance above 1: no float32
    assert gonio_kernel_for(sp.model, CONICAL.disk_code, params=q) == "block"


@pytest.mark.parametrize("spec, beam, theta", AGREE_MARKED)
def test_block32_and_ray_kernels_count_the_same_distribution(spec, beam, theta):
    assert agreement_with_rays(spec, beam, PSA, N, 51, "block32", theta) > EACH


def test_power_against_a_perturbed_roughness():
    a = kernel_counts(RP, CONICAL, PSA, N, 51, "block32", theta=30.0)
    b = kernel_counts("roughplastic:alpha=0.33,eta=1.5,kd=0.5", CONICAL, PSA, N, 52, "ray", theta=30.0)
    assert two_sample_p(a, b) < 1e-6


def test_power_against_a_perturbed_leaf_body():
    sp = parse_specimen(LEAF)
    p = sp.params(550.0)
    q = p.copy()
    q[3] *= 1.2  # r_b, the body's reflectance
    args = CONICAL.kernel_args(30.0, 20.0)
    a = gonio_counts(sp.model, p, CONICAL.code, CONICAL.disk_code, args, PSA.kernel_args(), N, measurement_seed(51),
                     kernel="block32")
    b = gonio_counts(sp.model, q, CONICAL.code, CONICAL.disk_code, args, PSA.kernel_args(), N, measurement_seed(52),
                     kernel="ray")
    assert two_sample_p(a, b) < 1e-6


@jit
def _all_redone(model, p64, kind, b64, cargs, n_blocks, lane, s, hist):
    """Every ray of ``n_blocks`` float32 blocks decided by the doubt path alone (as if every
    ray were in doubt), counted as the kernels count: patches, absorbed, missed."""
    nb = 1024
    conical = kind == BEAM_CONICAL
    n_beam = 4 if conical else 0
    n_scat = 7 if model == MODEL_ROUGHPLASTIC else 9
    ublock = np.empty(((n_beam + n_scat) * nb // 64, 64), dtype=np.float32)
    u = ublock.reshape(ublock.size)
    s0 = n_beam * nb
    bo = nb if conical else 0
    scheme, n_theta, n_phi, sin2_edges, phi_cs = cargs
    n_bins = 2 * n_theta * n_phi
    for _ in range(n_blocks):
        fill_uniforms32(lane, ublock)
        for i in range(nb):
            ox, oy, oz, alive, hit = redo_coat_ray64(model, p64, kind, b64, u, i, nb, bo, s0, s)
            if not hit:
                hist[n_bins + 1] += 1
            elif not alive:
                hist[n_bins] += 1
            else:
                hist[patch_of(ox, oy, oz, scheme, n_theta, n_phi, sin2_edges, phi_cs)] += 1


@pytest.mark.parametrize("spec, beam", REDO)
def test_the_float64_redo_of_a_doubted_ray_counts_the_ray_kernels_law(spec, beam):
    """The redo refines a ray's 24-bit uniforms to 53 bits and runs the float64 given forms:
    applied to every ray (not only the one in 10^6 the kernel flags), it must give the law."""
    sp = parse_specimen(spec)
    args = beam.kernel_args(30.0, 20.0)
    p64 = np.ascontiguousarray(measurement_params(sp.model, sp.params(550.0), beam.code, args), dtype=np.float64)
    p64 = np.concatenate([p64, np.zeros(max(0, 6 - p64.size))])
    n_blocks = N // 1024
    hist = np.zeros(2 * PSA.n_patches + 2, dtype=np.int64)
    seq = measurement_seed(53)
    kind = BEAM_CONICAL if beam is CONICAL else BEAM_COLLIMATED
    _all_redone(np.int64(sp.model), p64, np.int64(kind), tuple(float(v) for v in args), tuple(PSA.kernel_args()),
                n_blocks, lane_states32(seq, 1)[0].copy(), stream_states(seq, 1)[0].copy(), hist)
    b = kernel_counts(spec, beam, PSA, n_blocks * 1024, 54, "ray", theta=30.0)
    assert hist.sum() == b.sum()
    assert two_sample_p(hist, b) > EACH


def test_the_redo_path_has_power():
    """The same comparison against a leaf whose body reflects 20 % more fails."""
    sp = parse_specimen(LEAF)
    args = CONICAL.kernel_args(30.0, 20.0)
    p64 = np.concatenate([sp.params(550.0), [0.0]])
    hist = np.zeros(2 * PSA.n_patches + 2, dtype=np.int64)
    seq = measurement_seed(53)
    _all_redone(np.int64(sp.model), p64, np.int64(BEAM_CONICAL), tuple(float(v) for v in args),
                tuple(PSA.kernel_args()), N // 1024, lane_states32(seq, 1)[0].copy(), stream_states(seq, 1)[0].copy(),
                hist)
    q = sp.params(550.0).copy()
    q[3] *= 1.2
    b = gonio_counts(sp.model, q, CONICAL.code, CONICAL.disk_code, args, PSA.kernel_args(), hist.sum(),
                     measurement_seed(54), kernel="ray")
    assert two_sample_p(hist, b) < 1e-6
