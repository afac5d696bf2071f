"""The roughplastic's table values on the float32 block kernel
(:func:`~virtual.kernels.block32_coat._rp_cells32`, :func:`~virtual.kernels.block32_coat._rp_read_block32`)
against the float64 reads (:func:`~virtual.kernels.coat.rp_t`, :func:`~virtual.kernels.coat.rp_e`) over
every incidence from normal to grazing: within a few float32 roundings (:data:`BOUND`, relative), the error
each float32 survival test carries. Power: the same reads at directions tilted by 1e-5 rad differ
from the untilted ones by more than the bound, in c t(mu) and in 1 - E(mu).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from virtual.kernel_codes import RP_N_E
from virtual.beam import Beam
from virtual.kernels.block32_coat import _rp_bounds, _rp_read_block32, _t_cell32, rp_tables32
from virtual.kernels.coat import rp_e, rp_t
from virtual.kernels.emit import BEAM_COLLIMATED
from virtual.specimens import parse_specimen
from virtual.specimens.roughplastic import incidence_params

#: Eight float32 roundings of a value <= 1: a table value's own rounding, the weights', the sums'.
BOUND = 8 * 2.0 ** -24
F = np.float32


def _hemisphere_params(spec: str) -> np.ndarray:
    """The kernel vector with the specular albedo table over every incidence (an integrating sphere's)."""
    return incidence_params(np.asarray(parse_specimen(spec).params(550.0), dtype=np.float64), BEAM_COLLIMATED,
                            np.zeros(16), hemisphere=True)


def _beam_params(spec: str, beam: Beam, theta: float) -> np.ndarray:
    """The kernel vector of one measurement: the E table over the beam's cosines at incidence ``theta``."""
    return incidence_params(np.asarray(parse_specimen(spec).params(550.0), dtype=np.float64), beam.code,
                            beam.kernel_args(theta, 0.0))


def _float32_reads(p: np.ndarray, w: np.ndarray, u4: np.ndarray) -> np.ndarray:
    """Rows ``c t(mu), 1 - E(mu), t(mo)`` as the kernel computes them for unit directions ``w``
    (rounded to float32) and grid uniforms ``u4``."""
    n, n_e = len(u4), int(p[RP_N_E])
    cell_i, cell_f, aux = np.ones((3, n), np.int32), np.zeros((6, n), np.float32), np.zeros((7, n), np.float32)
    for i in range(n):
        cell_i[2, i], cell_f[5, i] = _t_cell32(math.sqrt(F(1.0) - F(u4[i])))
    aux[:3] = w.astype(np.float32).T
    # cell_i[0] = 1: every ray's incidence read (the kernel reads it only where its bounds leave the base unsure)
    t32, e32, lo, hi, scale = rp_tables32(p, n_e, True)
    _rp_read_block32(t32, e32, F(p[3]), lo, hi, scale, n_e, n, cell_i, cell_f, aux)
    return aux[3:6].astype(np.float64)


def _directions() -> np.ndarray:
    """Unit directions from normal incidence (and within 1e-4 rad of it) to grazing, at random azimuths."""
    rng = np.random.default_rng(7)
    theta = np.concatenate([[0.0, 1e-7, 1e-5], rng.uniform(0.0, 1e-4, 200),
                            rng.uniform(0.0, 0.5 * math.pi - 1e-3, 2000)])
    phi = rng.uniform(0.0, 2.0 * math.pi, len(theta))
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)


@pytest.mark.slow  # every incidence's tables in both precisions (21-57 s under load)
def test_float32_table_values_are_within_a_few_roundings_of_the_float64_reads_at_every_incidence():
    for spec in ("roughplastic:alpha=0.3,eta=1.5,kd=0.5", "roughplastic:alpha=0.5,eta=1.33,kd=0.5"):
        p = _hemisphere_params(spec)
        w = _directions()
        u4 = np.random.default_rng(8).integers(0, 2 ** 24, len(w)) * 2.0 ** -24
        got = _float32_reads(p, w, u4)
        mu = np.abs(w[:, 2])
        want = np.array([[p[3] * rp_t(p, m) for m in mu], [1.0 - rp_e(p, m) for m in mu],
                         [rp_t(p, math.sqrt(1.0 - v)) for v in u4]])
        err = (np.abs(got - want) / want).max(axis=1)
        assert (err <= BOUND).all(), f"{spec}: relative errors {err} (c t, 1 - E, t(mo)) exceed {BOUND:.3g}"


@pytest.mark.slow  # the power of the slow test above; compiles the float32 table reader (7-21 s)
def test_power_directions_a_hundred_thousandth_of_a_radian_off_miss_the_bound():
    p = _hemisphere_params("roughplastic:alpha=0.3,eta=1.5,kd=0.5")
    theta = np.linspace(0.3, 1.3, 200)
    w, tilted = (np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=1) for t in (theta, theta + 1e-5))
    u4 = np.full(len(theta), 0.5)
    err = np.abs(_float32_reads(p, tilted, u4) - _float32_reads(p, w, u4)).max(axis=1)
    assert err[0] > BOUND and err[1] > BOUND, err


def _base_probabilities(p: np.ndarray, mu_lo: float, mu_hi: float, rng) -> np.ndarray:
    """c t / (1 - E) as the kernel computes it, at 3000 directions with cosines uniform in [mu_lo, mu_hi]."""
    mu = rng.uniform(mu_lo, min(mu_hi, 1.0), 3000)
    phi = rng.uniform(0.0, 2.0 * math.pi, len(mu))
    sin = np.sqrt(1.0 - mu * mu)
    num, den, _ = _float32_reads(p, np.stack([sin * np.cos(phi), sin * np.sin(phi), mu], axis=1), np.zeros(len(mu)))
    return num / den


@pytest.mark.slow  # 3000 directions per cosine range through the float32 table reader (7 s)
def test_the_base_bounds_hold_the_float32_probability_at_every_cosine_they_claim():
    """:func:`_rp_bounds`: for cosines in its [mu_lo, mu_hi], c t / (1 - E) as the kernel computes it lies
    inside [q_lo, q_hi] with half the margin to spare, so a ray it decides decides as the read would,
    and out of doubt. Power: the probabilities of a perturbed specimen (kd 0.5 -> 0.8) leave them."""
    rng = np.random.default_rng(9)
    margin = 1e-5
    for kind in ("conical", "collimated"):
        for theta in (0.0, 30.0, 60.0, 80.0):
            beam = Beam(kind)
            p, perturbed = (_beam_params(f"roughplastic:alpha=0.3,eta=1.5,kd={kd}", beam, theta) for kd in (0.5, 0.8))
            q_lo, q_hi, mu_lo, mu_hi = (float(v) for v in _rp_bounds(p, int(p[RP_N_E]), margin))
            q = _base_probabilities(p, mu_lo, mu_hi, rng)
            assert q_lo + margin / 2 <= q.min() and q.max() <= q_hi - margin / 2, (kind, theta, q.min(), q.max())
            q = _base_probabilities(perturbed, mu_lo, mu_hi, rng)
            assert q.min() < q_lo or q.max() > q_hi, (kind, theta)
