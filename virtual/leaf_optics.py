"""Leaf optics: PROSPECT-D's spectra and the angular model that carries them.

Spectral core: PROSPECT-D (Féret et al. 2017, Remote Sens. Environ. 193:204-215) from the
``prosail`` package, the directional-hemispherical reflectance R_P and transmittance T_P of a
leaf from 400 to 2500 nm at 1 nm, from its structure N and its absorbers (chlorophyll a+b,
carotenoids, anthocyanins, brown pigments, water, dry matter).

Angular model (after Bousquet et al. 2005, Remote Sens. Environ. 98:201-211: a specular part
from the cuticle plus a nearly Lambertian part from the mesophyll; the two coupled as in
Kelemen & Szirmay-Kalos 2001, "A microfacet based coupled specular-matte BRDF model with
importance sampling", Eurographics short papers):

* a ray meets a visible GGX microfacet m of the wax cuticle (roughness alpha, index eta); with
  probability F(wi.m) it is reflected there and, when the reflection lies above the horizon, it
  leaves with probability ks G2/G1 -- the specular lobe ``ks F D G2 / (4 cos_i cos_o)``, white
  (not coloured by pigments), growing toward grazing incidence with Fresnel. Its albedo is
  ``E(wi) = ks E_s(wi)``;
* every other ray (refracted, or reflected and then caught by the rough surface) enters the
  mesophyll, which sends it up with probability r_b, down with probability t_b, or absorbs it.
  It leaves through the same cuticle in a direction wo drawn from the cosine lobe thinned by
  ``1 - E(wo)`` (the probability that light arriving from wo would have entered: by Helmholtz
  reciprocity, the probability of leaving toward wo), on either face (two-sided).

So the BSDF, with E_avg = 2 int_0^1 E(mu) mu dmu, is

    f_r = ks F D G2 / (4 cos_i cos_o) + r_b (1 - E(wi)) (1 - E(wo)) / (pi (1 - E_avg)),
    f_t =                               t_b (1 - E(wi)) (1 - E(wo)) / (pi (1 - E_avg)),

symmetric in (wi, wo) -- reciprocal in reflection and in transmission -- and

    R(wi) = E(wi) + r_b (1 - E(wi)),      T(wi) = t_b (1 - E(wi)).

r_b and t_b are solved per wavelength so that at 8 deg -- LOPEX's incidence (Hosgood et al.
1995) -- R and T equal PROSPECT-D's exactly: r_b = (R_P - E(8)) / (1 - E(8)), t_b = T_P /
(1 - E(8)), and r_b + t_b <= 1 exactly when R_P + T_P <= 1 (no renormalization ever). ks = 1
unless PROSPECT-D's R_P is below the cuticle's own specular albedo E_s(8) (it can be, in the
strong water bands, where PROSPECT's index n(lambda) falls to ~1.3): there ks = R_P / E_s(8) < 1
and r_b = 0, listed in :attr:`LeafTables.specular_scaled_nm`.

Why not the ``plastic`` coupling (entry 1 - Fbar(wi) through the rough coat, exit 1 - F(cos_o)
through a smooth one, masked specular rays absorbed)? Its diffuse term is not symmetric (at
alpha 0.3, eta 1.5 the BRDF at (0, 70 deg) and (70, 0 deg) differ by several per cent, which a
goniophotometric reciprocity check sees), and its surface loss Fbar - E_s can exceed PROSPECT's
absorption in the near infrared of a thin leaf, where R and T at 8 deg can then not be matched.

Numerics: E_s(theta) and Fbar(theta) are integrals over the visible normals (the sampler's own
spherical-cap parameterization, whose Jacobian is constant). E_s's integrand is cut where the
reflection crosses the horizon; :func:`cuticle_integrals` finds those crossings (dense scan,
then bisection) and integrates each lit segment with Gauss-Legendre, so the rule stays accurate
up to grazing incidence (the plain 48 x 48 tensor rule of :func:`virtual.specimens.physics.
vndf_mean` is not: at alpha 0.05 it is off by 4e-5 even at normal incidence, where the
visible normals of a smooth cuticle turn to the horizon within r2 ~ 1 - alpha^2, so the segments
are also graded toward r2 = 1). :class:`CuticleAlbedo` tabulates E_s for the density
(Chebyshev in theta for cos theta >= 1/2, in log cos theta below: a smooth cuticle's E_s changes
within cos theta ~ alpha of grazing); the table is good to ~2e-5 except within 0.01 deg of
grazing for alpha = 1e-4 (7e-4 there, where cos theta weighs nothing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bench.core.errors import SpecimenError
from bench.core.geometry import gauss_legendre
from virtual.fresnel import np_fresnel_dielectric

__all__ = ["prospect_d", "LeafTables", "leaf_tables", "CuticleAlbedo", "cuticle_albedo", "cuticle_integrals",
           "INCIDENCE_CALIBRATION_DEG", "PROSPECT_RANGE_NM"]

#: the incidence at which the leaf's R and T equal PROSPECT-D's (LOPEX93's, Hosgood et al. 1995)
INCIDENCE_CALIBRATION_DEG = 8.0
#: the wavelengths PROSPECT-D covers (nm)
PROSPECT_RANGE_NM = (400.0, 2500.0)


@lru_cache(maxsize=128)
def prospect_d(n: float, cab: float, car: float, anth: float, cbrown: float, cw: float,
               cm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PROSPECT-D's (wavelengths nm, R, T) at 1 nm from 400 to 2500 nm (``prosail.run_prospect``,
    the first interface averaged over a 40 deg cone as in PROSPECT's own calibration)."""
    import warnings

    import prosail

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # 0/0 for a leaf with no absorber at all
        wl, r, t = prosail.run_prospect(float(n), float(cab), float(car), float(cbrown), float(cw), float(cm),
                                        ant=float(anth), prospect_version="D", alpha=40.0)
    wl, r, t = (np.array(a, dtype=float) for a in (wl, r, t))
    ok = np.all(np.isfinite(r)) and np.all(np.isfinite(t)) and np.all(r >= 0) and np.all(t >= 0) \
        and np.all(r + t <= 1.0 + 1e-12)
    if not ok:
        raise SpecimenError(f"leaf: PROSPECT-D gives no finite R, T in [0, 1] for n={n:g}, cab={cab:g}, car={car:g}, "
                            f"anth={anth:g}, cbrown={cbrown:g}, cw={cw:g}, cm={cm:g} (a leaf needs some absorber: "
                            f"cw or cm > 0)")
    r = np.clip(r, 0.0, 1.0)
    t = np.minimum(np.clip(t, 0.0, 1.0), 1.0 - r)
    for a in (wl, r, t):
        a.setflags(write=False)
    return wl, r, t


