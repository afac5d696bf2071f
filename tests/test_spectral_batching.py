"""Spectral batching: a Lambertian (and GGX with one roughness) measured at W wavelengths at once
(:func:`virtual.engine.gonio_counts_spectral`) gives, per wavelength, exactly the
single-wavelength count distribution.

Each wavelength's row is compared with an independent single-wavelength run by the suite's
two-sample chi-square (tests/helpers/stats.py; bins + absorbed + missed). The module runs
COMPARISONS such comparisons, each at EACH (Sidak), so a correct kernel fails it with
probability FAMILY = 1e-3 (fixed seeds, so fixed outcomes). Power: a row against a single run
whose reflectance differs by 0.02, or whose eta or k differs by 10 %, gives p < 1e-6.

The stream rule of the product (:mod:`virtual.goniophotometer`): rays counted for a specimen
whose wavelengths share the angular part draw one stream per (specimen, incidence), and a
wavelength's counts do not depend on the other wavelengths of its batch -- tested exactly (31
wavelengths in one batch against 31 batches of one) in both precisions, through
:class:`VirtualGoniophotometer`, a sweep and the virtual bench.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.kernels import on_one_and_all_threads
from tests.helpers.stats import family_rate, two_sample_p
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_counts, gonio_counts_spectral, measurement_seed
from virtual.model_ids import MODEL_ANISO_GGX, MODEL_GGX, MODEL_LAMBERT, MODEL_PHONG
from virtual.specimens import parse_specimen

COL = Collector("equal-psa", 9, 24)
N = 400_000
# agreement comparisons: Lambert 2 x 4, GGX 2 x (3 + 2), float32 Lambert 2 x 3, float32 GGX 2 x 4, narrow 2
COMPARISONS = 8 + 10 + 6 + 8 + 2
FAMILY = 1e-3
EACH = -np.expm1(np.log1p(-FAMILY) / COMPARISONS)  # about 2.9e-5
# (R, T) per wavelength: reflecting and transmitting, opaque, a 50/50 split, a near-white one
RT = [(0.6, 0.3), (0.2, 0.0), (0.5, 0.5), (0.9, 0.05), (0.6, 0.3)]


def _single(p, beam, theta, seed):
    return gonio_counts(MODEL_LAMBERT, np.array(p), beam.code, beam.disk_code, beam.kernel_args(theta, 20.0),
                        COL.kernel_args(), N, measurement_seed(seed))


def _spectral(rows, beam, theta, seed, n=N):
    return gonio_counts_spectral(MODEL_LAMBERT, [np.array(p) for p in rows], beam.code, beam.disk_code,
                                 beam.kernel_args(theta, 20.0), COL.kernel_args(), n, measurement_seed(seed))


def test_the_stated_family_wise_rate_is_the_one_run():
    assert family_rate(EACH, COMPARISONS) == pytest.approx(FAMILY, rel=1e-9)


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_every_wavelength_has_the_single_wavelength_distribution(beam, theta):
    many = _spectral(RT, beam, theta, 1)
    assert many.shape == (len(RT), 2 * COL.n_patches + 2) and (many.sum(axis=1) == N).all()
    np.testing.assert_array_equal(many[0], many[-1])  # equal parameters, shared rays: equal rows
    for w, p in enumerate(RT[:-1]):
        assert two_sample_p(many[w], _single(p, beam, theta, 10 + w)) > EACH, w


def test_the_comparison_has_power_against_a_slightly_different_reflectance():
    many = _spectral(RT, Beam("conical"), 35.0, 1)
    assert two_sample_p(many[0], _single((0.62, 0.3), Beam("conical"), 35.0, 10)) < 1e-6


def test_spectral_counts_do_not_depend_on_the_thread_count():
    n = 3 * (1 << 20) + 9
    one, many = on_one_and_all_threads(lambda: _spectral(RT, Beam("conical"), 35.0, 4, n))
    np.testing.assert_array_equal(one, many)


def test_other_models_fall_back_to_one_measurement_per_wavelength():
    sp = parse_specimen("phong:exponent=20")
    beam = Beam("conical")
    p = sp.params(550.0)
    rows = gonio_counts_spectral(MODEL_PHONG, [p, p], beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                                 COL.kernel_args(), 10_000, measurement_seed(2))
    single = gonio_counts(MODEL_PHONG, p, beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                          COL.kernel_args(), 10_000, measurement_seed(2))
    np.testing.assert_array_equal(rows[0], single)
    np.testing.assert_array_equal(rows[1], single)
    with pytest.raises(ValueError, match="at least one"):
        gonio_counts_spectral(MODEL_LAMBERT, [], beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0),
                              COL.kernel_args(), 10, measurement_seed(2))


# GGX, one roughness, eta and k per wavelength: a dielectric, a conductor, another conductor
GGX_ROWS = [(0.2, 0.2, 1.5, 0.0), (0.2, 0.2, 0.2, 3.0), (0.2, 0.2, 0.6, 2.0)]


def _ggx_single(p, beam, theta, seed, model=MODEL_GGX):
    return gonio_counts(model, np.array(p), beam.code, beam.disk_code, beam.kernel_args(theta, 20.0),
                        COL.kernel_args(), N, measurement_seed(seed))


def _ggx_spectral(rows, beam, theta, seed, model=MODEL_GGX, n=N):
    return gonio_counts_spectral(model, [np.array(p) for p in rows], beam.code, beam.disk_code,
                                 beam.kernel_args(theta, 20.0), COL.kernel_args(), n, measurement_seed(seed))


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_ggx_wavelengths_each_have_the_single_wavelength_distribution(beam, theta):
    many = _ggx_spectral(GGX_ROWS, beam, theta, 1)
    assert (many.sum(axis=1) == N).all()
    for w, p in enumerate(GGX_ROWS):
        assert two_sample_p(many[w], _ggx_single(p, beam, theta, 20 + w)) > EACH, w
    aniso = [(0.4, 0.1, 1.5, 0.0), (0.4, 0.1, 0.2, 3.0)]
    many = _ggx_spectral(aniso, beam, theta, 2, MODEL_ANISO_GGX)
    for w, p in enumerate(aniso):
        assert two_sample_p(many[w], _ggx_single(p, beam, theta, 30 + w, MODEL_ANISO_GGX)) > EACH, w


def test_ggx_batch_has_power_against_a_slightly_different_fresnel():
    many = _ggx_spectral(GGX_ROWS, Beam("conical"), 35.0, 1)
    assert two_sample_p(many[1], _ggx_single((0.2, 0.2, 0.2, 3.3), Beam("conical"), 35.0, 20)) < 1e-6


def test_ggx_with_a_spectral_roughness_falls_back_to_one_measurement_per_wavelength():
    rows = [(0.2, 0.2, 1.5, 0.0), (0.3, 0.3, 1.5, 0.0)]
    many = _ggx_spectral(rows, Beam("conical"), 35.0, 3, n=10_000)
    for w, p in enumerate(rows):
        np.testing.assert_array_equal(many[w], gonio_counts(
            MODEL_GGX, np.array(p), Beam("conical").code, Beam("conical").disk_code,
            Beam("conical").kernel_args(35.0, 20.0), COL.kernel_args(), 10_000, measurement_seed(3)))


# --- the float32 batches (virtual.kernels.spectral32), against the float64 ray-by-ray kernel --------------------
# Same two-sample chi-square at EACH per comparison (counted in COMPARISONS); power: a perturbed
# parameter gives p < 1e-6. GGX rows: conductors, a dielectric and total internal reflection (eta < 1, k = 0).
GGX32_ROWS = [(0.2, 0.2, 0.2, 3.0), (0.2, 0.2, 1.5, 0.0), (0.2, 0.2, 0.6, 0.0), (0.2, 0.2, 2.5, 8.0)]


def _ray(model, p, beam, theta, seed):
    return gonio_counts(model, np.array(p), beam.code, beam.disk_code, beam.kernel_args(theta, 20.0),
                        COL.kernel_args(), N, measurement_seed(seed), kernel="ray")


def _counting(monkeypatch, name, module="virtual.chunked"):
    """Count the calls of ``<module>.<name>`` (to know which batch ran; virtual.engine imports
    the kernels from virtual.chunked when it counts, so a patch there is seen)."""
    import importlib

    mod = importlib.import_module(module)
    calls, fn = [], getattr(mod, name)
    monkeypatch.setattr(mod, name, lambda *a, **k: calls.append(1) or fn(*a, **k))
    return calls


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_float32_lambert_batch_matches_the_ray_kernel(monkeypatch, beam, theta):
    calls = _counting(monkeypatch, "lambert_spectral32_kernel")
    many = _spectral(RT, beam, theta, 5)
    assert calls and (many.sum(axis=1) == N).all()
    for w in (0, 2, 3):
        assert two_sample_p(many[w], _ray(MODEL_LAMBERT, RT[w], beam, theta, 40 + w)) > EACH, w


@pytest.mark.parametrize("beam, theta", [(Beam("conical"), 35.0), (Beam("collimated"), 150.0)])
def test_float32_ggx_batch_matches_the_ray_kernel(monkeypatch, beam, theta):
    calls = _counting(monkeypatch, "ggx_spectral32_kernel")
    many = _ggx_spectral(GGX32_ROWS, beam, theta, 6)
    assert calls and (many.sum(axis=1) == N).all()
    for w in range(len(GGX32_ROWS)):
        assert two_sample_p(many[w], _ray(MODEL_GGX, GGX32_ROWS[w], beam, theta, 50 + w)) > EACH, w


def test_float32_batches_have_power_against_a_perturbed_parameter():
    beam = Beam("conical")
    many = _ggx_spectral(GGX32_ROWS, beam, 35.0, 6)
    assert two_sample_p(many[0], _ray(MODEL_GGX, (0.2, 0.2, 0.2, 3.3), beam, 35.0, 50)) < 1e-6
    assert two_sample_p(many[2], _ray(MODEL_GGX, (0.2, 0.2, 0.66, 0.0), beam, 35.0, 52)) < 1e-6
    lam = _spectral(RT, beam, 35.0, 5)
    assert two_sample_p(lam[0], _ray(MODEL_LAMBERT, (0.62, 0.3), beam, 35.0, 40)) < 1e-6


def test_fresnel_bounds_bracket_the_fresnel_factor():
    """lo <= F(c) <= hi (F in float64 and in float32) at 10^6 random c and at every cell edge, the
    critical angle of total internal reflection and the ends, for extreme (eta, k)."""
    from numba import int32

    from virtual.kernels import jit
    from virtual.kernels.ggx import fresnel_conductor_ratio
    from virtual.kernels.ggx32 import fresnel_conductor_ratio as fresnel_conductor_ratio32
    from virtual.kernel_codes import FRESNEL_CELLS, FRESNEL_SAMPLES
    from virtual.kernels.spectral32 import fresnel_bounds

    @jit
    def worst(c32, etas, ks, lo, hi):  # the largest violation of either bound (<= 0 when all hold)
        n = np.float32(lo.shape[0])
        out = -1.0
        for i in range(c32.shape[0]):
            j = min(int32(c32[i] * n), int32(lo.shape[0] - 1))
            for w in range(etas.shape[0]):
                a, b = fresnel_conductor_ratio(np.float64(c32[i]), etas[w], ks[w], False)
                a32, b32 = fresnel_conductor_ratio32(c32[i], np.float32(etas[w]), np.float32(ks[w]), False)
                if b > 0.0 and b32 > 0.0:  # 0/0 only at c = 0 with eta = 1, k = 0 (no interface, no ray)
                    for f in (a / b, np.float64(a32 / b32)):
                        out = max(out, lo[j, w] - f, f - hi[j, w])
        return out

    etas = np.array([0.2, 0.2, 0.5, 0.9, 0.99, 1.0, 1.01, 1.5, 3.0, 3.0, 0.2, 1.0])
    ks = np.array([0.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 10.0, 3.0, 1e-3])
    etas, ks = etas.astype(np.float32).astype(np.float64), ks.astype(np.float32).astype(np.float64)
    lo, hi = fresnel_bounds(etas, ks, FRESNEL_CELLS, FRESNEL_SAMPLES, 16)
    assert (lo <= hi).all() and (lo[:, len(etas):] == 0).all() and (hi[:, len(etas):] == 0).all()
    rng = np.random.default_rng(7)
    edges = np.arange(FRESNEL_CELLS + 1) / FRESNEL_CELLS
    crit = np.sqrt(1.0 - etas[etas < 1.0] ** 2)  # total internal reflection below these cosines (k = 0)
    special = np.concatenate([edges, crit, [0.0, 1.0, 1e-7, 1.0 - 1e-7]]).astype(np.float32)
    near = np.concatenate([np.nextafter(special, np.float32(-1)), special, np.nextafter(special, np.float32(2))])
    c = np.concatenate([rng.random(1_000_000, dtype=np.float32), np.clip(near, 0, np.float32(1.0000001))])
    assert worst(c, etas, ks, lo, hi) <= 0.0
    # and the bounds are tight enough to decide almost every ray without the exact factor
    assert np.median(hi[:, :len(etas)] - lo[:, :len(etas)]) < 1e-3


def test_narrow_ggx_lobes_keep_the_float64_batch(monkeypatch):
    """alpha < MIN_ALPHA at some wavelength's parameters: float32 does not suit, the float64 batch runs
    (still each row with the single-wavelength distribution, here the float64 block kernel's)."""
    calls = _counting(monkeypatch, "ggx_spectral_kernel")
    rows = [(0.005, 0.005, 0.2, 3.0), (0.005, 0.005, 1.5, 0.0)]
    many = _ggx_spectral(rows, Beam("conical"), 35.0, 8)
    assert calls and (many.sum(axis=1) == N).all()
    for w, p in enumerate(rows):
        assert two_sample_p(many[w], _ggx_single(p, Beam("conical"), 35.0, 60 + w)) > EACH, w


def test_float32_ggx_batch_does_not_depend_on_the_thread_count():
    n = 3 * (1 << 20) + 9
    one, many = on_one_and_all_threads(lambda: _ggx_spectral(GGX32_ROWS, Beam("conical"), 35.0, 4, n=n))
    np.testing.assert_array_equal(one, many)


# --- the product's stream rule: a batch of 31 wavelengths == 31 batches of one, exactly ---------------------------
WL31 = np.arange(400.0, 701.0, 10.0)
LAMBERT31 = [(0.05 + 0.03 * i, 0.3 - 0.009 * i) for i in range(31)]
GGX31 = [(0.2, 0.2, 0.2 + 0.05 * i, 3.0 - 0.09 * i, 0.0) for i in range(31)]


def _rows_equal_single_batches(model, rows, beam, n=60_000):
    args, cargs = beam.kernel_args(35.0, 20.0), COL.kernel_args()
    many = gonio_counts_spectral(model, [np.array(p) for p in rows], beam.code, beam.disk_code, args, cargs, n,
                                 measurement_seed(7, 11))
    for w, p in enumerate(rows):
        one = gonio_counts_spectral(model, [np.array(p)], beam.code, beam.disk_code, args, cargs, n,
                                    measurement_seed(7, 11))
        np.testing.assert_array_equal(many[w], one[0], err_msg=f"row {w}")
    return many


@pytest.mark.parametrize("float32", [True, False])
@pytest.mark.parametrize("beam", [Beam("conical"), Beam("collimated")])
def test_a_lambert_batch_of_31_gives_exactly_31_single_wavelength_batches(monkeypatch, beam, float32):
    import virtual.engine as eng

    if not float32:  # a Lambertian always suits float32: force the float64 batch to test it too
        monkeypatch.setattr(eng, "float32_suits", lambda model, params: False)
    calls = _counting(monkeypatch, "lambert_spectral32_kernel" if float32 else "lambert_spectral_kernel")
    many = _rows_equal_single_batches(MODEL_LAMBERT, LAMBERT31, beam)
    assert calls and len({tuple(r) for r in many}) == 31  # every wavelength its own counts


@pytest.mark.parametrize("alpha, kernel", [(0.2, "ggx_spectral32_kernel"), (0.005, "ggx_spectral_kernel")])
@pytest.mark.parametrize("beam", [Beam("conical"), Beam("collimated")])
def test_a_ggx_batch_of_31_gives_exactly_31_single_wavelength_batches(monkeypatch, beam, alpha, kernel):
    calls = _counting(monkeypatch, kernel)  # alpha 0.005 < MIN_ALPHA: the float64 batch
    rows = [(alpha, alpha, *p[2:]) for p in GGX31]
    many = _rows_equal_single_batches(MODEL_GGX, rows, beam)
    assert calls and len({tuple(r) for r in many}) > 25


def _spectral_ggx():
    from virtual.specimens.microfacet import GGX

    return GGX(alpha=0.2, eta=(list(WL31), [p[2] for p in GGX31]), k=(list(WL31), [p[3] for p in GGX31]))


@pytest.mark.parametrize("specimen", ["colorchecker:dark skin", "ggx"])
def test_the_goniophotometer_batches_its_wavelengths_with_the_counts_of_single_wavelength_runs(monkeypatch, specimen):
    from virtual.goniophotometer import VirtualGoniophotometer

    sp = _spectral_ggx() if specimen == "ggx" else parse_specimen(specimen)
    kw = {"collector": "equal-psa:9x24", "rays": 60_000, "seed": 3, "method": "rays", "beam": "conical"}
    calls = _counting(monkeypatch, "gonio_counts_spectral", "virtual.goniophotometer")
    g = VirtualGoniophotometer(sp, wavelengths=WL31, **kw)
    assert g.batches_wavelengths
    rec = g.measure_bsdf(30.0, 10.0)
    assert len(calls) == 1 and rec.meta["method"] == "rays"  # one batch for the 31 wavelengths
    for w in WL31:
        one = VirtualGoniophotometer(sp, wavelengths=[w], **kw).measure_bsdf(30.0, 10.0)
        assert rec.table[rec.table.wavelength_nm == w]["count"].tolist() == one.table["count"].tolist(), w
    # one wavelength asked alone first (a detector scan): the rest of the spectrum comes in its batch
    g2 = VirtualGoniophotometer(sp, wavelengths=WL31, **kw)
    np.testing.assert_array_equal(g2.simulate(30.0, 10.0, 550.0), g.simulate(30.0, 10.0, 550.0))
    assert len(calls) == 1 + 31 + 1 and len(g2._cache) == 31


def test_specimens_whose_direction_depends_on_the_wavelength_keep_a_stream_per_wavelength(monkeypatch):
    from virtual.goniophotometer import VirtualGoniophotometer
    from virtual.specimens.microfacet import GGX

    calls = _counting(monkeypatch, "gonio_counts_spectral", "virtual.goniophotometer")
    kw = {"collector": "equal-psa:9x24", "rays": 20_000, "seed": 3, "method": "rays"}
    for sp in (GGX(alpha=([400.0, 700.0], [0.1, 0.3])), parse_specimen("phong"), parse_specimen("plastic")):
        g = VirtualGoniophotometer(sp, wavelengths=[450, 550], **kw)
        assert not g.batches_wavelengths
        g.measure_bsdf(30.0)
    assert not calls
    assert not VirtualGoniophotometer("lambert:albedo=0.5", beam=Beam("collimated", disk_sampling="rejection"),
                                      **kw).batches_wavelengths


def test_auto_counts_rays_for_several_wavelengths_only_where_one_batch_beats_the_quadratures():
    from virtual.goniophotometer import VirtualGoniophotometer

    def method(sp, wl, rays=10_000_000):
        return "fast" if VirtualGoniophotometer(sp, wavelengths=wl, rays=rays, seed=1).uses_fast_path() else "rays"

    ggx = "ggx:alpha=0.2,eta=0.2,k=3"
    assert method(ggx, [550]) == "fast"  # one wavelength: the fast path, as before
    assert method(ggx, WL31) == "rays"  # 31 quadratures of ~1 s against one batch
    assert method(ggx, WL31, rays=10_000_000_000) == "fast"  # a batch of 1e10 rays costs more
    assert method("lambert:albedo=0.5", WL31) == "fast"  # a Lambertian's quadrature is cheap
    assert method("phong", WL31) == "fast"  # no batch for a Phong lobe


def test_a_sweep_batches_a_task_s_wavelengths_with_the_counts_of_one_wavelength_tasks(monkeypatch):
    import pandas as pd

    from bench.sweep import run_task, sweep_from_dict

    d = {"sweep": {"seed": 4, "instrument": "gonio", "specimens": ["ggx:alpha=0.3,eta=1.5,k=0"],
                   "incidences": [20], "collectors": ["equal-psa:6x12"], "wavelengths": "450:650:50",
                   "rays": 100_000}}
    whole = sweep_from_dict(d)  # default: a whole spectrum per task; auto resolves to rays (one batch)
    split = sweep_from_dict({"sweep": {**d["sweep"], "wavelengths_per_task": 1}})
    assert len(whole) == 1 and len(split) == 5 and {t.method for t in whole.tasks + split.tasks} == {"rays"}
    calls = _counting(monkeypatch, "gonio_counts_spectral", "virtual.goniophotometer")
    a = run_task(whole.tasks[0]).rows
    assert len(calls) == 1
    b = pd.concat([run_task(t).rows for t in split.tasks], ignore_index=True)
    pd.testing.assert_frame_equal(a, b, check_exact=True)


def test_the_virtual_bench_reads_every_detector_wavelength_from_one_batch(monkeypatch):
    from bench.core.geometry import Geometry
    from virtual.goniophotometer import VirtualGoniophotometer

    calls = _counting(monkeypatch, "gonio_counts_spectral", "virtual.goniophotometer")
    g = VirtualGoniophotometer("colorchecker:foliage", collector="equal-psa:9x24", rays=50_000, seed=2, method="rays",
                               wavelengths=WL31)
    g.move_to(Geometry(30.0, 0.0, 30.0, 180.0))
    r = g.acquire(1.0)
    g.move_to(Geometry(30.0, 0.0, 45.0, 180.0))
    g.acquire(1.0)
    assert len(calls) == 1 and r.signal.shape == (31,) and (r.signal > 0).all()
