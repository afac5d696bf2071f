"""Stored runs of every record kind an export meets, built quickly (no ray tracing but for the
spectrophotometer and its sweep): for the export tests and the export conformance cells.

* ``gonio``: a collector record over the whole hemisphere (equal-PSA 6x24 patches with bounds and
  PSA), a Lambertian's exact BRDF ``0.5/pi`` at two wavelengths, a lab sample name on its bench;
* ``in-plane``: point samples of a goniometer scan in the plane of incidence;
* ``spectro``: ``bench spectro --store`` (8/d reflectance and transmittance rows);
* ``spectro-sweep``: a spectrophotometric ``bench sweep`` (8/d and 45/0).
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np
import pandas as pd

from bench.core.records import BSDFRecord
from bench.store import RunStore

#: the exact BRDF of the synthetic Lambertian (albedo 0.5)
LAMBERT_BRDF = 0.5 / math.pi
#: the lab's name of the mounted specimen on the synthetic runs' bench
SAMPLE_NAME = "tile 7 (north shelf)"

SPECTRO_SWEEP = """[sweep]
name = "spectro-cells"
seed = 7
instrument = "spectro"
specimens = ["lambert:reflectance=0.5,transmittance=0.2"]
geometries = ["8/d", "45/0"]
wavelengths = [450, 550]
rays = 4000
delta = 0.01
"""


def _bench_meta(name: str) -> dict:
    return {"name": "shelf-bench", "kind": "virtual",
            "specimen": {"spec": "lambert:albedo=0.5", "name": name}}


def gonio_record() -> BSDFRecord:
    """Equal-PSA 6x24 patches (sin^2 theta_k = k/6, 15 deg sectors), value exactly 0.5/pi."""
    n_t, n_p = 6, 24
    edges = np.degrees(np.arcsin(np.sqrt(np.arange(n_t + 1) / n_t)))
    rows = []
    for w in (450.0, 550.0):
        for k in range(n_t):
            for j in range(n_p):
                t0, t1, p0, p1 = edges[k], edges[k + 1], 15.0 * j, 15.0 * (j + 1)
                psa = math.radians(15.0) / 2 * (math.cos(math.radians(t0)) ** 2 - math.cos(math.radians(t1)) ** 2)
                rows.append({"wavelength_nm": w, "theta_i": 30.0, "phi_i": 0.0, "theta_r": (t0 + t1) / 2,
                             "phi_r": (p0 + p1) / 2, "hemisphere": "R", "value": LAMBERT_BRDF, "std": 0.001,
                             "theta_min": t0, "theta_max": t1, "phi_min": p0, "phi_max": p1, "psa": psa})
    meta = {"specimen": "lambert:albedo=0.5", "collector": "equal-psa:6x24", "quantity": "BSDF",
            "bench": _bench_meta(SAMPLE_NAME), "plan_name": "hemisphere", "body": "virtual", "seed": 3}
    return BSDFRecord(pd.DataFrame(rows), meta)


def in_plane_record() -> BSDFRecord:
    """Point samples in the plane of incidence, as a goniometer scan stores them (raw columns too)."""
    rows = [{"wavelength_nm": w, "theta_i": 30.0, "phi_i": 0.0, "theta_r": abs(tr), "phi_r": 0.0 if tr > 0 else 180.0,
             "hemisphere": "R", "value": LAMBERT_BRDF * (1 + 0.01 * k), "std": 0.002, "signal": 1000.0 + k,
             "dark": 10.0, "white": 2000.0, "saturated": 0}
            for w in (450.0, 550.0) for k, tr in enumerate((-40.0, -20.0, 20.0, 40.0, 60.0))]
    meta = {"specimen": "lambert:albedo=0.5", "quantity": "BSDF", "bench": _bench_meta(SAMPLE_NAME),
            "plan_name": "in-plane", "body": "emulated", "seed": 4}
    return BSDFRecord(pd.DataFrame(rows), meta)


def store_record(store: Path, record: BSDFRecord, kind: str = "virtual") -> str:
    """``record`` as a completed run of ``store``; its run id."""
    meta = {k: v for k, v in record.meta.items() if k != "bench"}
    with RunStore(store) as s:
        rid = s.create_run(kind, bench=record.meta.get("bench"), seed=meta.get("seed"), n_planned=1, meta=meta)
        s.add_record(rid, record, merge_meta=False)
        s.set_status(rid, "completed")
    return rid


def stored_runs(tmp: Path, main) -> dict[str, str]:
    """Every record kind as a run of ``tmp / "runs.sqlite"``: kind -> run id (``main`` is
    :func:`bench.cli.main`, called with stdout captured by the caller)."""
    store = tmp / "runs.sqlite"
    runs = {"gonio": store_record(store, gonio_record()), "in-plane": store_record(store, in_plane_record())}
    code = main(["spectro", "--specimen", "lambert:reflectance=0.5,transmittance=0.2", "--geometry", "8/d",
                 "--wavelengths", "450,550", "--rays", "4000", "--seed", "1", "--store", str(store), "--json"])
    assert code == 0
    sweep = tmp / "sweep.toml"
    sweep.write_text(SPECTRO_SWEEP)
    assert main(["sweep", str(sweep), "--store", str(store)]) == 0
    with RunStore(store, create=False) as s:
        listed = {r["run_id"]: r for r in s.runs()}
    rest = [rid for rid in listed if rid not in runs.values()]
    kinds = {rid: listed[rid]["kind"] for rid in rest}
    runs["spectro"] = next(r for r in rest if kinds[r] == "virtual")
    runs["spectro-sweep"] = next(r for r in rest if kinds[r] == "sweep")
    return runs


def stored_runs_quietly(tmp_path_factory, name: str, main) -> tuple[Path, dict[str, str]]:
    """:func:`stored_runs` in a fresh folder ``name`` of the session, the CLI's output swallowed:
    ``(store, kind -> run id)``, what a module-scoped ``runs`` fixture returns."""
    tmp = tmp_path_factory.mktemp(name)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        ids = stored_runs(tmp, main)
    return tmp / "runs.sqlite", ids