# --- the cuticle's integrals over visible normals --------------------------------------------


def _cap_normals(theta: float, alpha: float, u: np.ndarray, v: np.ndarray):
    """Visible normal m (the kernel's spherical-cap map, phi = 2 pi u, r2 = v) for wi at zenith
    theta in the xz plane; returns (c = wi.m, the reflection's z, G2/G1) (any broadcast shape)."""
    st, ct = math.sin(theta), math.cos(theta)
    ni = math.sqrt(alpha * alpha * st * st + ct * ct)
    vx, vz = alpha * st / ni, ct / ni
    q = 1.0 + vz
    sc = np.sqrt(np.maximum(v * q * (2.0 - q * v), 0.0))
    phi = 2.0 * math.pi * u
    hx = sc * np.cos(phi) + vx
    hy = sc * np.sin(phi)
    hz = np.maximum(1.0 - q * v + vz, 0.0)
    mx, my = alpha * hx, alpha * hy
    nn = np.maximum(np.sqrt(mx * mx + my * my + hz * hz), 1e-300)
    mx, my, mz = mx / nn, my / nn, hz / nn
    c = np.clip(st * mx + ct * mz, 0.0, 1.0)
    ox, oy, oz = 2.0 * c * mx - st, 2.0 * c * my, 2.0 * c * mz - ct
    no = np.sqrt(alpha * alpha * (ox * ox + oy * oy) + oz * oz)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(oz > 0.0, (ct + ni) * oz / (ni * oz + no * ct), 0.0)
    return c, oz, np.nan_to_num(g, nan=0.0)


