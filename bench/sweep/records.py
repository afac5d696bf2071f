"""Sweep runs as keyed records: every row carries its task's specimen and collector (a
goniophotometric sweep, one :class:`BSDFRecord`), or one :class:`Spectrum` per specimen and CIE
geometry (a spectrophotometric sweep), so a comparison pairs like with like
(:func:`sweep_record`; :func:`bench.io.load_run` calls it for sweep runs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from bench.core.errors import InputError
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from bench.sweep.executor import sweep_readings

__all__ = ["sweep_record"]


def sweep_record(store: Any, run_id: str) -> BSDFRecord | tuple[Spectrum, ...]:
    """A sweep run as a keyed record (see the module docstring)."""
    info = store.run(run_id)
    meta = info.get("meta") or {}
    plan = (info.get("plan") or {}).get("sweep", {})
    delta = float(plan.get("delta", 0.01))
    df = sweep_readings(store, run_id)
    base = {"run_id": run_id, "kind": "sweep", "source": "virtual", "seed": info.get("seed"), "delta": delta,
            "sweep": meta.get("sweep"), "instrument": meta.get("instrument")}
    if meta.get("instrument") == "spectro":
        return _sweep_spectra(df, base, delta)
    rec = store.to_record(run_id)
    t = rec.table
    for k in ("specimen", "collector"):
        t[k] = df[k].to_numpy() if k in df.columns else None
    t["geometry"] = None
    t["quantity"] = "BSDF"
    return BSDFRecord(t, {**rec.meta, **base})


def _sweep_spectra(df: pd.DataFrame, base: dict[str, Any], delta: float) -> tuple[Spectrum, ...]:
    out = []
    for (spec, geo), g in df.groupby(["specimen", "geometry"], sort=False):
        r = g[g.hemisphere == "R"].sort_values("wavelength_nm", kind="stable")
        t = g[g.hemisphere == "T"].set_index("wavelength_nm").reindex(r.wavelength_nm)
        q = str(r["quantity"].iloc[0]) if "quantity" in r.columns else "reflectance"
        out.append(Spectrum(
            geometry=str(geo), wavelengths=r.wavelength_nm.to_numpy(float), reflectance=r.value.to_numpy(float),
            transmittance=t.value.to_numpy(float), reflectance_ci=r[["ci_lo", "ci_hi"]].to_numpy(float),
            transmittance_ci=t[["ci_lo", "ci_hi"]].to_numpy(float), N=r.N.to_numpy(np.int64),
            seed=int(r.series_seed.iloc[0]) if "series_seed" in r.columns else None, delta=delta,
            meta={**base, "specimen": str(spec), "quantity": q, "reflectance_std": r["std"].to_numpy(float),
                  "transmittance_std": t["std"].to_numpy(float)}))
    if not out:
        raise InputError(f"sweep run {base['run_id']} has no spectra")
    return tuple(out)
