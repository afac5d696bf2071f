"""Mitsuba 3's ``roughplastic`` as a native specimen (numpy density and sampler; kernel model
``MODEL_ROUGHPLASTIC``, :mod:`virtual.kernels.coat`).

Mitsuba's definition (``src/bsdfs/roughplastic.cpp``, GGX with visible-normal sampling): a
specular GGX coat of relative index eta with *separable* Smith masking, over a Lambertian base
of reflectance kd seen through the coat:

    f = F(wi.h) D(h) G1(wi) G1(wo) / (4 cos_i cos_o)
        + kd' t(cos_i) t(cos_o) / (pi eta^2),      kd' = kd / (1 - R_int)     (nonlinear = false)
                                                   kd' = kd / (1 - kd R_int)  (nonlinear = true)

t(mu) = the coat's rough transmittance at cos theta = mu (refracted rays that pass the
masking, E[(1 - F) G1(wt)] over the visible normals) is tabulated at 64 cosines
mu_i = max(1e-6, i / 63) and interpolated linearly (``lerp_gather``); R_int = 2 mean_i(R(mu_i;
1/eta) mu_i) is the coat's internal reflectance, the mean over the same 64 nodes of the
specular albedo seen from inside. The table entries are computed by Mitsuba's own fixed
quadrature (:mod:`virtual.specimens.coat_quadrature`): the converged albedos differ from them
by up to ~1e-3 of the diffuse term, which 10^8 rays detect.

The model does not conserve energy by construction; a combination whose diffuse albedo exceeds
what the coat lets through (``kd' (2 int t mu dmu) / eta^2 > 1``) is refused.

Sampling (exact, so ray counting and the fast path measure the same thing): a visible normal
m, mirror reflection, kept with probability F(wi.m) G1(wo) -- the specular term. Otherwise (the
remaining probability is exactly 1 - albedo_spec(wi), which the table's t(cos_i) interpolates)
the ray goes to the base with probability c t(cos_i) / (1 - albedo_spec(wi)) (<= 1 since
t <= 1 - albedo_spec and c <= 1), c = kd' 2 int t
mu dmu / eta^2, and leaves with a direction of density t(cos_o) cos_o / (pi 2 int t mu dmu)
(a cosine direction kept with probability t(cos_o), redrawn otherwise).

The kernels (ray by ray, and the float64 block kernel of :mod:`virtual.kernels.block_coat`)
sample the same way. Their parameter vector carries the 64-node table t (:meth:`kernel_params`)
and, appended per measurement by the engine (:func:`incidence_params`), a table of the specular
albedo E_spec over the cosines of incidence the beam delivers: no formulation of the split
between the two lobes without E_spec was found (the base must get c t(cos_i) of *all* rays, and
only 1 - E_spec of them are left once the specular roll failed). A collimated beam has one
cosine, where E_spec is computed as the Python sampler computes it (no interpolation); a conical
beam's cosines (bounded by :func:`beam_cosines`) get E_spec on nodes uniform in sqrt(1 - mu)
(E_spec is smooth in it, not in mu at normal incidence) read by four-point Lagrange
interpolation, the nodes doubled until the interpolant of the coarser table matches E_spec at
the finer table's new nodes within :data:`E_TABLE_TOL` = 1e-6 of 1 - E_spec; the finer table is
used -- so the base's probability c t / (1 - E_spec) is off by less than that fraction (tested
against E_spec at random cosines, tests/test_block_coat.py; 1e9 rays detect ~1e-5). block32 does not run this family (the
tables would need float32 error bounds of their own).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Mapping

import numpy as np

from bench.core.errors import SpecimenError
from virtual.kernel_codes import (B_AXIS_Z, B_DISTANCE, B_EMITTER_RADIUS, B_SPECIMEN_RADIUS, BEAM_COLLIMATED,
                                  RP_TABLE)
from virtual.model_ids import MODEL_ROUGHPLASTIC
from virtual.specimens.coat_quadrature import mitsuba_rough_reflectance, mitsuba_rough_transmittance
from virtual.specimens.declare import DeclaredSpecimen, Param, register_specimen
from virtual.specimens.microfacet import ALPHA_MAX, ALPHA_MIN, mirror_lobe
from virtual.specimens.physics import (local, np_fresnel_dielectric, np_g2_over_g1, np_ggx_reflection,
                                       vndf_expectation, vndf_normals)

__all__ = ["MitsubaRoughPlastic", "TABLE_RES", "coat_tables", "E_TABLE_TOL", "beam_cosines", "albedo_table",
           "incidence_params"]

#: Mitsuba's MI_ROUGH_TRANSMITTANCE_RES
TABLE_RES = 64


@lru_cache(maxsize=4096)
def _specular_albedo(mu: float, alpha: float, eta: float, rtol: float = 1e-9) -> float:
    """E[F(wi.m) G1(wo)] over the visible normals of wi = (sqrt(1 - mu^2), 0, mu): the rough
    coat's specular albedo under separable masking (Mitsuba's ``eval_reflectance``)."""
    w = np.array([math.sqrt(max(1.0 - mu * mu, 0.0)), 0.0, mu])

    def g(m: np.ndarray) -> np.ndarray:
        c = np.clip(m @ w, 0.0, 1.0)
        o = 2.0 * c[:, None] * m - w
        return np_fresnel_dielectric(c, eta) * np_g2_over_g1(w, o, alpha, alpha, "separable")

    return vndf_expectation(w, alpha, alpha, g, rtol=rtol, atol=rtol * 1e-2)[0]


@lru_cache(maxsize=64)
def coat_tables(alpha: float, eta: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``(mu nodes, t(mu) at the nodes, R_int)`` as Mitsuba builds them (see the module docstring)."""
    mu = np.maximum(1e-6, np.arange(TABLE_RES) / (TABLE_RES - 1))
    t = np.array([mitsuba_rough_transmittance(float(m), alpha, eta) for m in mu])
    r_int = 2.0 * float(np.mean([mitsuba_rough_reflectance(float(m), alpha, 1.0 / eta) * m for m in mu]))
    return mu, t, r_int


