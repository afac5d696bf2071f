"""Cheap synthetic records with known parameters for the fit tests: one certified quadrature per
model gives the patch probabilities, then every record is one multinomial draw (the fast path's
own distribution) -- no rays. Leaf spectra are drawn from ``prosail.run_prospect`` directly."""

from __future__ import annotations

import numpy as np
import prosail

from bench.core.records import BSDFRecord, Spectrum
from virtual.goniophotometer import VirtualGoniophotometer

#: PROSPECT-D's keywords other than N, Cab, Cw, Cm, at the leaf family's defaults
LEAF_FIXED = {"car": 8.0, "cbrown": 0.0, "ant": 0.0}


def gonio_template(specimen: str, collector: str = "equal-psa:5x12", theta_i: float = 30.0,
                   rays: int = 200_000) -> tuple[BSDFRecord, np.ndarray]:
    """A fast-path record of ``specimen`` and its bin probabilities (patches, absorbed)."""
    g = VirtualGoniophotometer(specimen, collector=collector, rays=rays, seed=1, method="fast")
    record = g.measure_bsdf(theta_i, 0.0)
    return record, g.bin_probabilities(theta_i, 0.0, 550.0)[:-1]


def redraw(template: BSDFRecord, p: np.ndarray, rays: int, rng: np.random.Generator) -> BSDFRecord:
    """``template`` with new counts: one multinomial draw of ``rays`` over ``p``."""
    k = rng.multinomial(rays, p / p.sum())
    table = template.table.copy()
    table["count"] = k[:-1].astype(np.int64)
    table["N"] = np.int64(rays)
    return BSDFRecord(table, dict(template.meta))


def prospect_rt(n: float, cab: float, cw: float, cm: float, wavelengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PROSPECT-D's R and T at ``wavelengths`` (1 nm grid from 400 nm), straight from prosail."""
    wl, r, t = prosail.run_prospect(n, cab, LEAF_FIXED["car"], LEAF_FIXED["cbrown"], cw, cm,
                                    ant=LEAF_FIXED["ant"], prospect_version="D", alpha=40.0)
    idx = np.searchsorted(wl, wavelengths)
    return r[idx], t[idx]


def leaf_spectrum(truth: dict[str, float], wavelengths: np.ndarray, rays: int, rng: np.random.Generator) -> Spectrum:
    """A virtual 8/d spectrum of a leaf: per wavelength one multinomial of reflected,
    transmitted, absorbed with PROSPECT-D's R and T."""
    r, t = prospect_rt(truth["n"], truth["cab"], truth["cw"], truth["cm"], wavelengths)
    k = np.array([rng.multinomial(rays, [ri, ti, max(0.0, 1.0 - ri - ti)]) for ri, ti in zip(r, t)])
    zeros = np.zeros((len(wavelengths), 2))
    return Spectrum(geometry="8/d", wavelengths=np.asarray(wavelengths, float), reflectance=k[:, 0] / rays,
                    transmittance=k[:, 1] / rays, reflectance_ci=zeros, transmittance_ci=zeros,
                    N=np.full(len(wavelengths), rays, dtype=np.int64), seed=None, delta=0.01,
                    meta={"beam": {"kind": "collimated"}, "specimen": "leaf"})


__all__ = ["gonio_template", "redraw", "prospect_rt", "leaf_spectrum", "LEAF_FIXED"]
