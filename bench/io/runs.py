"""Records of stored runs, with their keys: what ``bench compare`` (and the Python API) reads from
the run store.

:func:`load_run` turns a run id into the record a comparison needs:

* a **sweep** -> :func:`bench.sweep.records.sweep_record`: a goniophotometric sweep as a
  :class:`BSDFRecord` whose rows carry the task's keys (``specimen``, ``collector``,
  ``quantity``), so two specimens at the same incidence are never paired with each other; a
  spectrophotometric sweep as a tuple of :class:`Spectrum`, one per (specimen, CIE geometry);
* a **spectral scan** (plan kind ``spectral``: CIE geometries measured on the goniometer) -> a
  tuple of :class:`Spectrum` per geometry, reflectance factor ``R = pi * BRDF``;
* any other run -> :meth:`RunStore.to_record` with the identity keys added
  (:func:`bench.core.records.with_keys`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.core.errors import InputError
from bench.core.geometry import cie_geometry
from bench.core.records import BSDFRecord, with_keys
from bench.core.roles import Spectrum
from bench.sweep.records import sweep_record

if TYPE_CHECKING:
    from bench.store import RunStore

__all__ = ["load_run", "sweep_record", "spectral_scan_spectra"]


def _z(delta: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(1.0 - delta / 2.0))


def spectral_scan_spectra(record: BSDFRecord) -> tuple[Spectrum, ...]:
    """A spectral scan (CIE geometries on the goniometer) as spectra: one per geometry, the
    reflectance factor ``R = pi * f_r`` with its std scaled alike; the geometry named from the
    point's (theta_i, theta_r) when it is a CIE bidirectional geometry, else ``"THETA_I/THETA_R"``."""
    t = record.table
    geos = (record.meta.get("plan") or {}).get("spectral", {}).get("geometries") or []
    known = {}
    for name in geos:
        try:
            g = cie_geometry(name)
        except (InputError, ValueError, KeyError):
            continue
        known[name] = g
    out = []
    delta = float(record.meta.get("delta", 0.01))
    spec = with_keys(record).table["specimen"].iloc[0] if len(t) else None
    for (ti, tr), g in t.groupby(["theta_i", "theta_r"], sort=True):
        g = g.sort_values("wavelength_nm", kind="stable")
        name = _geometry_name(float(ti), float(tr), known)
        v = math.pi * g.value.to_numpy(float)
        s = math.pi * g["std"].to_numpy(float) if "std" in g else np.full(len(g), np.nan)
        ci = np.stack([v - _z(delta) * s, v + _z(delta) * s], axis=1)
        zeros = np.zeros(len(g))
        out.append(Spectrum(geometry=name, wavelengths=g.wavelength_nm.to_numpy(float), reflectance=v,
                            transmittance=zeros, reflectance_ci=ci, transmittance_ci=np.zeros((len(g), 2)),
                            N=np.zeros(len(g), np.int64), seed=record.meta.get("seed"), delta=delta,
                            meta={"specimen": spec, "quantity": "reflectance factor", "source": "scan",
                                  "run_id": record.meta.get("run_id"), "reflectance_std": s,
                                  "converted": "R = pi * BRDF"}))
    return tuple(out)


def _geometry_name(ti: float, tr: float, known: dict[str, Any]) -> str:
    for name in known:
        a, _, b = name.partition("/")
        try:
            if abs(float(a) - ti) < 1.0 and abs(float(b) - tr) < 1.0:
                return name
        except ValueError:
            continue
    return f"{ti:g}/{tr:g}"


def load_run(store: RunStore, run_id: str) -> BSDFRecord | tuple[Spectrum, ...]:
    """The record of a stored run, keyed (see the module docstring)."""
    info = store.run(run_id)
    if info["kind"] == "sweep":
        return sweep_record(store, run_id)
    rec = store.to_record(run_id)
    if ((info.get("plan") or {}).get("kind") == "spectral") and len(rec.table):
        return spectral_scan_spectra(rec)
    return with_keys(rec)
