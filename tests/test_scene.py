"""Scenes: TOML loading, only the declared effects composed, positions only when needed, and
every effect's reading against its exact reference (binomial intervals at delta = 1e-4)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bench.core.errors import ConfigError, GeometryError
from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import gonio_counts, measurement_seed, spectro_counts
from virtual.scene import (Aperture, Bandpass, Effects, GlossTrap, Noise, Scene, SpecimenPattern, Sphere, StrayLight,
                           effect_costs, load_scene, scene_from_dict)
from virtual.specimens import GGX, Lambertian, OrenNayar

SCENES = Path(__file__).resolve().parent.parent / "fixtures" / "scenes"
LAMBERT = Lambertian(0.6, 0.0)


def _seq(sc: Scene, wl: float = 550.0) -> np.random.SeedSequence:
    return measurement_seed(sc.seed, int(round(wl * 1000)), int(round(sc.incidence[0] * 1000)),
                            int(round((sc.incidence[1] % 360.0) * 1000)))


def _covers(sc: Scene, rays: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Run and check every reading's 1 - delta interval covers the reference; returns both."""
    r = sc.run(rays=rays, seed=seed)
    ref, exact = sc.reference()
    assert exact
    inside = (r.ci[..., 0] <= ref) & (ref <= r.ci[..., 1])
    assert inside.all(), (r.values, ref)
    return r.values, ref


def test_every_fixture_scene_loads():
    names = sorted(p.stem for p in SCENES.glob("*.toml"))
    assert {"lambert-bare", "conical-grazing", "gonio-ggx", "sphere-effects", "gonio-aperture",
            "physical-inplane"} <= set(names)
    for p in SCENES.glob("*.toml"):
        sc = load_scene(p)
        assert sc.name == p.stem
    se = load_scene(SCENES / "sphere-effects.toml")
    assert se.effects.declared() == ["noise", "stray_light", "sphere", "bandpass", "specimen"]
    assert se.needs_positions


@pytest.mark.parametrize("bad, match", [
    ({"colour": 1}, "unknown key"),
    ({"effects": {"glare": {}}}, "unknown key 'effects.glare'"),
    ({"effects": {"sphere": {"wall_reflectance": 0.99}}}, "effects.sphere.wall_reflectance: .* 0.985 .got 0.99"),
    ({"effects": {"sphere": {"port_fraction": 0.12}}}, "effects.sphere.port_fraction"),
    ({"effects": {"aperture": {"half_angle_deg": 2}}}, "goniophotometer"),
    ({"instrument": "goniophotometer", "effects": {"sphere": {}}}, "spectrophotometer"),
    ({"instrument": "goniophotometer", "effects": {"aperture": {"views": [[89, 0]]}}}, "horizon"),
    ({"effects": {"bandpass": {"nodes": 4}}}, "odd"),
    ({"effects": {"gloss_trap": {"specular": "maybe"}}}, "excluded"),
    ({"observable": "colour"}, "observable"),
    ({"effects": {"gloss_trap": {"half_angle_deg": 60}}}, "effects.gloss_trap.half_angle_deg"),
    ({"beam": {"kind": "conical"}, "method": "fast"}, "fast"),
])
def test_bad_scenes_are_refused_naming_the_key(bad, match):
    with pytest.raises(ConfigError, match=match):
        scene_from_dict({"specimen": "lambert:reflectance=0.5", **bad})


def test_grazing_scene_is_a_geometry_error():
    with pytest.raises(GeometryError):
        scene_from_dict({"incidence": [90, 0]})


