"""Leaf optics: PROSPECT-D's spectra and the angular model that carries them.

Spectral core: PROSPECT-D (Féret et al. 2017, Remote Sens. Environ. 193:204-215) from the
``prosail`` package, the directional-hemispherical reflectance R_P and transmittance T_P of a
leaf from 400 to 2500 nm at 1 nm, from its structure N and its absorbers (chlorophyll a+b,
carotenoids, anthocyanins, brown pigments, water, dry matter).

Angular model (after Bousquet et al. 2005, Remote Sens. Environ. 98:201-211: a specular part
from the cuticle plus a nearly Lambertian part from the mesophyll; the coupling of the two is
Kelemen & Szirmay-Kalos 2001's energy-conserving coat, the same as the ``plastic`` specimen):

* a ray meets a visible GGX microfacet m of the wax cuticle (roughness alpha, index eta);
  with probability F(wi.m) it is reflected there (kept with probability G2/G1): the specular
  lobe ``ks F D G2 / (4 cos_i cos_o)``, white (not coloured by pigments), growing toward
  grazing incidence with Fresnel;
* otherwise it enters the mesophyll and leaves diffusely up with probability r_b (the body
  reflectance), down with probability t_b (the body transmittance), or is absorbed; a diffuse
  ray leaves through the smooth cuticle with density (1 - F(|cos_o|)) |cos_o| / (pi (1 - F_avg)).

Hence, with Fbar(wi) the mean entry Fresnel over wi's visible normals and E_s(wi) the
specular lobe's albedo,

    R(wi) = E_s(wi) + r_b (1 - Fbar(wi)),      T(wi) = t_b (1 - Fbar(wi)).

r_b and t_b are solved per wavelength so that at 8 deg -- LOPEX's incidence -- R and T equal
PROSPECT-D's exactly: r_b = (R_P - ks E_s(8)) / (1 - Fbar(8)), t_b = T_P / (1 - Fbar(8)).
ks = 1 unless PROSPECT-D's R_P is below the cuticle's own specular albedo (it can be, in strong
water bands, where PROSPECT's index n(lambda) falls to ~1.3): there ks = R_P / E_s(8) < 1 and
r_b = 0, said in :attr:`LeafTables.specular_scaled_nm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bench.core.errors import SpecimenError

__all__ = ["prospect_d", "LeafTables", "leaf_tables", "INCIDENCE_CALIBRATION_DEG", "PROSPECT_RANGE_NM"]

#: the incidence at which the leaf's R and T equal PROSPECT-D's (LOPEX93's, Hosgood et al. 1995)
INCIDENCE_CALIBRATION_DEG = 8.0
#: the wavelengths PROSPECT-D covers (nm)
PROSPECT_RANGE_NM = (400.0, 2500.0)


@lru_cache(maxsize=128)
def prospect_d(n: float, cab: float, car: float, anth: float, cbrown: float, cw: float,
               cm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PROSPECT-D's (wavelengths nm, R, T) at 1 nm from 400 to 2500 nm (``prosail.run_prospect``)."""
    import warnings

    import prosail

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # 0/0 for a leaf with no absorber at all
        wl, r, t = prosail.run_prospect(float(n), float(cab), float(car), float(cbrown), float(cw), float(cm),
                                        ant=float(anth), prospect_version="D", alpha=40.0)
    wl, r, t = (np.asarray(a, dtype=float) for a in (wl, r, t))
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
        raise SpecimenError(f"leaf: PROSPECT-D gives no finite R, T for n={n}, cab={cab}, car={car}, anth={anth}, "
                            f"cbrown={cbrown}, cw={cw}, cm={cm} (a leaf needs some absorber: cw or cm > 0)")
    r.setflags(write=False)
    t.setflags(write=False)
    wl.setflags(write=False)
    return wl, r, t


@dataclass(frozen=True)
class LeafTables:
    """Per-wavelength body parameters of a leaf, solved at the calibration incidence."""

    wavelengths: np.ndarray       # nm, 1 nm steps
    prospect_r: np.ndarray        # PROSPECT-D's R
    prospect_t: np.ndarray        # PROSPECT-D's T
    body_r: np.ndarray            # r_b
    body_t: np.ndarray            # t_b
    specular_scale: np.ndarray    # ks (1 except where R_P < E_s(8))
    fbar8: float                  # mean entry Fresnel at 8 deg
    es8: float                    # specular albedo at 8 deg (ks = 1)

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
        return tuple(float(np.interp(wavelength_nm, w, a)) for a in
                     (self.prospect_r, self.prospect_t, self.body_r, self.body_t, self.specular_scale))  # type: ignore[return-value]


def leaf_tables(prospect: tuple[np.ndarray, np.ndarray, np.ndarray], fbar8: float, es8: float) -> LeafTables:
    """Solve r_b, t_b, ks per wavelength so that R(8 deg) = R_P and T(8 deg) = T_P exactly."""
    wl, rp, tp = prospect
    if not (0.0 <= es8 <= fbar8 < 1.0):
        raise SpecimenError(f"leaf: cuticle albedo {es8} and entry Fresnel {fbar8} out of order")
    ks = np.ones_like(rp)
    low = rp < es8
    if es8 > 0.0:
        ks[low] = rp[low] / es8
    rb = np.maximum(rp - ks * es8, 0.0) / (1.0 - fbar8)
    tb = tp / (1.0 - fbar8)
    over = rb + tb > 1.0  # only where PROSPECT absorbs less than the cuticle's masking loss
    if np.any(over):
        s = rb[over] + tb[over]
        rb[over] /= s
        tb[over] /= s
    return LeafTables(wl, rp, tp, rb, tb, ks, float(fbar8), float(es8))


def calibration_direction() -> np.ndarray:
    """The unit vector toward the source at the calibration incidence (phi = 0)."""
    t = math.radians(INCIDENCE_CALIBRATION_DEG)
    return np.array([math.sin(t), 0.0, math.cos(t)])
