"""The declared ``leaf`` family: PROSPECT-D's R and T carried by a cuticle-and-body angular model.

``leaf:n=1.5,cab=40,car=8,anth=0,cbrown=0,cw=0.01,cm=0.009,roughness=0.3,eta=1.5``, or a named
leaf of ``fixtures/specimens/leaves.toml``: ``leaf:healthy`` (with overrides:
``leaf:healthy,roughness=0.2``). The model, its source and its numerics are documented in
:mod:`virtual.leaf_optics`; the kernel branch is ``_leaf`` in :mod:`virtual.kernels.scatter`.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from bench.core.errors import SpecimenError
from bench.core.parsing import read_toml
from virtual.model_ids import MODEL_LEAF
from virtual.leaf_optics import (INCIDENCE_CALIBRATION_DEG, PROSPECT_RANGE_NM, LeafTables, cuticle_albedo,
                                 cuticle_integrals, leaf_tables, prospect_d)
from virtual.specimens.declare import DeclaredSpecimen, Param, Spectral, register_specimen
from virtual.specimens.physics import local, mirror, np_fresnel_dielectric, np_ggx_reflection

__all__ = ["Leaf", "LEAF_LIBRARY"]

#: the named leaves (``leaf:NAME``)
LEAF_LIBRARY = Path(__file__).resolve().parents[2] / "fixtures" / "specimens" / "leaves.toml"
_PROSPECT = ("n", "cab", "car", "anth", "cbrown", "cw", "cm")


@lru_cache(maxsize=4)
def _library(path: str) -> dict[str, dict[str, Any]]:
    leaves = read_toml(path, "leaf library").get("leaf", {})
    if not isinstance(leaves, dict) or not leaves:
        raise SpecimenError(f"leaf library {path}: no [leaf.NAME] tables")
    return leaves


@lru_cache(maxsize=256)
def _cuticle_at(theta_rad: float, alpha: float, eta: float) -> tuple[float, float]:
    """:func:`cuticle_integrals`, cached: a spectrum asks for the same (incidence, cuticle) at
    every wavelength, and leaves differing only in PROSPECT's parameters (a fit) share their
    cuticle; one evaluation costs tens of milliseconds."""
    return cuticle_integrals(theta_rad, alpha, eta)


@lru_cache(maxsize=64)
def _tables(n: float, cab: float, car: float, anth: float, cbrown: float, cw: float, cm: float,
            alpha: float, eta: float) -> LeafTables:
    es8, fbar8 = _cuticle_at(math.radians(INCIDENCE_CALIBRATION_DEG), alpha, eta)
    return leaf_tables(prospect_d(n, cab, car, anth, cbrown, cw, cm), es8, fbar8)


@register_specimen
class Leaf(DeclaredSpecimen):
    """A plant leaf: PROSPECT-D (Féret et al. 2017) under a GGX wax cuticle; two-sided.

    f_r = ks F D G2 / (4 cos_i cos_o) + r_b (1 - E(wi)) (1 - E(wo)) / (pi (1 - E_avg)) above,
    f_t = t_b (1 - E(wi)) (1 - E(wo)) / (pi (1 - E_avg)) below, E = ks E_s the cuticle's specular
    albedo; r_b, t_b, ks per wavelength so that R and T at 8 deg equal PROSPECT-D's
    (:mod:`virtual.leaf_optics`). Reciprocal in reflection and transmission. 400-2500 nm.

    params: ``[alpha, eta, ks, r_b, t_b]``.
    """

    name = "leaf"
    convention = ("PROSPECT-D (Féret 2017) at 8 deg; GGX wax cuticle (masking correlated) over a diffuse body, "
                  "Kelemen & Szirmay-Kalos 2001 coupling (reciprocal)")
    model = MODEL_LEAF
    has_density = True
    reciprocal = True
    parameters = (
        Param("n", 1.5, 1.0, 3.5, doc="PROSPECT structure parameter N (layers)"),
        Param("cab", 40.0, 0.0, 300.0, "ug/cm2", "chlorophyll a+b"),
        Param("car", 8.0, 0.0, 100.0, "ug/cm2", "carotenoids"),
        Param("anth", 0.0, 0.0, 100.0, "ug/cm2", "anthocyanins"),
        Param("cbrown", 0.0, 0.0, 1.0, doc="brown pigments (arbitrary units)"),
        Param("cw", 0.01, 0.0, 1.0, "cm", "equivalent water thickness"),
        Param("cm", 0.009, 0.0, 1.0, "g/cm2", "dry matter per area"),
        Param("roughness", 0.3, 1e-4, 1.0, doc="cuticle roughness (GGX alpha)"),
        Param("eta", 1.5, 1.2, 2.0, doc="cuticle (wax) refractive index"),
    )

    def __post_init__(self) -> None:
        for p in self.parameters:
            v = getattr(self, p.name)
            if isinstance(v, tuple) or (isinstance(v, Spectral) and v.wavelengths is not None):
                raise SpecimenError(f"leaf: {p.name} must be a number (PROSPECT-D takes no spectral parameter)")
        super().__post_init__()

    # -- the model's pieces --------------------------------------------------------------------
    def _scalars(self) -> dict[str, float]:
        return self.values(550.0)  # constants: every wavelength gives the same checked values

    def tables(self) -> LeafTables:
        """The per-wavelength body (r_b, t_b, ks) with PROSPECT-D's R_P, T_P (1 nm steps)."""
        v = self._scalars()
        return _tables(*(v[k] for k in _PROSPECT), v["roughness"], v["eta"])

    def prospect(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """PROSPECT-D's (wavelengths, R, T) of this leaf (``prosail.run_prospect``)."""
        v = self._scalars()
        return prospect_d(*(v[k] for k in _PROSPECT))

    def kernel_params(self, v: Mapping[str, float]) -> np.ndarray:  # pragma: no cover - params() is overridden
        raise SpecimenError("leaf: the kernel parameters depend on the wavelength; call params(wavelength_nm)")

    def params(self, wavelength_nm: float) -> np.ndarray:
        v = self.values(wavelength_nm)
        t = _tables(*(v[k] for k in _PROSPECT), v["roughness"], v["eta"])
        _, _, rb, tb, ks = t.at(float(wavelength_nm))  # SpecimenError outside 400-2500 nm
        return np.array([v["roughness"], v["eta"], ks, rb, tb], dtype=np.float64)

    def wavelength_range(self) -> tuple[float, float]:
        return PROSPECT_RANGE_NM

    def transmits(self, wavelength_nm: float) -> bool:
        return bool(self.params(wavelength_nm)[4] > 0.0)

    def directional_rt(self, theta_deg: float, wavelength_nm: float) -> tuple[float, float]:
        """The model's directional-hemispherical (R, T) at incidence ``theta_deg`` (quadrature):
        R = E + r_b (1 - E), T = t_b (1 - E), E = ks E_s(theta)."""
        a, eta, ks, rb, tb = self.params(wavelength_nm)
        e = ks * _cuticle_at(math.radians(abs(theta_deg)), float(a), float(eta))[0]
        return e + rb * (1.0 - e), tb * (1.0 - e)

    # -- density -------------------------------------------------------------------------------
    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        a, eta, ks, rb, tb = self.params(wavelength_nm)
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros(len(wo))
        albedo = cuticle_albedo(float(a), float(eta))
        ei = ks * float(albedo(np.array([wi[2]]))[0])
        eo = ks * albedo(wo[:, 2])
        diff = (1.0 - ei) * (1.0 - eo) / (math.pi * (1.0 - ks * albedo.average))
        zo = wo[:, 2]
        spec = ks * np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta))
        return np.where(zo > 0.0, spec + rb * diff, np.where(zo < 0.0, tb * diff, 0.0))

    def bsdf_spectrum(self, wi: np.ndarray, wo: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
        """:meth:`bsdf` at many wavelengths at once, ``(wavelengths, directions)``: the cuticle's
        roughness and index do not depend on the wavelength, so its lobe and albedo are computed
        once and only the body's tables (r_b, t_b, ks; linear between their 1 nm samples, as
        :meth:`LeafTables.at`) vary. Equal to :meth:`bsdf` per wavelength to rounding."""
        wl = np.asarray(wavelengths_nm, dtype=float)
        lo, hi = PROSPECT_RANGE_NM
        if wl.size and not (lo <= float(wl.min()) and float(wl.max()) <= hi):
            raise SpecimenError(f"leaf: wavelengths {wl.min():g}-{wl.max():g} nm leave PROSPECT-D's {lo:g}-{hi:g} nm")
        v = self._scalars()
        a, eta = float(v["roughness"]), float(v["eta"])
        t = self.tables()
        ks, rb, tb = (np.interp(wl, t.wavelengths, x)[:, None] for x in (t.specular_scale, t.body_r, t.body_t))
        wi, wo, _ = local(wi, wo)
        if not wi[2] > 0.0:
            return np.zeros((wl.size, len(wo)))
        albedo = cuticle_albedo(a, eta)
        ei = ks * float(albedo(np.array([wi[2]]))[0])
        eo = ks * albedo(wo[:, 2])[None, :]
        diff = (1.0 - ei) * (1.0 - eo) / (math.pi * (1.0 - ks * albedo.average))
        zo = wo[:, 2][None, :]
        spec = ks * np_ggx_reflection(wi, wo, a, a, lambda c: np_fresnel_dielectric(c, eta))[None, :]
        return np.where(zo > 0.0, spec + rb * diff, np.where(zo < 0.0, tb * diff, 0.0))

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        return [(mirror(wi), 2.0 * float(self.params(wavelength_nm)[0]))]

    # -- the library ---------------------------------------------------------------------------
    @classmethod
    def preset(cls, name: str) -> dict[str, float]:
        """The parameters of the named leaf ``name`` of :data:`LEAF_LIBRARY`."""
        lib = _library(str(LEAF_LIBRARY))
        entry = lib.get(name.strip().lower())
        if entry is None:
            raise SpecimenError(f"unknown leaf {name!r}; the library has: {', '.join(sorted(lib))}")
        return {p.name: float(entry[p.name]) for p in cls.parameters if p.name in entry}
