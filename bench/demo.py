"""The end-to-end demo (``bench demo``, ``make demo``): a virtual spectrophotometer and
goniophotometer, one plan scanned on the emulated and the virtual bench, and the comparison of
the emulated run with two virtual candidate models.

Imported lazily by the CLI (it loads numba kernels, colour-science and matplotlib).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import colour
import numpy as np

from bench.config import load_bench
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.io import spectrum_to_csv
from bench.plans import load_plan
from bench.runner import run_scan
from bench.store import RunStore
from compare.figures import plot_bsdf_polar, plot_in_plane, plot_spectrum
from compare.report import compare_records
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.spectrophotometer import VirtualSpectrophotometer

__all__ = ["run_demo", "lab_of"]


def lab_of(wavelengths: np.ndarray, reflectance: np.ndarray) -> np.ndarray:
    """CIELAB (D65, CIE 1931 2 deg) of a reflectance spectrum, through colour-science."""
    sd = colour.SpectralDistribution(dict(zip(wavelengths.tolist(), reflectance.tolist())))
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    illuminant = colour.SDS_ILLUMINANTS["D65"]
    xyz = colour.sd_to_XYZ(sd, cmfs, illuminant) / 100.0
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(xyz, white)


def _spectro_demo(out: Path, seed: int) -> tuple[dict[str, Any], list[str]]:
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


GLOSSY = "plastic:alpha=0.15,eta=1.5,kd=0.5"
#: the second candidate model of the comparison: the same material, a lobe twice as rough
ROUGHER = "plastic:alpha=0.3,eta=1.5,kd=0.5"


def _gonio_demo(out: Path, seed: int) -> tuple[dict[str, Any], list[str]]:
    """In-plane and hemispherical BRDF of a glossy specimen on the virtual goniophotometer."""
    t0 = time.perf_counter()
    g = VirtualGoniophotometer(GLOSSY, collector="equal-psa:45x180", rays=100_000_000, seed=seed)
    curves = []
    angles = np.arange(-85.0, 85.5, 1.0)
    for theta_i in (30.0, 60.0):
        vals = np.array([[x[0] for x in g.bsdf_at(Geometry.in_plane(theta_i, tr))] for tr in angles])
        curves.append((f"theta_i = {theta_i:g} deg", angles, vals[:, 0], vals[:, 1], vals[:, 2]))
    in_plane = plot_in_plane(curves, out / "gonio-glossy-in-plane.png",
                             title=f"{GLOSSY}: in-plane BRDF, 1e8 rays ({'fast path' if g.uses_fast_path() else 'rays'})")
    record = g.measure_bsdf(30.0)
    polar = plot_bsdf_polar(record, out / "gonio-glossy-polar.png")
    seconds = time.perf_counter() - t0
    peak = float(curves[0][2].max())
    tot = record.meta["totals"][0]
    summary = {"specimen": GLOSSY, "collector": "equal-psa:45x180", "rays": g.rays, "method": record.meta["method"],
               "seconds": seconds, "peak_brdf_30": peak, "reflectance_30": tot["reflectance"],
               "plots": [str(in_plane), str(polar)]}
    lines = [f"virtual goniophotometer: {GLOSSY}, 8100-patch equal-PSA sphere, 1e8 rays per incidence "
             f"({record.meta['method']}), {seconds:.1f} s",
             f"  specular peak BRDF at theta_i = 30: {peak:.3f} 1/sr; directional-hemispherical reflectance "
             f"{tot['reflectance']:.4f}",
             f"  wrote {in_plane} and {polar}"]
    return summary, lines


def _scan_demo(out: Path, seed: int) -> tuple[dict[str, Any], list[str]]:
    """The in-plane plan on the emulated bench (real drivers over emulators) and on the virtual
    bench, both stored in one run store."""
    fixtures = Path(__file__).resolve().parent.parent / "fixtures"
    plan = load_plan(fixtures / "plans" / "in-plane.toml")
    store_path = out / "runs.sqlite"
    runs = {}
    lines = [f"scan: plan '{plan.name}' ({len(plan)} points) on two benches, store {store_path}"]
    with RunStore(store_path) as store:
        for name, kind, spec in (("emulated", "emulated", GLOSSY), ("virtual", "virtual", GLOSSY),
                                 ("virtual-rougher", "virtual", ROUGHER)):
            cfg = read_toml(fixtures / "benches" / f"{kind}.toml")
            cfg["specimen"] = {"spec": spec}
            t0 = time.perf_counter()
            with load_bench(cfg, seed=seed) as bench:
                res = run_scan(bench, plan, store, seed=seed)
            runs[name] = {"run_id": res.run_id, "seconds": time.perf_counter() - t0, "points": res.points_done,
                          "specimen": spec}
            lines.append(f"  {kind:8s} bench, {spec}: run {res.run_id}, {res.points_done} points in "
                         f"{runs[name]['seconds']:.1f} s")
    return {"store": str(store_path), "runs": runs}, lines


def _compare_demo(out: Path, runs: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The emulated-hardware run against two virtual candidate models: which goes into the renderer?"""
    with RunStore(runs["store"]) as store:
        actual = store.to_record(runs["runs"]["emulated"]["run_id"])
        candidates = {f"model A ({GLOSSY})": store.to_record(runs["runs"]["virtual"]["run_id"]),
                      f"model B ({ROUGHER})": store.to_record(runs["runs"]["virtual-rougher"]["run_id"])}
    summary = compare_records(actual, candidates, out / "compare",
                              title="Emulated gonioreflectometer vs two virtual models")
    lines = ["compare: emulated-hardware run against two virtual candidate models"]
    for i, entry in enumerate(summary["ranking"], 1):
        s = summary["candidates"][entry["name"]]
        lines.append(f"  #{i} {entry['name']}: mean |discrepancy| {s['mean_abs_discrepancy_pct']:.2f} %, "
                     f"chi2/dof {s['chi2_per_dof']:.2f}, within uncertainty {s['fraction_within_uncertainty']:.0%}")
    lines.append(f"  report: {summary['report_html']}")
    return {"ranking": [e["name"] for e in summary["ranking"]], "report": summary["report_html"],
            "candidates": {n: {k: summary["candidates"][n][k] for k in ("mean_abs_discrepancy_pct", "chi2_per_dof",
                                                                        "fraction_within_uncertainty", "p_value")}
                           for n in summary["candidates"]}}, lines


def run_demo(out: Path, seed: int = 20261122, progress: bool = False) -> dict[str, Any]:
    """Run every demo stage, write files into ``out``, return a summary (with printable lines).

    ``progress``: a bar over the four stages with an ETA, on stderr (the CLI asks for it on a terminal).
    """
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {"out": str(out), "lines": []}
    with tqdm(total=4, disable=not progress, desc="demo", unit="stage", leave=False, dynamic_ncols=True) as bar:
        for name, stage in (("spectro", _spectro_demo), ("gonio", _gonio_demo), ("scan", _scan_demo)):
            bar.set_postfix_str(name)
            part, lines = stage(out, seed)
            summary[name] = part
            summary["lines"] += lines
            bar.update()
        bar.set_postfix_str("compare")
        summary["compare"], lines = _compare_demo(out, summary["scan"])
        summary["lines"] += lines
        bar.update()
    return summary
