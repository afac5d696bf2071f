"""Specimen models: parameters, energy, reciprocity, exact sampling (scatter vs. quadrature), stability.

Statistical tests use fixed seeds. The sampling test is Pearson's chi-square of 10^6 rays from
``scatter`` binned by the collector against the quadrature probabilities (independent code: it
only uses ``bsdf``), with bins of expected count < 5 pooled and absorbed rays as their own bin,
rejected at significance alpha = 1e-4 (about 20 such tests: family-wise false alarm < 2e-3).
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_dist

from bench.core.errors import SpecimenError
from bench.core.geometry import direction
from virtual.collector import Collector
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels import jit
from virtual.quadrature import integrate_patches
from virtual.rng import stream_states
from virtual.kernels.scatter import scatter
from virtual.model_ids import MODEL_LAMBERT
from virtual.specimens import (
    GGX,
    AnisoGGX,
    Lambertian,
    OrenNayar,
    Phong,
    RoughDielectric,
    RoughPlastic,
    Spectral,
    parse_specimen,
)

WL = 550.0
COL = Collector("equal-psa", 9, 36)

SPECS = {
    "lambert": "lambert:albedo=0.5",
    "lambert-t": "lambert:albedo=0.5,transmittance=0.3",
    "ggx-coat": "ggx:alpha=0.2,eta=1.5,k=0",
    "ggx-metal": "ggx:alpha=0.3,eta=0.2,k=3",
    "phong": "phong:exponent=20,ks=0.5,kd=0.3",
    "oren-nayar": "oren-nayar:sigma=20,albedo=0.8",
    "plastic": "plastic:alpha=0.1,eta=1.5,kd=0.5",
    "aniso": "aniso-ggx:alpha_x=0.1,alpha_y=0.4,eta=0.2,k=3",
    "dielectric": "dielectric:alpha=0.2,eta=1.5",
}


@jit
def _histogram(model, p, wx, wy, wz, n, s, sc, nt, nph, s2e, pcs):
    """Counts per collector bin, then absorbed rays in the last cell; also the worst |o| - 1."""
    h = np.zeros(2 * nt * nph + 1, dtype=np.int64)
    worst = 0.0
    for _ in range(n):
        ox, oy, oz, alive = scatter(model, p, wx, wy, wz, s)
        if alive:
            worst = max(worst, abs(math.sqrt(ox * ox + oy * oy + oz * oz) - 1.0))
            if not (worst < 1e-9):  # NaN or not unit: report at once
                worst = 1e300
                break
            h[patch_of(ox, oy, oz, sc, nt, nph, s2e, pcs)] += 1
        else:
            h[-1] += 1
    return h, worst


def shoot(specimen, wi, n, seed, col=COL):
    s = stream_states(seed, 1)[0].copy()
    return _histogram(specimen.model, specimen.params(WL), wi[0], wi[1], wi[2], n, s, *col.kernel_args())


# --- parsing and parameters -----------------------------------------------------------------------


@pytest.mark.parametrize("spec,cls,params", [
    ("lambert:albedo=0.5", Lambertian, [0.5, 0.0]),
    ("ggx:alpha=0.2,eta=1.5,k=0", GGX, [0.2, 0.2, 1.5, 0.0, 0.0]),
    ("ggx:alpha=0.2,masking=separable", GGX, [0.2, 0.2, 1.5, 0.0, 1.0]),
    ("phong:exponent=20,ks=0.5,kd=0.3", Phong, [0.3, 0.5, 20.0, 0.5 * 22 / 21]),
    ("plastic:alpha=0.1,eta=1.5,kd=0.5", RoughPlastic, None),
    ("aniso-ggx:alpha_x=0.1,alpha_y=0.4,eta=0.2,k=3", AnisoGGX, [0.1, 0.4, 0.2, 3.0, 0.0]),
    ("dielectric:alpha=0.2,eta=1.5", RoughDielectric, [0.2, 1.5, 0.0]),
    ("dielectric:alpha=0.2,eta=1.5,masking=separable", RoughDielectric, [0.2, 1.5, 1.0]),
    ("oren-nayar:sigma=20,albedo=0.8", OrenNayar, None),
])
def test_cli_strings_parse(spec, cls, params):
    s = parse_specimen(spec)
    assert type(s) is cls and s.label == spec and s.has_density
    p = s.params(WL)
    assert p.dtype == np.float64 and np.all(np.isfinite(p))
    if params is not None:
        np.testing.assert_allclose(p, params, rtol=1e-15)


def test_param_layouts_derived_values():
    on = parse_specimen("oren-nayar:sigma=20,albedo=0.8").params(WL)
    s2 = math.radians(20) ** 2
    a, b = 1 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    np.testing.assert_allclose(on, [0.8, a, b, 0.8 * a, 1.6 * b / math.pi], rtol=1e-14)
    pl = parse_specimen("plastic:alpha=0.1,eta=1.5,kd=0.5").params(WL)
    # hemispherical average Fresnel of n = 1.5 is 0.0918 (standard tables: 0.092)
    assert pl[:3].tolist() == [0.1, 1.5, 0.5] and 1 / pl[3] == pytest.approx(1 - 0.0918, abs=2e-4)


@pytest.mark.parametrize("spec,name", [
    ("ggx:alpha=0", "alpha"), ("ggx:alpha=1.5", "alpha"), ("ggx:alpha=0.2,eta=-1", "eta"),
    ("ggx:alpha=0.2,k=-0.1", "k"), ("ggx:alpha=nan", "alpha"),
    ("aniso-ggx:alpha_x=0.1,alpha_y=0", "alpha_y"), ("aniso-ggx:alpha_x=2", "alpha_x"),
    ("phong:exponent=-1", "exponent"), ("phong:ks=1.2", "ks"), ("phong:kd=-0.1", "kd"),
    ("phong:exponent=20,ks=0.5,kd=0.5", "ks"),  # kd + ks(n+2)/(n+1) > 1
    ("oren-nayar:sigma=95", "sigma"), ("oren-nayar:albedo=1.2", "albedo"),
    ("oren-nayar:sigma=10,albedo=1", "albedo"),  # albedo (A + 2B/pi) > 1
    ("plastic:eta=0.5", "eta"), ("plastic:kd=2", "kd"), ("plastic:alpha=0", "alpha"),
    ("dielectric:eta=1", "eta"), ("dielectric:alpha=1e-5", "alpha"),
    ("ggx:beta=1", "beta"), ("phong:exponent=x", "exponent"),
])
def test_bad_parameters_name_the_parameter(spec, name):
    with pytest.raises(SpecimenError, match=name):
        parse_specimen(spec)


def test_spectral_parameters():
    g = GGX(alpha=0.1, eta=((400.0, 700.0), (0.2, 0.4)), k=3.0)
    assert g.params(550.0)[2] == pytest.approx(0.3)
    assert g.wavelength_range() == (400.0, 700.0)
    with pytest.raises(SpecimenError, match="eta"):
        g.params(800.0)
    with pytest.raises(SpecimenError, match="ks"):  # a table entry out of range fails at construction
        Phong(exponent=10.0, ks=Spectral.of(((400.0, 700.0), (0.2, 0.99)), "ks"), kd=0.0)


# --- energy -------------------------------------------------------------------------------------------

INCIDENCES = [(0.0, 0.0), (30.0, 20.0), (60.0, 200.0), (85.0, 45.0)]


@pytest.mark.parametrize("key", list(SPECS))
def test_energy_conservation_by_quadrature(key):
    s = parse_specimen(SPECS[key])
    col = Collector("equal-psa", 6, 12)
    for th, ph in INCIDENCES:
        r = integrate_patches(s, direction(th, ph), col, WL)
        assert np.all(r.p >= 0.0)
        assert r.albedo <= 1.0 + 1e-9, (key, th)
        assert r.albedo > 0.0


@pytest.mark.parametrize("spec,th,expected", [
    ("lambert:albedo=0.5,transmittance=0.3", 40.0, 0.8),
    ("phong:exponent=20,ks=0.5,kd=0.3", 0.0, 0.8),  # lobe fits above the horizon: kd + ks exactly
    ("oren-nayar:sigma=20,albedo=0.8", 0.0, None),  # normal incidence: the B term vanishes: rho A
    ("ggx:alpha=0.001,eta=0.2,k=3", 0.0, ((0.2 - 1) ** 2 + 9) / ((0.2 + 1) ** 2 + 9)),  # ~ F(0)
    ("dielectric:alpha=0.001,eta=1.5", 0.0, 1.0),  # nearly smooth: R + T = 1, nothing lost
])
def test_quadrature_against_closed_forms(spec, th, expected):
    s = parse_specimen(spec)
    if expected is None:
        expected = s.params(WL)[3]
    r = integrate_patches(s, direction(th, 0.0), COL, WL)
    # alpha = 1e-3 loses ~1e-6 to masking; the rest is quadrature error
    assert r.albedo == pytest.approx(expected, rel=2e-6)
    if spec.startswith("dielectric"):
        assert r.reflectance == pytest.approx(0.04, rel=1e-4)


def test_lambertian_patch_probabilities_exact():
    p = integrate_patches(Lambertian(reflectance=0.5, transmittance=0.25), direction(35.0, 10.0), COL, WL).p
    np.testing.assert_allclose(p[: COL.n_patches], 0.5 * COL.psa[: COL.n_patches] / math.pi, rtol=1e-12)
    np.testing.assert_allclose(p[COL.n_patches:], 0.25 * COL.psa[COL.n_patches:] / math.pi, rtol=1e-12)


# --- reciprocity and isotropy ------------------------------------------------------------------------


def _random_dirs(rng, n, upper=True):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2]) if upper else -np.abs(v[:, 2])
    return v


def _specimen_and_dirs(key, seed, n_in, n_out):
    """The specimen ``SPECS[key]``, a generator seeded ``seed`` and ``n_in`` then ``n_out`` random
    upper-hemisphere directions drawn from it."""
    rng = np.random.default_rng(seed)
    return parse_specimen(SPECS[key]), rng, _random_dirs(rng, n_in), _random_dirs(rng, n_out)


@pytest.mark.parametrize("key", list(SPECS))
def test_reciprocity(key):
    s, rng, wi, wo = _specimen_and_dirs(key, 5, 40, 40)
    fwd = np.array([s.bsdf(a, b[None, :], WL)[0] for a, b in zip(wi, wo)])
    back = np.array([s.bsdf(b, a[None, :], WL)[0] for a, b in zip(wi, wo)])
    assert np.all(fwd > 0)
    if s.reciprocal:
        np.testing.assert_allclose(fwd, back, rtol=1e-12)
    elif key == "plastic":
        assert not np.allclose(fwd, back, rtol=1e-6)  # documented: not reciprocal
    if key == "dielectric":
        np.testing.assert_allclose(fwd, back, rtol=1e-12)  # its reflection part is reciprocal
        # transmission: f(i -> o) / n_o^2 = f(o -> i) / n_i^2 (flux BTDF), i above (n = 1)
        rough = parse_specimen("dielectric:alpha=1,eta=1.5")  # broad: most random pairs transmit
        wi = _random_dirs(rng, 200)
        wt = _random_dirs(rng, 200, upper=False)
        f_io = np.array([rough.bsdf(a, b[None, :], WL)[0] for a, b in zip(wi, wt)])
        f_oi = np.array([rough.bsdf(b, a[None, :], WL)[0] for a, b in zip(wi, wt)])
        ok = f_io > 1e-300
        assert ok.sum() >= 20  # about 1 in 5 random pairs can be joined by a refraction
        assert np.all((f_oi > 1e-300) == ok)
        np.testing.assert_allclose(f_io[ok] / 1.5 ** 2, f_oi[ok], rtol=1e-10)


def _rotz(v, a):
    c, s = math.cos(a), math.sin(a)
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]])


@pytest.mark.parametrize("key", list(SPECS))
def test_isotropy_flag(key):
    s, _, wi, wo = _specimen_and_dirs(key, 6, 1, 50)
    f = s.bsdf(wi[0], wo, WL)
    fr = s.bsdf(_rotz(wi, 0.7)[0], _rotz(wo, 0.7), WL)
    assert np.allclose(f, fr, rtol=1e-10) == s.isotropic


# --- sampling: scatter agrees with the density ---------------------------------------------------------

SAMPLING_CASES = [
    ("lambert-t", 30.0, 0.0), ("lambert-t", 150.0, 0.0),  # lit from below: R below, T above
    ("ggx-coat", 30.0, 20.0), ("ggx-coat", 89.9, 0.0),
    ("ggx-metal", 0.0, 0.0), ("ggx-metal", 70.0, 120.0),
    ("phong", 0.0, 0.0), ("phong", 60.0, 300.0),
    ("oren-nayar", 40.0, 10.0), ("oren-nayar", 85.0, 250.0),
    ("plastic", 20.0, 0.0), ("plastic", 80.0, 45.0),
    ("aniso", 45.0, 30.0), ("aniso", 45.0, 120.0),
    ("dielectric", 25.0, 0.0), ("dielectric", 70.0, 200.0), ("dielectric", 140.0, 30.0),
]
ALPHA = 1e-4


@pytest.mark.parametrize("key,th,ph", SAMPLING_CASES)
def test_scatter_matches_quadrature(key, th, ph):
    s = parse_specimen(SPECS[key])
    wi = direction(th, ph)
    n = 1_000_000
    h, worst = shoot(s, wi, n, seed=zlib.crc32(repr((key, th, ph)).encode()))
    assert worst < 1e-9  # every scattered direction is a unit vector (and not NaN)
    q = integrate_patches(s, wi, COL, WL)
    p = np.append(q.p, max(0.0, 1.0 - q.albedo))
    assert p.sum() == pytest.approx(1.0, abs=1e-9)
    # energy by Monte Carlo: surviving fraction vs quadrature albedo, binomial z < 4.9 (~1e-6)
    alive = 1.0 - h[-1] / n
    se = math.sqrt(max(q.albedo * (1 - q.albedo), 1e-12) / n)
    assert abs(alive - q.albedo) < 4.9 * se + 1e-12
    e = n * p
    big = e >= 5
    obs = np.append(h[big], h[~big].sum())
    exp = np.append(e[big], e[~big].sum())
    if exp[-1] < 5:  # too little to pool: fold into the largest cell
        i = int(np.argmax(exp[:-1]))
        obs[i] += obs[-1]
        exp[i] += exp[-1]
        obs, exp = obs[:-1], exp[:-1]
    stat = float(np.sum((obs - exp) ** 2 / exp))
    df = len(exp) - 1
    assert df >= 5
    assert chi2_dist.sf(stat, df) > ALPHA, (stat, df)


def test_lambertian_kernel_branch_unchanged():
    # the existing model id and parameter layout are kept
    s = parse_specimen("lambert:reflectance=0.375")
    assert s.model == MODEL_LAMBERT and s.params(WL).tolist() == [0.375, 0.0]


# --- stability: near-delta lobes and grazing incidence -------------------------------------------------

STIFF = ["ggx:alpha=0.0001,eta=1.5,k=0", "ggx:alpha=0.0001,eta=0.2,k=3",
         "aniso-ggx:alpha_x=0.0001,alpha_y=0.0001,eta=0.2,k=3", "aniso-ggx:alpha_x=0.0001,alpha_y=1,eta=2,k=1",
         "plastic:alpha=0.0001,eta=1.5,kd=0.5", "dielectric:alpha=0.0001,eta=1.5",
         "phong:exponent=1000000,ks=0.9,kd=0", "oren-nayar:sigma=90,albedo=1"]


@pytest.mark.parametrize("spec", STIFF)
@pytest.mark.parametrize("th", [0.0, 89.9, 90.0 + 89.9])
def test_stable_for_near_delta_lobes_and_grazing(spec, th):
    s = parse_specimen(spec)
    if th > 90 and not s.transmits(WL):
        th = 180.0 - th  # two-sided opaque models: same from below
    wi = direction(th, 33.0)
    h, worst = shoot(s, wi, 20000, seed=11)
    assert worst < 1e-9 and h.sum() == 20000
    rng = np.random.default_rng(2)
    wo = np.vstack([_random_dirs(rng, 200), _random_dirs(rng, 200, upper=False),
                    [[-wi[0], -wi[1], wi[2]]],  # exact mirror direction: the peak
                    [[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]], [[1.0, 0.0, 0.0]]])
    f = s.bsdf(wi, wo, WL)
    assert np.all(np.isfinite(f)) and np.all(f >= 0.0)
    if "0.0001" in spec and "alpha_y=1" not in spec and th == 0.0:
        # peak F D(n) G2 / 4 >= 0.04 / (4 pi alpha^2) ~ 3e5: resolved, not lost to underflow or NaN
        assert f[400] > 1e5


def test_exact_grazing_incidence_is_absorbed_not_nan():
    for spec in SPECS.values():
        s = parse_specimen(spec)
        h, worst = shoot(s, np.array([1.0, 0.0, 0.0]), 1000, seed=3)
        assert worst < 1e-9 and h.sum() == 1000


# --- declarations: one place per parameter, an open registry -------------------------------------

from virtual.spectrophotometer import VirtualSpectrophotometer  # noqa: E402
from virtual.specimens import (MODEL_PYTHON, SPECIMENS, DeclaredSpecimen, Param,  # noqa: E402
                               register_specimen, specimen_families, specimen_table_markdown)


@pytest.mark.parametrize("spec,message", [
    ("lambert:reflectance=0.5,foo=1", "unknown parameter 'foo' for lambert; accepted: reflectance, transmittance"),
    ("aniso-ggx:alpha=0.9", "unknown parameter 'alpha' for aniso-ggx; accepted: alpha_x, alpha_y, eta, k"),
    ("ggx:alpha_x=0.1", "unknown parameter 'alpha_x' for ggx; accepted: alpha, eta, k"),
    ("oren-nayar:albedo=0.5,R=0.5", "parameter albedo given twice"),
    ("phong:ks=0.1,ks=0.2", "ks given twice"),
])
def test_unknown_or_repeated_parameters_are_refused_naming_the_accepted_ones(spec, message):
    with pytest.raises(SpecimenError) as err:
        parse_specimen(spec)
    assert message in str(err.value)


def test_constructors_refuse_what_they_would_ignore():
    with pytest.raises(SpecimenError, match="unknown parameter 'alpha' for aniso-ggx; accepted: alpha_x, alpha_y"):
        AnisoGGX(alpha=0.9)  # was accepted and silently ignored
    with pytest.raises(SpecimenError, match="accepted: reflectance, transmittance"):
        Lambertian(albedo=0.5)  # aliases are for specimen strings; the constructor takes the names
    with pytest.raises(SpecimenError, match="at most 2 parameters"):
        Lambertian(0.2, 0.3, 0.4)
    assert Lambertian(0.6, 0.1).params(WL).tolist() == [0.6, 0.1]  # positions in the declared order


def test_aliases_and_keyword_defaults_keep_the_old_strings():
    assert parse_specimen("lambert:albedo=0.3").params(WL).tolist() == [0.3, 0.0]
    assert parse_specimen("lambert:R=0.3,T=0.2").params(WL).tolist() == [0.3, 0.2]
    assert parse_specimen("lambert:transmittance=0.7").params(WL).tolist() == [0.0, 0.7]  # a pure transmitter
    assert parse_specimen("phong:n=5,ks=0.1,kd=0.1").params(WL)[2] == 5.0
    assert parse_specimen("oren-nayar:reflectance=0.5").params(WL)[0] == 0.5


def test_every_family_is_listed_with_its_declared_parameters():
    fams = {f["name"]: f for f in specimen_families()}
    assert {"lambert", "oren-nayar", "phong", "ggx", "aniso-ggx", "plastic", "dielectric"} <= set(fams)
    assert [p["name"] for p in fams["phong"]["parameters"]] == ["exponent", "ks", "kd"]
    sigma = fams["oren-nayar"]["parameters"][0]
    assert (sigma["range"], sigma["unit"], sigma["default"]) == ([0.0, 90.0], "degrees", 20.0)
    table = specimen_table_markdown()
    assert table.startswith("| specimen | convention | parameter | range | unit | default | meaning |")
    rows = [r for r in table.splitlines()[2:]]
    assert len(rows) == sum(len(f["parameters"]) for f in fams.values())
    assert "| oren-nayar | Oren & Nayar 1994 qualitative model (A, B form) | `sigma` | 0 .. 90 | degrees | 20 |" in table
    # the conventions a Mitsuba user selects are named in the table, with their choices
    assert "separable = Mitsuba 3 roughconductor" in table and "| roughplastic | Mitsuba 3 roughplastic" in table
    assert "| `masking` | correlated \\| separable | - | correlated |" in table
    # defaults declared are the defaults used
    for name, cls in SPECIMENS.items():
        s = cls()
        for p in cls.parameters:
            assert getattr(s, p.name)(WL) == p.default, (name, p.name)


def test_a_categorical_parameter_takes_its_names_and_refuses_anything_else():
    assert parse_specimen("ggx:masking=separable").params(WL)[4] == 1.0
    assert parse_specimen("dielectric:masking=correlated").params(WL)[2] == 0.0
    for bad, msg in (("ggx:masking=smith", "one of correlated, separable"), ("ggx:masking=0.5", "one of"),
                     ("ggx:alpha=rough", "alpha must be a number")):
        with pytest.raises(SpecimenError, match=msg):
            parse_specimen(bad)


def _lab_velvet() -> type[DeclaredSpecimen]:
    """The velvet family of the lab's plugin package (fixtures/plugins), loaded from its file."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "fixtures/plugins/goniobench-labvelvet/labvelvet/__init__.py"
    spec = importlib.util.spec_from_file_location("labvelvet_in_test_specimens", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.Velvet


class _Velvet(_lab_velvet()):
    """A lab's own model, defined outside the package: a retro-reflector with a diffuse floor."""

    name = "test-velvet"


def test_a_lab_registers_its_own_model_without_editing_ours():
    velvet = register_specimen(_Velvet)
    try:
        s = parse_specimen("test-velvet:retro=0.25,albedo=0.6")
        assert isinstance(s, velvet) and s.params(WL).tolist() == [0.25, 0.6]
        assert "test-velvet" in {f["name"] for f in specimen_families()}
        with pytest.raises(SpecimenError, match="unknown parameter 'sheen' for test-velvet; accepted: retro, albedo"):
            parse_specimen("test-velvet:sheen=1")
        with pytest.raises(SpecimenError, match="retro must lie in"):
            parse_specimen("test-velvet:retro=2")
        with pytest.raises(SpecimenError, match="already taken"):
            register_specimen(type("Other", (DeclaredSpecimen,), {"name": "test-velvet", "model": MODEL_PYTHON}))
        # it measures: everything that survives is reflected (the source is above), at albedo 0.6
        n = 40_000
        sp = VirtualSpectrophotometer("test-velvet:retro=0.25,albedo=0.6", rays=n, seed=11)
        got = float(sp.measure("8/d", [550.0]).reflectance[0])
        assert abs(got - 0.6) < 5 * math.sqrt(0.6 * 0.4 / n)  # 5 se: false alarm < 1e-6
        assert abs(got - 0.8) > 5 * math.sqrt(0.8 * 0.2 / n)  # the declared default would be told apart
    finally:
        from virtual.specimens import declare

        declare._REGISTRY.pop("test-velvet", None)


def test_a_declaration_is_checked_when_registered():
    bad_default = type("Bad", (DeclaredSpecimen,), {"name": "test-bad", "model": MODEL_PYTHON,
                                                   "parameters": (Param("x", 2.0, 0.0, 1.0),)})
    with pytest.raises(SpecimenError, match="x must lie in"):
        register_specimen(bad_default)
    twice = type("Twice", (DeclaredSpecimen,), {"name": "test-twice", "model": MODEL_PYTHON,
                                               "parameters": (Param("x", 0.5, 0.0, 1.0, aliases=("y",)),
                                                              Param("y", 0.5, 0.0, 1.0))})
    with pytest.raises(SpecimenError, match="declared twice"):
        register_specimen(twice)
    with pytest.raises(SpecimenError, match="already taken"):
        register_specimen(type("Cc", (DeclaredSpecimen,), {"name": "colorchecker", "model": MODEL_PYTHON}))


def test_readme_specimen_table_is_the_generated_one():
    """The docs' table (README.md or a page under docs/) is generated from the declarations of the
    project's own families (one place per idea; families registered by tests or plugins are left
    out): `make docs` (``python -m bench.docs``) rewrites it when a family or parameter changes."""
    from bench.docs import page_holding, regenerate

    page = page_holding("specimen-table")
    assert regenerate(page.read_text(encoding="utf-8"))[1] == [], f"{page.name}'s specimen table is out of date: run `make docs`"


def test_the_readme_generator_rewrites_a_stale_table_and_tells_a_family_added_by_a_plugin(tmp_path):
    from bench.docs import main, page_holding
    from virtual.specimens import specimen_table_markdown

    page = page_holding("specimen-table")
    stale = tmp_path / page.name
    stale.write_text(page.read_text(encoding="utf-8").replace("| lambert |", "| lambertian |"), encoding="utf-8")
    assert main(["--check", "--readme", str(stale)]) == 1
    assert main(["--readme", str(stale)]) == 0 and main(["--check", "--readme", str(stale)]) == 0
    assert stale.read_text(encoding="utf-8") == page.read_text(encoding="utf-8")
    fam = type("Velvet", (DeclaredSpecimen,), {"__module__": "labmodels.velvet", "name": "test-velvet-docs",
                                               "model": MODEL_PYTHON, "parameters": (Param("sheen", 0.5, 0.0, 1.0),)})
    register_specimen(fam)
    assert "test-velvet-docs" in specimen_table_markdown() and "test-velvet-docs" not in \
        specimen_table_markdown(builtin_only=True)
    assert main(["--check", "--readme", str(stale)]) == 0