@lru_cache(maxsize=4)
def _gl(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = gauss_legendre(n)
    return 0.5 * (x + 1.0), 0.5 * w


#: breakpoints in r2 = v graded toward v = 1, where the visible normals of a smooth cuticle
#: (alpha -> 0) turn to the horizon within a layer of width ~ alpha^2
_GRADED = np.concatenate([[0.0], 1.0 - 10.0 ** -np.arange(1, 14, dtype=float), [1.0]])


def _segment_sums(theta: float, alpha: float, eta: float, u: np.ndarray, cuts: list[np.ndarray], xv: np.ndarray,
                  wv: np.ndarray, lit_only: bool) -> list[float]:
    """Per azimuth node ``u[k]``, the Gauss-Legendre sum over the segments of ``cuts[k]`` in r2 of
    F(wi.m) (times G2/G1 where the reflection is above the horizon, only on such segments, when
    ``lit_only``). Every node's segments are evaluated in one array (a loop over 64 nodes spent
    its time in numpy's per-call overhead), each node's terms then summed on their own, so each
    sum is the one a node-by-node evaluation gives, bit for bit."""
    ends = [(c[:-1][c[1:] > c[:-1]], c[1:][c[1:] > c[:-1]]) for c in cuts]
    owner = np.repeat(np.arange(len(cuts)), [len(a) for a, _ in ends])
    a = np.concatenate([a for a, _ in ends])
    b = np.concatenate([b for _, b in ends])
    if lit_only:
        _, ozm, _ = _cap_normals(theta, alpha, u[owner], 0.5 * (a + b))
        lit = ozm > 0.0
        a, b, owner = a[lit], b[lit], owner[lit]
    vv = a[:, None] + (b - a)[:, None] * xv[None, :]
    cc, _, g = _cap_normals(theta, alpha, np.repeat(u[owner][:, None], len(xv), axis=1), vv)
    f = np_fresnel_dielectric(cc, eta) * (g if lit_only else 1.0)
    terms = (b - a)[:, None] * wv[None, :] * f
    stops = np.cumsum(np.bincount(owner, minlength=len(cuts)))
    return [float(np.sum(terms[lo:hi])) if hi > lo else 0.0 for lo, hi in zip(np.concatenate([[0], stops[:-1]]), stops)]


def cuticle_integrals(theta: float, alpha: float, eta: float, nodes: int = 32,
                      scan: int = 256) -> tuple[float, float]:
    """(E_s, Fbar) at incidence ``theta`` (radians) for a GGX cuticle (alpha, eta).

    E_s = mean over wi's visible normals of F(wi.m) [reflection above the horizon] G2/G1: the
    albedo of the specular lobe (only the reflections the sampler keeps); Fbar = mean of
    F(wi.m). Gauss-Legendre with ``2 nodes`` points in azimuth (over half the circle: the
    integrand is even in phi) and ``nodes`` per segment in r2: segments graded toward r2 = 1
    (:data:`_GRADED`) and cut where the reflection crosses the horizon (found on a
    ``scan``-point grid, refined by bisection to ~1e-15).
    """
    theta = min(max(float(theta), 0.0), math.pi / 2 - 1e-12)
    xu, wu = _gl(2 * nodes)
    u = 0.5 * xu  # phi in [0, pi]; the weights of the half circle, doubled, are wu
    xv, wv = _gl(nodes)
    grid = np.unique(np.concatenate([np.linspace(0.0, 1.0, scan + 1), _GRADED]))
    _, oz, _ = _cap_normals(theta, alpha, u[:, None], grid[None, :])
    up = oz > 0.0
    iu, iv = np.nonzero(up[:, 1:] != up[:, :-1])
    lo, hi = grid[iv].copy(), grid[iv + 1].copy()
    lo_up = up[iu, iv]
    for _ in range(52):  # bisection on every crossing at once
        mid = 0.5 * (lo + hi)
        _, ozm, _ = _cap_normals(theta, alpha, u[iu], mid)
        same = (ozm > 0.0) == lo_up
        lo = np.where(same, mid, lo)
        hi = np.where(same, hi, mid)
    roots = 0.5 * (lo + hi)
    fbar_k = _segment_sums(theta, alpha, eta, u, [_GRADED] * len(u), xv, wv, False)
    es_k = _segment_sums(theta, alpha, eta, u, [np.unique(np.concatenate([_GRADED, roots[iu == k]]))
                                               for k in range(len(u))], xv, wv, True)
    es = fbar = 0.0
    for k in range(len(u)):  # in node order, as the sums always were
        fbar += wu[k] * fbar_k[k]
        es += wu[k] * es_k[k]
    return es, fbar


_CHEB_NODES = 33
#: E_s is tabulated in theta for cos(theta) >= MU_SPLIT and in log(cos theta) below it (a
#: smooth cuticle's albedo changes within cos(theta) ~ alpha of grazing: a layer in log mu)
_MU_SPLIT = 0.5
_MU_MIN = 1e-9


class _Chebyshev:
    """Barycentric interpolation on Chebyshev-Lobatto nodes of [a, b] (Berrut & Trefethen 2004)."""

    def __init__(self, a: float, b: float, func, n: int = _CHEB_NODES) -> None:
        k = np.arange(n)
        self.x = a + 0.5 * (b - a) * (1.0 + np.cos(math.pi * k / (n - 1)))
        self.w = np.where((k == 0) | (k == n - 1), 0.5, 1.0) * (-1.0) ** k
        self.f = np.array([func(x) for x in self.x])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        d = x[..., None] - self.x
        exact = d == 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            q = self.w / d
            val = (q @ self.f) / q.sum(axis=-1)
        hit = exact.any(axis=-1)
        return np.where(hit, self.f[np.argmax(exact, axis=-1)], val) if np.any(hit) else val


class CuticleAlbedo:
    """E_s of a GGX cuticle as a function of |cos theta|, tabulated (Chebyshev in theta above
    cos theta = 1/2, in log cos theta below), and E_avg = 2 int_0^1 E_s(mu) mu dmu."""

    def __init__(self, alpha: float, eta: float) -> None:
        self.alpha, self.eta = float(alpha), float(eta)
        es = lambda t: cuticle_integrals(t, self.alpha, self.eta)[0]  # noqa: E731
        self._near = _Chebyshev(0.0, math.acos(_MU_SPLIT), es)
        self._grazing = _Chebyshev(math.log(_MU_MIN), math.log(_MU_SPLIT), lambda s: es(math.acos(math.exp(s))))
        x, w = gauss_legendre(64)
        m1, w1 = _MU_SPLIT + 0.5 * (1.0 - _MU_SPLIT) * (x + 1.0), 0.5 * (1.0 - _MU_SPLIT) * w
        m0, w0 = 0.5 * _MU_SPLIT * (x + 1.0), 0.5 * _MU_SPLIT * w
        self.average = float(2.0 * (np.sum(w1 * m1 * self(m1)) + np.sum(w0 * m0 * self(m0))))

    def __call__(self, mu: np.ndarray) -> np.ndarray:
        """E_s at |cos theta| = ``mu``."""
        mu = np.clip(np.abs(np.asarray(mu, dtype=float)), _MU_MIN, 1.0)
        near = mu >= _MU_SPLIT
        out = np.empty(mu.shape)
        out[near] = self._near(np.arccos(mu[near]))
        out[~near] = self._grazing(np.log(mu[~near]))
        return out


@lru_cache(maxsize=64)
def cuticle_albedo(alpha: float, eta: float) -> CuticleAlbedo:
    """The (cached) :class:`CuticleAlbedo` of a cuticle."""
    return CuticleAlbedo(alpha, eta)


# --- the per-wavelength body, solved at 8 deg -------------------------------------------------


@dataclass(frozen=True)
class LeafTables:
    """Per-wavelength body parameters of a leaf, solved at the calibration incidence."""

    wavelengths: np.ndarray       # nm, 1 nm steps
    prospect_r: np.ndarray        # PROSPECT-D's R
    prospect_t: np.ndarray        # PROSPECT-D's T
    body_r: np.ndarray            # r_b
    body_t: np.ndarray            # t_b
    specular_scale: np.ndarray    # ks (1 except where R_P < E_s(8))
    es8: float                    # the cuticle's specular albedo E_s at 8 deg (ks = 1)
    fbar8: float                  # its mean Fresnel reflectance at 8 deg (for reference)

    @property
    def specular_scaled_nm(self) -> np.ndarray:
        return self.wavelengths[self.specular_scale < 1.0]

    def at(self, wavelength_nm: float) -> tuple[float, float, float, float, float]:
        """(R_P, T_P, r_b, t_b, ks) at a wavelength (linear between the 1 nm samples)."""
        lo, hi = PROSPECT_RANGE_NM
        if not lo <= wavelength_nm <= hi:
            raise SpecimenError(f"leaf: wavelength {wavelength_nm:g} nm lies outside PROSPECT-D's "
                                f"{lo:g}-{hi:g} nm")
        w = self.wavelengths
        i = float(np.interp(wavelength_nm, w, np.arange(w.size)))
        j = min(int(i), w.size - 2)
        f = i - j
        return tuple(float((1.0 - f) * a[j] + f * a[j + 1]) for a in  # type: ignore[return-value]
                     (self.prospect_r, self.prospect_t, self.body_r, self.body_t, self.specular_scale))


def leaf_tables(prospect: tuple[np.ndarray, np.ndarray, np.ndarray], es8: float, fbar8: float = float("nan")
                ) -> LeafTables:
    """Solve r_b, t_b, ks per wavelength so that R(8 deg) = R_P and T(8 deg) = T_P exactly.

    Between the 1 nm samples the tables are interpolated linearly; R(8) = E + r_b (1 - E) and
    T(8) = t_b (1 - E) are linear in r_b, t_b at fixed ks (and R = ks E_s in ks where r_b = 0), so
    the interpolated leaf matches the interpolated PROSPECT-D (except in the one 1 nm step where
    ks leaves 1, by a product term of order 1e-5).
    """
    wl, rp, tp = prospect
    if not 0.0 <= es8 < 1.0:
        raise SpecimenError(f"leaf: cuticle specular albedo {es8} out of [0, 1)")
    ks = np.ones_like(rp)
    low = rp < es8
    if es8 > 0.0:
        ks[low] = rp[low] / es8
    e = ks * es8
    rb = np.clip((rp - e) / (1.0 - e), 0.0, 1.0)
    tb = np.clip(tp / (1.0 - e), 0.0, 1.0 - rb)
    return LeafTables(wl, rp, tp, rb, tb, ks, float(es8), float(fbar8))


