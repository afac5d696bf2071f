"""Emulated body x spectral specimen x band fit: a leaf's cuticle fitted within its uncertainty.

The emulated detector gives each pixel the specimen's value at that pixel's wavelength, a band
reads the mean of its pixels, and the fit predicts that mean (``bench.identify.prediction``). With
the former 41-wavelength interpolation and centre-wavelength prediction the fitted roughness and
index of ``leaf:healthy,roughness=0.2,eta=1.45`` missed the truth by 3-12 standard errors."""

from __future__ import annotations

import copy

import pytest

from bench.core.parsing import read_toml
from bench.identify import design_study
from cells import BENCHES

LEAF = "leaf:healthy,roughness=0.2,eta=1.45"
#: |z| bound per parameter: 3 standard errors (0.27 % false alarms each for honest errors)
Z_MAX = 3.0


@pytest.mark.slow  # ~3 CPU-min on a loaded core: one emulated in-plane scan (63 points x 3 bands) and a fit
def test_emulated_leaf_scan_fits_its_cuticle_within_its_uncertainty():
    d = copy.deepcopy(read_toml(BENCHES / "emulated.toml"))
    d["specimen"]["spec"] = LEAF
    m = design_study.measure("leaf:roughness=?,eta=?", d, seeds=[7], methods=("uniform",))
    fit = m["results"]["uniform in-plane"][0]["fit"]
    for p, truth in m["truth"].items():
        value, lo, hi = fit[p]
        z = (value - truth) / ((hi - lo) / 2 / 1.96)
        assert abs(z) <= Z_MAX, (p, value, truth, z)