def test_no_effects_runs_the_bare_kernel_bit_for_bit():
    sc = Scene(LAMBERT, beam=Beam("conical"), seed=4)
    r = sc.run(rays=100_000)
    assert r.method == "bare" and not r.positions_sampled
    b = sc.beam.kernel_args(*sc.incidence)
    t = spectro_counts(LAMBERT.model, LAMBERT.params(550.0), sc.beam.code, sc.beam.disk_code, b, 100_000, _seq(sc))
    assert r.counts[0][:5].tolist() == [t.reflected, t.transmitted, t.absorbed, t.missed, t.cone]
    g = Scene(LAMBERT, instrument="goniophotometer", collector=Collector("equal-psa", 4, 8), method="rays", seed=4)
    rg = g.run(rays=50_000)
    c = gonio_counts(LAMBERT.model, LAMBERT.params(550.0), 0, 0, g.beam.kernel_args(*g.incidence),
                     g.collector.kernel_args(), 50_000, _seq(g))
    assert rg.method == "bare" and np.array_equal(rg.counts[0], c)


def test_far_field_effects_sample_no_positions():
    """A uniform specimen with far-field detectors draws exactly the bare kernel's random numbers:
    its collector counts are identical to the bare ray-by-ray kernel's for the same seed (every
    native family also has a block kernel, with other streams: rejection-sampled beam disks keep
    the bare measurement on the ray-by-ray kernel). A non-uniform specimen or near-field
    detectors do sample positions."""
    base = Scene(OrenNayar(sigma=20.0, albedo=0.8), instrument="goniophotometer",
                 collector=Collector("equal-psa", 4, 8), method="rays", seed=2, incidence=(30.0, 0.0),
                 beam=Beam("conical", disk_sampling="rejection"))
    far = base.with_effects(Effects(aperture=Aperture(2.0, ((0.0, 0.0), (30.0, 180.0))),
                                    specimen=SpecimenPattern(uniform=True)))
    assert not far.needs_positions
    r0, r1 = base.run(rays=100_000), far.run(rays=100_000)
    assert r1.method == "effects" and not r1.positions_sampled
    nb = base.collector.n_bins + 2
    assert np.array_equal(r0.counts[0], r1.counts[0][:nb])
    assert base.with_effects(Effects(aperture=Aperture(2.0, ((0.0, 0.0),), 500.0))).needs_positions
    assert base.with_effects(Effects(specimen=SpecimenPattern(uniform=False))).needs_positions


def test_each_spectro_effect_matches_its_exact_reference():
    base = Scene(LAMBERT, delta=1e-4, seed=5)
    n = 400_000
    _covers(base.with_effects(Effects(stray_light=StrayLight(0.01))), n)
    _covers(base.with_effects(Effects(sphere=Sphere(0.975, 0.06, 0.01, 0.02, 0.99))), n)
    _covers(base.with_effects(Effects(specimen=SpecimenPattern(False, 4.0, 0.6, 8.0))), n)
    v, ref = _covers(replace(base, beam=Beam("conical")).with_effects(
        Effects(specimen=SpecimenPattern(False, 4.0, 0.6))), n)
    assert ref[0, 0] < 0.6 * 0.75  # the pattern darkens the reading by its exact mean
    # bandpass: a spectral peak is flattened by the slit function (weighted node average)
    peak = Lambertian(reflectance=([530.0, 550.0, 570.0], [0.2, 0.8, 0.2]))
    sc = Scene(peak, delta=1e-4, seed=6, effects=Effects(bandpass=Bandpass(10.0, 9)))
    v, ref = _covers(sc, n)
    assert ref[0, 0] == pytest.approx(0.8 - 0.6 * (10.0 / 3.0) / 20.0, rel=0.02)
    # gloss trap: a glossy coat loses its specular cone when excluded
    glossy = Scene(GGX(alpha=0.01, eta=1.5, k=3.0), delta=1e-4, seed=7, incidence=(8.0, 0.0))
    v_in, ref_in = _covers(glossy.with_effects(Effects(gloss_trap=GlossTrap("included", 4.0))), n)
    v_ex, ref_ex = _covers(glossy.with_effects(Effects(gloss_trap=GlossTrap("excluded", 4.0))), n)
    assert ref_ex[0, 0] < 0.2 * ref_in[0, 0]


