"""The end-to-end demo on the embedded default (virtual) bench, run by ``make demo``."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["run_demo", "lab_of"]


def lab_of(wavelengths: np.ndarray, reflectance: np.ndarray) -> np.ndarray:
    """CIELAB (D65, CIE 1931 2 deg) of a reflectance spectrum, through colour-science."""
    import colour

    sd = colour.SpectralDistribution(dict(zip(wavelengths.tolist(), reflectance.tolist())))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    illuminant = colour.SDS_ILLUMINANTS["D65"]
    xyz = colour.sd_to_XYZ(sd, cmfs, illuminant) / 100.0
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(xyz, white)


def _spectro_demo(out: Path, seed: int) -> tuple[dict[str, Any], list[str]]:
    import colour

    from bench.export import spectrum_to_csv
    from bench.plotting import plot_spectrum
    from virtual.spectrophotometer import VirtualSpectrophotometer

    patch = "dark skin"
    sp = VirtualSpectrophotometer(f"colorchecker:{patch}", beam="conical", uncertainty=0.005, delta=0.01, seed=seed)
    wl = np.arange(380.0, 731.0, 10.0)  # BabelColor data: 380..730 nm
    t0 = time.perf_counter()
    s = sp.measure("8/d", wl)
    seconds = time.perf_counter() - t0
    csv = spectrum_to_csv(s, out / "spectro-dark-skin.csv")
    png = plot_spectrum(s, out / "spectro-dark-skin.png")
    truth = np.array([sp.specimen.params(w)[0] for w in wl])
    lab_meas, lab_true = lab_of(wl, s.reflectance), lab_of(wl, truth)
    de = float(colour.delta_E(lab_meas, lab_true, method="CIE 2000"))
    err = np.abs(s.reflectance - truth)
    summary = {"specimen": f"colorchecker:{patch}", "geometry": "8/d", "beam": "conical", "N": int(s.N[0]),
               "wavelengths": int(wl.size), "seconds": seconds, "max_abs_error": float(err.max()),
               "delta_e2000": de, "lab": lab_meas.tolist(), "csv": str(csv), "plot": str(png)}
    lines = [
        f"virtual spectrophotometer: ColorChecker '{patch}' at 8/d, conical beam, seed {seed}",
        f"  {s.N[0]:,} rays x {wl.size} wavelengths (eq. 3.5 for v = 0.005, delta = 0.01) in {seconds:.2f} s",
        f"  max |R - R_true| = {err.max():.4f} (bound 0.005);  CIEDE2000 to the true spectrum = {de:.3f}",
        f"  L*a*b* (D65, 2 deg) = {lab_meas[0]:.2f}, {lab_meas[1]:.2f}, {lab_meas[2]:.2f}",
        f"  wrote {csv} and {png}",
    ]
    return summary, lines


def run_demo(out: Path, seed: int = 20261122) -> dict[str, Any]:
    """Run every demo stage, write files into ``out``, return a summary (with printable lines)."""
    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {"out": str(out), "lines": []}
    spectro, lines = _spectro_demo(out, seed)
    summary["spectro"] = spectro
    summary["lines"] += lines
    return summary
