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
import pandas as pd

from bench.config import load_bench
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.core.records import BSDFRecord
from bench.io import load_run, save_figure, spectrum_to_csv
from bench.plans import load_plan
from bench.runner import run_scan
from bench.store import RunStore
from compare.figures import plot_bsdf_polar, plot_in_plane, plot_spectrum
from compare.report import compare_records
from compare.verdict import Criterion
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.spectrophotometer import VirtualSpectrophotometer

__all__ = ["run_demo", "lab_of", "leaf_angle_figures"]

FIXTURES = Path(__file__).resolve().parent.parent / "fixtures"


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


#: the model tolerance of the demo's acceptance criterion (relative standard uncertainty)
DEMO_TOLERANCE = 0.02
#: the demo's scan plan: in-plane, incidences facing each other so reciprocity can be tested
DEMO_PLAN = "demo-reciprocal.toml"
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
    fixtures = FIXTURES
    plan = load_plan(fixtures / "plans" / DEMO_PLAN)
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


def _model_spheres(wavelengths: list[float], seed: int) -> dict[str, Any]:
    """Each candidate model measured over the whole sphere (patch records at the plan's
    incidences): what the energy-conservation and reciprocity checks of the models run on."""
    out = {}
    for label, spec in (("A", GLOSSY), ("B", ROUGHER)):
        g = VirtualGoniophotometer(spec, collector="equal-psa:18x72", rays=2_000_000, seed=seed, method="rays")
        frames = [g.measure_bsdf(ti, pi_, wavelengths) for ti, pi_ in ((30.0, 0.0), (45.0, 180.0), (60.0, 0.0))]
        out[f"model {label} whole sphere"] = BSDFRecord(pd.concat([f.table for f in frames], ignore_index=True),
                                                        dict(frames[0].meta))
    return out