def test_goniophotometer_effects_match_their_references():
    sp = OrenNayar(sigma=20.0, albedo=0.8)
    base = Scene(sp, instrument="goniophotometer", collector=Collector("equal-psa", 3, 8), method="rays",
                 delta=1e-4, seed=8, incidence=(30.0, 0.0))
    sc = base.with_effects(Effects(aperture=Aperture(3.0, ((0.0, 0.0), (30.0, 180.0), (50.0, 90.0))),
                                   stray_light=StrayLight(0.01)))
    r = sc.run(rays=1_000_000)
    ref, exact = sc.reference()
    assert exact and r.values.shape == (1, sc.collector.n_bins + 3)
    inside = (r.ci[..., 0] <= ref) & (ref <= r.ci[..., 1])
    assert inside.all()


def test_noise_keeps_the_mean_and_widens_the_interval():
    """Gaussian instrument noise of u: over 200 seeds the readings' spread is sqrt(mc^2 + u^2)
    (sample std within +-20 %: 5 sigma for 200 draws) and the mean stays at the reference."""
    sc = Scene(LAMBERT, effects=Effects(noise=Noise(0.01)), seed=1)
    vals, widths = [], []
    for s in range(200):
        r = sc.run(rays=20_000, seed=s)
        vals.append(r.values[0, 0])
        widths.append(r.ci[0, 0, 1] - r.ci[0, 0, 0])
    mc = math.sqrt(0.6 * 0.4 / 20_000)
    want = math.hypot(mc, 0.01)
    assert abs(np.std(vals) / want - 1.0) < 0.2
    assert abs(np.mean(vals) - 0.6) < 5 * want / math.sqrt(200)
    bare = Scene(LAMBERT, seed=1).run(rays=20_000)
    assert np.mean(widths) > 2 * (bare.ci[0, 0, 1] - bare.ci[0, 0, 0])


def test_fast_path_for_a_bare_goniophotometer_scene():
    sc = Scene(GGX(alpha=0.3), instrument="goniophotometer", collector=Collector("equal-psa", 3, 8), delta=1e-4)
    assert sc.uses_fast_path()
    r = sc.run(rays=10**7)
    ref, _ = sc.reference()
    assert r.method == "fast" and ((r.ci[..., 0] <= ref) & (ref <= r.ci[..., 1])).all()
    assert not sc.with_effects(Effects(stray_light=StrayLight(0.01))).uses_fast_path()


def test_effect_costs_rows():
    sc = load_scene(SCENES / "sphere-effects.toml")
    rows = effect_costs(sc, rays=50_000, repeat=1)
    assert rows[0]["effects"].startswith("none") and rows[0]["ratio_to_bare"] == 1.0
    assert rows[0]["method"] == "bare"
    assert [r["effects"] for r in rows[1:-1]] == sc.effects.declared()
    assert rows[-1]["effects"] == "all declared" and rows[-1]["positions_sampled"]
    assert all(r["seconds"] > 0 for r in rows)


def test_near_field_detectors_sample_positions_and_approach_the_far_field():
    """Detectors at 2 m with a 12.5 mm illuminated spot: the near-field acceptance differs from
    the far-field cone by O(spot / distance) ~ 1 %, so the readings agree within 5 sigma + 3 %."""
    sp = OrenNayar(sigma=20.0, albedo=0.8)
    views = ((0.0, 0.0), (30.0, 180.0))
    base = Scene(sp, instrument="goniophotometer", collector=Collector("equal-psa", 3, 8), method="rays", seed=9,
                 incidence=(30.0, 0.0))
    near = base.with_effects(Effects(aperture=Aperture(3.0, views, 2000.0)))
    far = base.with_effects(Effects(aperture=Aperture(3.0, views)))
    assert near.needs_positions and not far.needs_positions
    rn, rf = near.run(rays=1_000_000), far.run(rays=1_000_000)
    assert rn.positions_sampled and np.all(np.isfinite(rn.values))
    nb = base.collector.n_bins
    a, b = rn.values[0, nb:], rf.values[0, nb:]
    sd = (rf.ci[0, nb:, 1] - rf.ci[0, nb:, 0]) / 2 / 3.9
    assert np.all(np.abs(a - b) < 5 * np.sqrt(2) * sd + 0.03 * b)

