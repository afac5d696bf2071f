"""Exports of records to files people and tools read (tidy CSV first; more formats later)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bench.instruments import Spectrum

__all__ = ["spectrum_table", "spectrum_to_csv"]


def spectrum_table(s: Spectrum) -> Any:
    """A tidy ``pandas.DataFrame``: one row per wavelength, intervals as lo/hi columns."""
    import pandas as pd

    return pd.DataFrame({
        "wavelength_nm": s.wavelengths,
        "reflectance": s.reflectance,
        "reflectance_lo": s.reflectance_ci[:, 0],
        "reflectance_hi": s.reflectance_ci[:, 1],
        "transmittance": s.transmittance,
        "transmittance_lo": s.transmittance_ci[:, 0],
        "transmittance_hi": s.transmittance_ci[:, 1],
        "N": s.N,
        "geometry": s.geometry,
        "seed": s.seed,
        "confidence": 1.0 - s.delta,
    })


def spectrum_to_csv(s: Spectrum, path: str | Path) -> Path:
    """Write :func:`spectrum_table` as CSV (parent folders created); return the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    spectrum_table(s).to_csv(p, index=False, float_format="%.8g")
    return p