def _compare_demo(out: Path, runs: dict[str, Any], seed: int = 20261122) -> tuple[dict[str, Any], list[str]]:
    """The emulated-hardware run against two virtual candidate models: which goes into the renderer?"""
    with RunStore(runs["store"]) as store:
        actual = load_run(store, runs["runs"]["emulated"]["run_id"])
        candidates = {f"model A ({GLOSSY})": load_run(store, runs["runs"]["virtual"]["run_id"]),
                      f"model B ({ROUGHER})": load_run(store, runs["runs"]["virtual-rougher"]["run_id"])}
    wls = sorted(set(map(float, actual.table.wavelength_nm)))
    spheres = _model_spheres(wls[:: max(1, len(wls) // 3)][:3], seed)
    # the criterion, stated before looking: a model within 2 % (standard uncertainty) of the
    # material is good enough for the renderer; family-wise alpha 1 %
    summary = compare_records(actual, candidates, out / "compare", check_records=spheres,
                              criterion=Criterion(alpha=0.01, k=2.0, tolerance=DEMO_TOLERANCE),
                              title="Emulated gonioreflectometer vs two virtual models")
    lines = ["compare: emulated-hardware run against two virtual candidate models",
             f"  criterion: {summary['criterion']['statement']}"]
    for i, entry in enumerate(summary["ranking"], 1):
        s = summary["candidates"][entry["name"]]
        v = summary["verdicts"][entry["name"]]
        lines.append(f"  #{i} {entry['name']}: {v['verdict'].upper()} ({v['reason']}); mean |discrepancy| "
                     f"{s['mean_abs_discrepancy_pct']:.2f} %, chi2/dof {s['chi2_per_dof']:.2f}, within uncertainty "
                     f"{s['fraction_within_uncertainty']:.0%}")
    tested = [f"{rec}: {name} {'passed' if r['passed'] else 'FAILED'}" for rec, res in summary["checks"].items()
              for name, r in res.items() if r["tested"]]
    lines.append(f"  physical checks run: {len(tested)} ({'; '.join(tested)})")
    lines.append(f"  report: {summary['report_html']}")
    return {"ranking": [e["name"] for e in summary["ranking"]], "report": summary["report_html"],
            "verdicts": {n: {k: v[k] for k in ("verdict", "reason")} for n, v in summary["verdicts"].items()},
            "checks_tested": tested,
            "candidates": {n: {k: summary["candidates"][n][k] for k in ("mean_abs_discrepancy_pct", "chi2_per_dof",
                                                                        "fraction_within_uncertainty", "p_value")}
                           for n in summary["candidates"]}}, lines


# --- leaves ---------------------------------------------------------------------------------

LEAF = "leaf:healthy"


def leaf_angle_figures(readings: Any, out: Path, theta_i: float = 40.0, wavelength_nm: float = 550.0,
                       name: str = "leaf") -> dict[str, Path]:
    """Figures of a leaf's angular sweep (the tidy readings of ``fixtures/sweeps/leaf-angles.toml``,
    :func:`bench.sweep.sweep_readings`): the BRDF and BTDF side by side in polar maps at one
    incidence and wavelength, and the directional-hemispherical R and T against incidence, per
    wavelength, counted (sum of count / N over each hemisphere) with the model's own R(theta),
    T(theta) (quadrature of :meth:`virtual.specimens.Leaf.directional_rt`) as lines."""
    import pandas as pd

    from bench.core.records import BSDF_COLUMNS, BSDFRecord
    from compare.figures import pyplot
    from virtual.specimens import parse_specimen

    df = pd.DataFrame(readings)
    incidences = np.sort(df.theta_i.unique())
    ti = float(incidences[np.argmin(np.abs(incidences - theta_i))])
    wls = np.sort(df.wavelength_nm.unique())
    wl = float(wls[np.argmin(np.abs(wls - wavelength_nm))])
    sel = df[(df.theta_i == ti) & (df.wavelength_nm == wl)]
    spec = str(sel.specimen.iloc[0]) if "specimen" in sel else LEAF
    polar = plot_bsdf_polar(BSDFRecord(sel[BSDF_COLUMNS].reset_index(drop=True), {"specimen": spec}),
                            out / f"{name}-polar-{ti:g}deg-{wl:g}nm.png",
                            title=f"{spec}: BRDF | BTDF at theta_i = {ti:g} deg, {wl:g} nm")
    tot = (df.assign(p=df["count"] / df["N"]).groupby(["wavelength_nm", "theta_i", "hemisphere"])["p"].sum()
           .unstack("hemisphere"))
    specimen = parse_specimen(spec)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    grid = np.linspace(0.0, float(incidences.max()), 33)
    for i, w in enumerate(wls):
        c = f"C{i}"
        t = tot.loc[w]
        ax.plot(t.index, t["R"], "o", color=c, ms=4, label=f"{w:g} nm R (rays)")
        ax.plot(t.index, t["T"], "s", color=c, ms=4, mfc="none", label=f"{w:g} nm T (rays)")
        model = np.array([specimen.directional_rt(g, float(w)) for g in grid])
        ax.plot(grid, model[:, 0], "-", color=c, lw=1)
        ax.plot(grid, model[:, 1], "--", color=c, lw=1)
    ax.axvline(8.0, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("incidence theta_i (deg)")
    ax.set_ylabel("directional-hemispherical fraction")
    ax.set_title(f"{spec}: R (-) and T (--) against incidence; dotted: 8 deg (= PROSPECT-D)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2, loc="best")
    fig.tight_layout()
    rt = out / f"{name}-rt-vs-incidence.png"
    save_figure(fig, rt)
    plt.close(fig)
    return {"polar": polar, "rt_vs_incidence": rt}


def _leaf_demo(out: Path, seed: int) -> tuple[dict[str, Any], list[str]]:
    """A leaf at 8/d against PROSPECT-D (spectrum with R and T), and its angular sweep (polar
    BRDF | BTDF, R and T against incidence) from ``fixtures/sweeps/leaf-angles.toml``."""
    from bench.sweep import load_sweep, run_sweep, sweep_readings

    t0 = time.perf_counter()
    sp = VirtualSpectrophotometer(LEAF, beam="conical", uncertainty=0.005, delta=0.01, seed=seed)
    s = sp.measure("8/d", "400:2500:5")
    csv = spectrum_to_csv(s, out / "leaf-spectrum.csv")
    png = plot_spectrum(s, out / "leaf-spectrum.png",
                        title=f"{LEAF} at 8/d, conical beam, N = {int(s.N[0]):,} rays/wavelength (PROSPECT-D at 8 deg)")
    wl, rp, tp = sp.specimen.prospect()
    idx = np.searchsorted(wl, s.wavelengths)
    err = float(max(np.abs(s.reflectance - rp[idx]).max(), np.abs(s.transmittance - tp[idx]).max()))
    lab = lab_of(s.wavelengths[s.wavelengths <= 780], s.reflectance[s.wavelengths <= 780])
    spec = load_sweep(FIXTURES / "sweeps" / "leaf-angles.toml")
    with RunStore(out / "leaf-sweep.sqlite") as store:
        res = run_sweep(spec, store)
        readings = sweep_readings(store, res.run_id)
    figs = leaf_angle_figures(readings, out)
    seconds = time.perf_counter() - t0
    summary = {"specimen": LEAF, "N": int(s.N[0]), "max_abs_error_vs_prospect": err, "lab": lab.tolist(),
               "csv": str(csv), "spectrum_plot": str(png), "sweep_run": res.run_id,
               "plots": [str(figs["polar"]), str(figs["rt_vs_incidence"])], "seconds": seconds}
    lines = [f"leaf: {LEAF} at 8/d (conical beam), 400-2500 nm every 5 nm, {int(s.N[0]):,} rays/wavelength",
             f"  max |R - R_PROSPECT|, |T - T_PROSPECT| = {err:.4f} (eq. 3.5 bound 0.005 at 99 %); "
             f"L*a*b* (D65) = {lab[0]:.1f}, {lab[1]:.1f}, {lab[2]:.1f}",
             f"  angular sweep {res.run_id}: incidences 0-80 deg, BRDF and BTDF, {seconds:.1f} s",
             f"  wrote {png}, {figs['polar']} and {figs['rt_vs_incidence']}"]
    return summary, lines


def run_demo(out: Path, seed: int = 20261122, progress: bool = False) -> dict[str, Any]:
    """Run every demo stage, write files into ``out``, return a summary (with printable lines).

    ``progress``: a bar over the stages with an ETA, on stderr (the CLI asks for it on a terminal).
    """
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, Any] = {"out": str(out), "lines": []}
    stages = (("spectro", _spectro_demo), ("gonio", _gonio_demo), ("leaf", _leaf_demo), ("scan", _scan_demo))
    with tqdm(total=len(stages) + 1, disable=not progress, desc="demo", unit="stage", leave=False,
              dynamic_ncols=True) as bar:
        for name, stage in stages:
            bar.set_postfix_str(name)
            part, lines = stage(out, seed)
            summary[name] = part
            summary["lines"] += lines
            bar.update()
        bar.set_postfix_str("compare")
        summary["compare"], lines = _compare_demo(out, summary["scan"], seed)
        summary["lines"] += lines
        bar.update()
    return summary


if __name__ == "__main__":  # python -m bench.demo leaf-figures STORE RUN_ID OUT_DIR [THETA_I WAVELENGTH]
    import sys

    from bench.sweep import sweep_readings as _readings

    if len(sys.argv) not in (5, 7) or sys.argv[1] != "leaf-figures":
        sys.exit("usage: python -m bench.demo leaf-figures STORE RUN_ID OUT_DIR [THETA_I WAVELENGTH_NM]")
    _out = Path(sys.argv[4])
    _out.mkdir(parents=True, exist_ok=True)
    with RunStore(sys.argv[2], create=False) as _store:
        _df = _readings(_store, sys.argv[3])
    _extra = {"theta_i": float(sys.argv[5]), "wavelength_nm": float(sys.argv[6])} if len(sys.argv) == 7 else {}
    for _k, _p in leaf_angle_figures(_df, _out, **_extra).items():
        print(f"{_k}: {_p}")