def _lerp_gather(table: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Mitsuba's ``lerp_gather``: linear interpolation on the uniform grid i / (size - 1)."""
    size = len(table)
    x = np.asarray(x, dtype=float) * (size - 1)
    idx = np.minimum(np.maximum(x, 0.0).astype(np.int64), size - 2)
    w1 = x - idx
    return (1.0 - w1) * table[idx] + w1 * table[idx + 1]


def _t_mu_integral(t: np.ndarray) -> float:
    """2 int_0^1 t(mu) mu dmu for the piecewise-linear interpolant on the grid i / (n - 1) (exact)."""
    n = len(t)
    h = 1.0 / (n - 1)
    a = np.arange(n - 1) * h
    t0, t1 = t[:-1], t[1:]
    # int over [a, a + h] of (t0 + (t1 - t0) (mu - a) / h) mu dmu
    seg = t0 * (a * h + h * h / 2) + (t1 - t0) * (a * h / 2 + h * h / 3)
    return 2.0 * float(seg.sum())


@register_specimen
class MitsubaRoughPlastic(DeclaredSpecimen):
    """Mitsuba 3's ``roughplastic`` (GGX, visible-normal sampling): specular coat with separable
    masking over a Lambertian base through tabulated coat transmittances (see the module
    docstring). Opaque, one-sided as in Mitsuba (mirrored for light from below, like every
    opaque model here). Declared parameters ``alpha, eta, kd, nonlinear``; the kernel's vector is
    ``[alpha, eta, kd_eff, c, t(mu_0..mu_63)]`` (:mod:`virtual.kernels.coat`)."""

    name = "roughplastic"
    model = MODEL_ROUGHPLASTIC
    has_density = True
    opaque = True
    reciprocal = True
    convention = "Mitsuba 3 roughplastic (GGX, separable masking, 64-node coat tables)"
    parameters = (Param("alpha", 0.1, ALPHA_MIN, ALPHA_MAX, doc="coat roughness (GGX)"),
                  Param("eta", 1.49, 1.0 + 1e-3, 10.0, doc="coat relative index (Mitsuba: int_ior / ext_ior)"),
                  Param("kd", 0.5, 0.0, 1.0, doc="diffuse_reflectance of the base"),
                  Param("nonlinear", 0.0, 0.0, 1.0, doc="Mitsuba's internal-scattering nonlinearity",
                        choices=("false", "true")))

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:
        a, eta, kd, nl = v["alpha"], v["eta"], v["kd"], v["nonlinear"]
        _, t, r_int = coat_tables(float(a), float(eta))
        kd_eff = kd / (1.0 - (kd * r_int if nl else r_int))
        c = kd_eff * _t_mu_integral(t) / (eta * eta)
        if c > 1.0 + 1e-12:
            raise SpecimenError(f"roughplastic: kd = {kd:g} gives a diffuse albedo factor {c:.6g} > 1 for "
                                f"alpha = {a:g}, eta = {eta:g} (not energy conserving)")
        return np.concatenate([[a, eta, kd_eff, c], t])

    # -- density ---------------------------------------------------------------------------
    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, kd_eff, _ = self.params(wavelength_nm)[:RP_TABLE]
        _, t, _ = coat_tables(float(a), float(eta))
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        spec = np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta), "separable")
        zo = np.maximum(wo[:, 2], 0.0)
        diff = kd_eff * _lerp_gather(t, wi[2]) * _lerp_gather(t, zo) / (math.pi * eta * eta)
        return spec + np.where(wo[:, 2] > 0.0, diff, 0.0)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        a = float(self.params(wavelength_nm)[0])
        return [mirror_lobe(wi, a, a)]

    def albedo_reference(self, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
        """The specular albedo over the visible normals plus the diffuse albedo in closed form
        (c t(cos_i), the interpolant integrated exactly): no density evaluated."""
        a, eta, _, c = self.params(wavelength_nm)[:RP_TABLE]
        _, t, _ = coat_tables(float(a), float(eta))
        w = np.asarray(wi, dtype=float).reshape(3)
        w = w / np.linalg.norm(w)
        mu = abs(float(w[2]))
        spec = _specular_albedo(mu, float(a), float(eta)) if mu > 0 else 0.0
        return spec + c * float(_lerp_gather(t, mu)), 1e-9

    # -- sampler (numpy: the kernels' reference) ---------------------------------------------------------------
    def sample(self, wi: np.ndarray, n: int, wavelength_nm: float,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``n`` outgoing directions and survival flags (see the module docstring)."""
        a, eta, _, c = self.params(wavelength_nm)[:RP_TABLE]
        _, t, _ = coat_tables(float(a), float(eta))
        w0 = np.asarray(wi, dtype=float)
        if w0.ndim == 2:  # one incidence per ray: sample each distinct one (conical beams)
            dirs = np.zeros((n, 3))
            alive = np.zeros(n, dtype=bool)
            for k in range(n):
                d, al = self.sample(w0[k], 1, wavelength_nm, rng)
                dirs[k], alive[k] = d[0], al[0]
            return dirs, alive
        flip = w0[2] < 0.0
        w = w0 * np.array([1.0, 1.0, -1.0]) if flip else w0
        dirs = np.zeros((n, 3))
        alive = np.zeros(n, dtype=bool)
        if not w[2] > 0.0 or n == 0:
            return dirs, alive
        u = rng.random((n, 4))
        m, _ = vndf_normals(w, a, a, u[:, 0], np.arccos(1.0 - 2.0 * u[:, 1]) / math.pi)  # r2 = u1
        cm = np.clip(m @ w, 0.0, 1.0)
        o = 2.0 * cm[:, None] * m - w
        keep = np_fresnel_dielectric(cm, eta) * np_g2_over_g1(w, o, a, a, "separable")
        spec = u[:, 2] < keep
        dirs[spec], alive[spec] = o[spec], True
        rest = ~spec
        # the specular path left exactly 1 - albedo_spec(wi) of the rays; send c t(cos_i) of all
        left = 1.0 - _specular_albedo(float(w[2]), float(a), float(eta))
        p_base = c * float(_lerp_gather(t, w[2])) / max(left, 1e-300)
        if p_base > 1.0 + 1e-9:
            raise SpecimenError(f"roughplastic: the base needs {p_base:.6g} > 1 of the rays the coat lets through")
        base = rest & (rng.random(n) < p_base)
        k = int(base.sum())
        out = np.zeros((k, 3))
        todo = np.arange(k)
        while len(todo):  # cosine directions thinned by t(cos_o); ends with probability 1
            x = rng.random((len(todo), 3))
            r = np.sqrt(x[:, 0])
            ph = 2.0 * math.pi * x[:, 1]
            d = np.column_stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(np.maximum(1.0 - x[:, 0], 0.0))])
            ok = x[:, 2] < _lerp_gather(t, d[:, 2])
            out[todo[ok]] = d[ok]
            todo = todo[~ok]
        dirs[base], alive[base] = out, True
        if flip:
            dirs[:, 2] = -dirs[:, 2]
        return dirs, alive


# -- the specular albedo table the kernels read (see the module docstring) -------------------------

#: Largest interpolation error of :func:`albedo_table`'s coarser table at the finer one's new
#: nodes, relative to 1 - E_spec (the finer table, the one used, is closer still).
E_TABLE_TOL = 1e-6
#: Most nodes :func:`albedo_table` tries before refusing the beam.
E_TABLE_MAX_NODES = 257
#: Smallest cosine tabulated (rays below it read E_spec there; their share of a beam is negligible).
MU_MIN = 1e-6


#: Margin (rad) added on each side of the sampled range of a conical beam's angles of incidence.
ANGLE_MARGIN = math.radians(0.25)


def beam_cosines(beam_kind: int, beam_args: np.ndarray) -> tuple[float, float]:
    """Bounds (lo, hi) of |cos theta| of the rays a beam delivers (:meth:`virtual.beam.Beam.kernel_args`).
    Collimated: the axis's. Conical: a ray joins an emitter point R (x1, y1, D) to a specimen
    point (x2, y2, 0); the extreme angles of these vectors (a convex set: the extremes lie on its
    boundary) are taken over the two disks' rims and an inner circle each (cached), widened by
    :data:`ANGLE_MARGIN`; the normal is included when atan((r1 + r2) / (D - r2)), a bound on the
    angle to the axis, reaches it. Rays outside read the table's end (the kernels clamp)."""
    return _beam_cosines(int(beam_kind), tuple(float(v) for v in np.asarray(beam_args, dtype=np.float64)))


@lru_cache(maxsize=1024)
def _beam_cosines(beam_kind: int, args: tuple[float, ...]) -> tuple[float, float]:
    b = np.array(args)
    mu0 = min(abs(float(b[B_AXIS_Z])), 1.0)
    if beam_kind == BEAM_COLLIMATED:
        return mu0, mu0
    r1, r2, d = float(b[B_EMITTER_RADIUS]), float(b[B_SPECIMEN_RADIUS]), float(b[B_DISTANCE])
    delta = math.atan2(r1 + r2, d - r2) if d > r2 else math.pi
    theta = math.acos(mu0)
    phi = np.linspace(0.0, 2.0 * math.pi, 120, endpoint=False)  # 3 deg apart: the rims' chords miss ~1e-3 deg
    ring = np.concatenate([[[0.0, 0.0]], *[k * np.column_stack([np.cos(phi), np.sin(phi)]) for k in (0.5, 1.0)]])
    origin = np.column_stack([r1 * ring, np.full(len(ring), d)]) @ b[:9].reshape(3, 3).T
    v = origin[:, None, :] - np.column_stack([r2 * ring, np.zeros(len(ring))])[None, :, :]
    wz = v[..., 2] / np.sqrt(np.einsum("ijk,ijk->ij", v, v))
    ang = np.arccos(np.clip(np.abs(wz[wz * b[B_AXIS_Z] > 0.0]), 0.0, 1.0))
    lo = math.cos(min(float(ang.max()) + ANGLE_MARGIN, 0.5 * math.pi))
    hi = 1.0 if theta <= delta else math.cos(max(float(ang.min()) - ANGLE_MARGIN, 0.0))
    return lo, hi


def lagrange4(values: np.ndarray, lo: float, hi: float, s: np.ndarray) -> np.ndarray:
    """The kernels' :func:`~virtual.kernels.coat.rp_e` in numpy: four-point Lagrange on n uniform
    nodes over [lo, hi], at ``s`` (clamped)."""
    n = len(values)
    x = (np.clip(s, lo, hi) - lo) / (hi - lo) * (n - 1)
    i = np.clip(x.astype(np.int64) - 1, 0, n - 4)
    t = x - i
    t1, t2, t3 = t - 1.0, t - 2.0, t - 3.0
    return (-t1 * t2 * t3 * values[i] + 3.0 * t * t2 * t3 * values[i + 1] - 3.0 * t * t1 * t3 * values[i + 2]
            + t * t1 * t2 * values[i + 3]) / 6.0


#: Relative tolerance of the table's E_spec values (the adaptive cubature's; 1e-9 costs 3-4x
#: and moves them by ~1e-9, a thousandth of what the table is certified to).
E_NODE_RTOL = 1e-8


def _e_of_s(s: np.ndarray, alpha: float, eta: float) -> np.ndarray:
    return np.array([_specular_albedo(float(1.0 - v * v), alpha, eta, E_NODE_RTOL) for v in np.atleast_1d(s)])


@lru_cache(maxsize=256)
def albedo_table(alpha: float, eta: float, lo: float, hi: float) -> tuple[float, float, np.ndarray]:
    """``(s_lo, s_hi, E_spec at n nodes uniform in s = sqrt(1 - mu) over [s_lo, s_hi])`` for the
    cosines mu in [lo, hi]: one cosine (lo == hi) gets four copies of its exact E_spec over
    [s, s + 1] (the kernels read the first); a range gets 9, 17, ... nodes, the first table whose
    coarser half interpolates E_spec at its other nodes within :data:`E_TABLE_TOL` (1 - E_spec)."""
    hi = max(float(hi), MU_MIN)
    lo = min(max(float(lo), MU_MIN), hi)
    if hi - lo < 1e-12:
        s = math.sqrt(1.0 - hi)
        return s, s + 1.0, np.full(4, _specular_albedo(hi, alpha, eta))
    a, b = math.sqrt(1.0 - hi), math.sqrt(1.0 - lo)
    n = 5
    values = _e_of_s(np.linspace(a, b, n), alpha, eta)
    while True:
        mid = np.linspace(a, b, 2 * n - 1)[1::2]
        new = _e_of_s(mid, alpha, eta)
        err = np.abs(lagrange4(values, a, b, mid) - new) / np.maximum(1.0 - new, 1e-300)
        both = np.empty(2 * n - 1)
        both[0::2], both[1::2] = values, new
        if err.max() <= E_TABLE_TOL:
            return a, b, both
        n, values = 2 * n - 1, both
        if n > E_TABLE_MAX_NODES:
            raise SpecimenError(f"roughplastic: the specular albedo over the cosines [{lo:.6g}, {hi:.6g}] "
                                f"(alpha = {alpha:g}, eta = {eta:g}) needs more than {E_TABLE_MAX_NODES} table nodes; "
                                "a narrower or collimated beam (and no integrating sphere) needs fewer")


def incidence_params(params: np.ndarray, beam_kind: int, beam_args: np.ndarray, hemisphere: bool = False) -> np.ndarray:
    """The kernel vector of one measurement: ``params`` (:meth:`MitsubaRoughPlastic.kernel_params`,
    one row or a table of rows) with the specular albedo table appended (``s_lo, s_hi, n, E...``,
    :mod:`virtual.kernels.coat`) over the beam's cosines, or over all of them (``hemisphere``:
    an integrating sphere lights the specimen from every direction; a long table). Raises
    :class:`SpecimenError` when the base would need more rays than the coat lets through (as
    :meth:`MitsubaRoughPlastic.sample`) or the table cannot be certified."""
    p = np.asarray(params, dtype=np.float64)
    if p.ndim == 2:
        return np.array([incidence_params(row, beam_kind, beam_args, hemisphere) for row in p])
    a, eta, _, c = (float(v) for v in p[:RP_TABLE])
    t = p[RP_TABLE:RP_TABLE + TABLE_RES]
    lo, hi, values = albedo_table(a, eta, *((MU_MIN, 1.0) if hemisphere else beam_cosines(beam_kind, beam_args)))
    s = np.linspace(lo, hi, len(values)) if len(values) > 4 else np.array([lo])  # 4 nodes: one cosine
    need = c * _lerp_gather(t, 1.0 - s * s) / np.maximum(1.0 - values[:len(s)], 1e-300)
    if need.max() > 1.0 + 1e-9:
        raise SpecimenError(f"roughplastic: the base needs {need.max():.6g} > 1 of the rays the coat lets through")
    return np.concatenate([p[:RP_TABLE + TABLE_RES], [lo, hi, float(len(values))], values])
