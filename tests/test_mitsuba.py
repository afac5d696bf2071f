"""Mitsuba 3 BSDFs as specimens, measured by our devices (virtual.specimens.mitsuba, virtual.python_engine).

Statistical checks use fixed seeds (deterministic); their false-alarm rates, as run: the
two-sample chi-square and each goodness of fit fail at p < ALPHA = 1e-3, the albedo check beyond
4 standard errors (6.3e-5), each Clopper-Pearson interval (delta = ALPHA) misses with at most
1e-3: in ``make test`` 1 + 1 + 5 checks, family-wise at most 6.1e-3 (union bound); ``make
test-all`` adds the two slow goodness-of-fit tests (8.1e-3 in all). Power: the same two-sample
test tells Mitsuba's diffuse 0.5 from our Lambertian 0.48 (p < 1e-6).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

# Optional extra `goniobench[mitsuba]`; `make test` installs it, elsewhere these tests are skipped.
pytest.importorskip("mitsuba")


from bench.core.errors import SpecimenError
from tests.helpers.stats import goodness_of_fit, two_sample_p
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.specimens.mitsuba import MitsubaSpecimen
from virtual.specimens import MODEL_PYTHON, Lambertian, parse_specimen
from virtual.spectrophotometer import VirtualSpectrophotometer

ALPHA = 1e-3
RAYS = 200_000
COLLECTOR = "equal-psa:6x12"
DIFFUSE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}
GGX = {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3}


def _used(counts: np.ndarray, n_bins: int) -> np.ndarray:
    """Patch counts and the absorbed bin (the missed bin is always 0 for a collimated beam)."""
    assert counts[n_bins + 1] == 0
    return counts[: n_bins + 1]


def test_mitsuba_diffuse_agrees_with_our_lambertian() -> None:
    counts = []
    for spec in (MitsubaSpecimen(DIFFUSE), Lambertian(reflectance=0.5)):
        g = VirtualGoniophotometer(spec, collector=COLLECTOR, rays=RAYS, method="rays", seed=11)
        counts.append(_used(g.simulate(30.0, 0.0, 550.0), 2 * g.collector.n_patches))
    p = two_sample_p(*counts)  # the empty transmission patches are dropped by its pooling rule
    assert p > ALPHA, f"two-sample chi-square p = {p:.2e}"
    albedo = 1.0 - counts[0][-1] / RAYS
    assert abs(albedo - 0.5) < 4.0 * np.sqrt(0.25 / RAYS)
    # power: a Lambertian 4 % darker (0.48) is told apart by the same test
    g = VirtualGoniophotometer(Lambertian(reflectance=0.48), collector=COLLECTOR, rays=RAYS, method="rays", seed=11)
    darker = _used(g.simulate(30.0, 0.0, 550.0), 2 * g.collector.n_patches)
    assert two_sample_p(counts[0], darker) < 1e-6


@pytest.mark.slow  # 2.5 minutes per incidence, warm (make test-all and CI run it, make test does not)
@pytest.mark.parametrize("theta_i", [30.0, 60.0])
def test_mitsuba_ggx_sampling_matches_its_own_eval(theta_i: float) -> None:
    spec = MitsubaSpecimen(GGX)
    g = VirtualGoniophotometer(spec, collector=COLLECTOR, rays=RAYS, method="rays", seed=5)
    assert not g.uses_fast_path()
    n_bins = 2 * g.collector.n_patches
    observed = _used(g.simulate(theta_i, 0.0, 550.0), n_bins)
    p = g.bin_probabilities(theta_i, 0.0, 550.0)[: n_bins + 1]  # quadrature of spec.bsdf (Mitsuba eval)
    assert 0.7 < 1.0 - p[-1] < 0.95  # a perfect-mirror GGX loses only shadowed/masked light
    chi2, pval, dof = goodness_of_fit(observed, RAYS * p)
    assert pval > ALPHA, f"chi-square {chi2:.1f} on {dof} dof, p = {pval:.2e}"
    assert spec.clamped == 0


def test_parse_specimen_mitsuba_strings() -> None:
    s = parse_specimen('mitsuba:{"type": "roughconductor", "distribution": "ggx", "alpha": 0.2}')
    assert isinstance(s, MitsubaSpecimen) and s.model == MODEL_PYTHON
    assert s.has_density and not s.transmits(550.0)
    assert s.label.startswith("mitsuba:")
    assert parse_specimen(s) is s
    with pytest.raises(SpecimenError, match="invalid JSON"):
        parse_specimen('mitsuba:{"type": "diffuse",}')
    with pytest.raises(SpecimenError, match="must be an object"):
        parse_specimen("mitsuba:[1, 2]")
    with pytest.raises(SpecimenError, match="nonsense"):
        parse_specimen('mitsuba:{"type": "nonsense"}')
    with pytest.raises(SpecimenError, match="expected mitsuba:"):
        parse_specimen("mitsuba:")
    with pytest.raises(SpecimenError, match="mitsuba"):  # listed among the known names
        parse_specimen("mitsubishi:x=1")


def test_spectrophotometer_measures_mitsuba_diffuse() -> None:
    sp = VirtualSpectrophotometer("mitsuba:" + json.dumps(DIFFUSE), rays=100_000, seed=3, delta=ALPHA)
    out = sp.measure("8/d", [450.0, 550.0, 650.0])
    lo, hi = out.reflectance_ci.T
    assert np.all((lo <= 0.5) & (0.5 <= hi)), (out.reflectance, out.reflectance_ci)
    assert np.all(out.transmittance == 0.0)
    again = VirtualSpectrophotometer(sp.specimen, rays=100_000, seed=3, delta=ALPHA).measure("8/d", [550.0])
    assert again.reflectance[0] == out.reflectance[1]  # same seed, same rays


def test_spectral_variant_on_a_conical_beam() -> None:
    spec = MitsubaSpecimen({"type": "diffuse", "reflectance": {"type": "spectrum", "value": [[400, 0.2], [700, 0.8]]}},
                           variant="scalar_spectral")
    sp = VirtualSpectrophotometer(spec, rays=50_000, seed=4, delta=ALPHA, beam="conical")
    out = sp.measure("8/d", [400.0, 700.0])
    lo, hi = out.reflectance_ci.T
    assert np.all((lo <= [0.2, 0.8]) & ([0.2, 0.8] <= hi)), (out.reflectance, out.reflectance_ci)
    with pytest.raises(SpecimenError, match="outside Mitsuba's spectral range"):
        sp.measure("8/d", [1000.0])


def test_one_sided_bsdf_absorbs_light_from_below() -> None:
    spec = MitsubaSpecimen(DIFFUSE)
    dirs, alive = spec.sample(np.array([0.0, 0.0, -1.0]), 1000, 550.0, np.random.default_rng(0))
    assert not alive.any()
    two = MitsubaSpecimen({"type": "twosided", "bsdf": DIFFUSE})
    dirs, alive = two.sample(np.array([0.0, 0.0, -1.0]), 1000, 550.0, np.random.default_rng(0))
    assert 400 < alive.sum() < 600 and np.all(dirs[alive, 2] < 0.0)


def test_weights_above_one_are_clamped_counted_and_warned_once() -> None:
    spec = MitsubaSpecimen({"type": "diffuse", "reflectance": {"type": "uniform", "value": 1.5}})
    with pytest.warns(RuntimeWarning, match="exceed 1 and were clamped") as record:
        _, alive = spec.sample(np.array([0.0, 0.0, 1.0]), 500, 550.0, np.random.default_rng(0))
        spec.sample(np.array([0.0, 0.0, 1.0]), 500, 550.0, np.random.default_rng(1))
    assert len(record) == 1 and spec.clamped == 1000 and alive.all()


def test_a_scene_counts_a_mitsuba_specimen_as_the_devices_do_and_refuses_effects_it_cannot_apply() -> None:
    """A scene of a specimen without a kernel counts its rays in numpy, as the virtual devices do
    (the same counts for the same stream), instead of handing model -1 to a kernel that absorbed
    every ray; per-ray effects, which only the kernels apply, are refused before any ray."""
    from bench.core.errors import ConfigError
    from virtual.collector import Collector
    from virtual.engine import measurement_seed
    from virtual.python_engine import gonio_counts_python
    from virtual.scene.declared import Effects, StrayLight
    from virtual.scene.simulate import Scene

    sp = MitsubaSpecimen(DIFFUSE)
    col = Collector("equal-psa", 6, 12)
    scene = Scene(sp, instrument="goniophotometer", collector=col, incidence=(30.0, 0.0), rays=50_000,
                  method="rays")
    res = scene.run()
    seq = measurement_seed(scene.seed, 550_000, 30_000, 0)
    expected = gonio_counts_python(sp, 550.0, scene.beam, 30.0, 0.0, col, 50_000, seq)
    np.testing.assert_array_equal(res.counts[0], expected)
    n_bins = 2 * col.n_patches
    assert abs(res.counts[0][:n_bins].sum() / 50_000 - 0.5) < 4 * np.sqrt(0.25 / 50_000)  # reflects, 4 SE
    with pytest.raises(ConfigError, match="has no kernel"):
        Scene(sp, instrument="goniophotometer", collector=col, effects=Effects(stray_light=StrayLight()))
