"""Sweep runs as keyed records: every row carries its task's specimen and collector (a
goniophotometric sweep, one :class:`BSDFRecord`), or one :class:`Spectrum` per specimen and CIE
geometry (a spectrophotometric sweep), so a comparison pairs like with like
(:func:`sweep_record`; :func:`bench.io.load_run` calls it for sweep runs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from bench.store import RunStore
from bench.core.errors import InputError
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from bench.sweep.executor import sweep_readings

__all__ = ["sweep_record", "sweep_table"]


def _base(info: dict[str, Any], run_id: str) -> dict[str, Any]:
    """What every record of a sweep states: run, seed, the sweep (its name as the plan's) and
    the virtual bench that ran it (``virtual-gonio`` / ``virtual-spectro``, as ``bench gonio`` and
    ``bench spectro`` name theirs)."""
    meta = info.get("meta") or {}
    plan = (info.get("plan") or {}).get("sweep", {})
    instrument = meta.get("instrument") or plan.get("instrument")
    return {"run_id": run_id, "kind": "sweep", "source": "virtual", "seed": info.get("seed"),
            "delta": float(plan.get("delta", 0.01)), "sweep": meta.get("sweep"), "instrument": instrument,
            "plan_name": meta.get("sweep") or plan.get("name"), "bench_name": f"virtual-{instrument or 'gonio'}",
            "body": "virtual"}


def sweep_record(store: RunStore, run_id: str) -> BSDFRecord | tuple[Spectrum, ...]:
    """A sweep run as a keyed record (see the module docstring)."""
    info = store.run(run_id)
    if (info.get("meta") or {}).get("instrument") == "spectro":
        base = _base(info, run_id)
        return _sweep_spectra(sweep_readings(store, run_id), base, base["delta"])
    return sweep_table(store, run_id)


def sweep_table(store: RunStore, run_id: str) -> BSDFRecord:
    """A sweep run as one table whose rows carry their task's keys: a goniophotometric sweep's
    ``specimen`` and ``collector`` (``quantity`` BSDF), a spectrophotometric sweep's ``specimen``,
    CIE ``geometry`` and measured ``quantity`` (a reflectance: unitless, no viewing direction)."""
    info = store.run(run_id)
    base = _base(info, run_id)
    df = sweep_readings(store, run_id)
    rec = store.to_record(run_id)
    t = rec.table
    spectro = base["instrument"] == "spectro"
    for k in ("specimen", "collector", "geometry") if spectro else ("specimen", "collector"):
        t[k] = df[k].to_numpy() if k in df.columns else None
    if not spectro:
        t["geometry"] = None
    t["quantity"] = df["quantity"].to_numpy() if spectro and "quantity" in df.columns else (
        "reflectance" if spectro else "BSDF")
    meta = {**rec.meta, **base}
    if spectro:
        meta["quantity"] = "reflectance"
    return BSDFRecord(t, meta)


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
