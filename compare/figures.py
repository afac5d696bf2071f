"""Figures people can act on: spectra, hemispherical BSDF maps, in-plane curves, and the figures
of a comparison report (spectral overlay and z, polar and sigma maps, Bland-Altman).

matplotlib is imported here only, with the Agg backend (:func:`pyplot`), when a figure is drawn:
the CLI imports this module lazily. Figure ids are stable (:func:`figure_ids`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from bench.core.outputs import save_figure
from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from compare.align import record_kind, record_quantity
from compare._grid import bland_altman_grid, incidence_order, sigma_grid, spectra_grid, unit_of, value_grid
from compare.stats import Comparison, nominal_fraction

__all__ = ["plot_spectrum", "plot_bsdf_polar", "plot_in_plane", "pyplot", "slug", "figure_ids", "report_figures"]


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_spectrum(s: Spectrum, path: str | Path, title: str | None = None) -> Path:
    """Reflectance and transmittance against wavelength with their confidence bands."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    q = "reflectance factor" if s.meta.get("quantity") == "reflectance factor" else "reflectance"
    for values, ci, label, colour in ((s.reflectance, s.reflectance_ci, q, "tab:blue"),
                                      (s.transmittance, s.transmittance_ci, "transmittance", "tab:orange")):
        if values.any():
            ax.plot(s.wavelengths, values, color=colour, lw=1.6, label=label)
            ax.fill_between(s.wavelengths, ci[:, 0], ci[:, 1], color=colour, alpha=0.25,
                            label=f"{1 - s.delta:.0%} interval")
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("fraction (1)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    n = np.broadcast_to(np.asarray(s.N), np.asarray(s.wavelengths).shape)
    n_text = f"{int(n.min()):,}" if n.min() == n.max() else f"{int(n.min()):,}-{int(n.max()):,}"
    measured = s.meta.get("measured_as")
    as_text = f" (measured as {measured})" if measured and str(measured) != str(s.geometry) else ""
    ax.set_title(title or f"{s.meta.get('specimen', '')} at {s.geometry}{as_text}, N = {n_text} rays/wavelength",
                 fontsize=10)
    return _save(fig, path)


def plot_bsdf_polar(record, path: str | Path, wavelength_nm: float | None = None, title: str | None = None,
                    norm=None) -> Path:
    """Hemispherical (polar) maps of a patch record: radius = theta, angle = phi, colour = BSDF.

    One panel per hemisphere that received light (reflection, transmission), log colour scale
    when the values span more than two decades (or the given matplotlib ``norm``, so several
    maps can share one scale); the incidence is marked.
    """
    from matplotlib.colors import LogNorm, Normalize

    plt = pyplot()
    t = record.table
    if wavelength_nm is None:
        wavelength_nm = float(t.wavelength_nm.iloc[0])
    t = t[t.wavelength_nm == wavelength_nm]
    panels = [h for h in ("R", "T") if (t[t.hemisphere == h].value > 0).any()] or ["R"]
    fig, axes = plt.subplots(1, len(panels), subplot_kw={"projection": "polar"}, figsize=(5.2 * len(panels), 4.8),
                             dpi=110, squeeze=False)
    for ax, h in zip(axes[0], panels):
        sub = t[t.hemisphere == h]
        v = sub.value.to_numpy()
        positive = v[v > 0]
        if norm is not None:
            panel_norm = norm
        elif positive.size and positive.max() / max(positive.min(), 1e-300) > 100:
            panel_norm = LogNorm(vmin=max(positive.min(), positive.max() * 1e-4), vmax=positive.max())
        else:
            panel_norm = Normalize(vmin=0.0, vmax=max(float(v.max()), 1e-12))
        # theta measured from this hemisphere's pole
        tmin = sub.theta_min.to_numpy() if h == "R" else 180.0 - sub.theta_max.to_numpy()
        tmax = sub.theta_max.to_numpy() if h == "R" else 180.0 - sub.theta_min.to_numpy()
        pmin, pmax = np.radians(sub.phi_min.to_numpy()), np.radians(sub.phi_max.to_numpy())
        cmap = plt.get_cmap("viridis")
        colours = cmap(panel_norm(np.where(v > 0, v, np.nan)))
        colours[~(v > 0)] = (0.92, 0.92, 0.92, 1.0)  # empty patches: light grey, not a colour
        _polar_patches(ax, pmin, pmax, tmin, tmax, colours)
        ti, pi_ = float(sub.theta_i.iloc[0]), float(sub.phi_i.iloc[0])
        ax.plot([np.radians(pi_)], [ti], marker="*", color="red", ms=12, ls="none", label="incidence")
        if h == "R":
            ax.plot([np.radians(pi_ + 180.0)], [ti], marker="o", mfc="none", mec="white", ms=10, ls="none",
                    label="specular")
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_yticklabels(["30°", "60°", "90°"])  # radius: theta_r in degrees
        ax.set_title(("BRDF (reflection)" if h == "R" else "BTDF (transmission)") + " [1/sr]", fontsize=10)
        fig.colorbar(plt.cm.ScalarMappable(norm=panel_norm, cmap=cmap), ax=ax, shrink=0.75, pad=0.1)
        ax.legend(loc="lower left", fontsize=7, bbox_to_anchor=(-0.15, -0.12))
    meta = record.meta
    fig.suptitle(title or f"{meta.get('specimen', '')}\ntheta_i = {ti:g} deg, {wavelength_nm:g} nm, "
                 f"{meta.get('rays', 0):,} rays ({meta.get('method', '')})", fontsize=10)
    return _save(fig, path)


def plot_in_plane(curves, path: str | Path, title: str = "In-plane BRDF") -> Path:
    """In-plane BRDF against signed viewing angle. ``curves``: list of (label, theta_signed,
    value, lo, hi) arrays; lo/hi may be None."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    for label, x, y, lo, hi in curves:
        line, = ax.plot(x, y, marker="o", ms=3, lw=1.4, label=label)
        if lo is not None and hi is not None:
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.25)
    ax.set_xlabel("viewing angle theta_r (deg; > 0 on the specular side)")
    ax.set_ylabel("BRDF (1/sr)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    return _save(fig, path)


# --- report figures -------------------------------------------------------------------------


def slug(name: str) -> str:
    """The id-safe form of a candidate name (``"GGX a=0.2"`` -> ``"ggx-a-0-2"``)."""
    s = re.sub(r"[^a-z0-9]+", "-", str(name).lower()).strip("-")
    return s or "candidate"


def figure_ids(kind: str, names: Sequence[str]) -> list[str]:
    """The ids of the figures a report of ``kind`` (``"spectrum"``/``"bsdf"``) with candidates
    ``names`` contains."""
    if kind == "spectrum":
        ids = ["fig-spectral-overlay", "fig-spectral-z"]
    else:
        ids = ["fig-value-grid"] + [f"fig-sigma-grid-{slug(n)}" for n in names] + ["fig-in-plane", "fig-polar-actual"]
        for n in names:
            ids += [f"fig-polar-{slug(n)}", f"fig-sigma-{slug(n)}"]
    return ids + ["fig-bland-altman"]


def _polar_patches(ax: Any, pmin: np.ndarray, pmax: np.ndarray, tmin: np.ndarray, tmax: np.ndarray,
                   colours: np.ndarray, arc_points: int = 9) -> None:
    """Collector patches (phi in radians, theta in degrees) on polar axes as ONE PolyCollection.

    Each patch is a polygon whose two arcs are sampled at ``arc_points`` azimuths (the polar
    transform maps vertices, not edges). ``ax.bar`` drew the same wedges as one Rectangle artist
    per patch, each re-interpolated at draw time: 30x slower for a 900-patch collector.
    """
    from matplotlib.collections import PolyCollection

    if len(pmin) == 0:
        return
    f = np.linspace(0.0, 1.0, arc_points)
    phi = pmin[:, None] + (pmax - pmin)[:, None] * f[None, :]           # (patches, arc_points)
    inner = np.stack([phi, np.broadcast_to(tmin[:, None], phi.shape)], axis=-1)
    outer = np.stack([phi[:, ::-1], np.broadcast_to(tmax[:, None], phi.shape)], axis=-1)
    verts: Any = np.concatenate([inner, outer], axis=1)  # one (N, M, 2) array: matplotlib's fast path
    ax.add_collection(PolyCollection(verts, facecolors=colours,
                                     edgecolors="none", linewidths=0.0))


_COLOURS = ["tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan"]


def _save(fig: Any, path: str | Path) -> Path:
    """Lay out, write (creating the folder) and close ``fig``; the path written."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    save_figure(fig, p)
    pyplot().close(fig)
    return p


def _fig(fid: str, path: Path, alt: str, caption: str, group: str | None = None) -> dict[str, Any]:
    return {"id": fid, "path": path, "alt": alt, "caption": caption, "group": group or fid}


def report_figures(act: Any, comps: dict[str, Comparison], recs: dict[str, Any], figdir: Path, k: float,
                   map_wl: float | None, map_inc: tuple[float, float] | None,
                   groups: dict[str, pd.DataFrame] | None = None) -> list[dict[str, Any]]:
    """Every figure of a report (ids: :func:`figure_ids`). BSDF: small multiples of every
    incidence first (worst first, one colour scale per quantity across models), then the
    single-incidence maps at ``map_wl``/``map_inc`` (default: the worst incidence)."""
    figs: list[dict[str, Any]] = []
    kind = record_kind(act)
    unit = unit_of(kind, record_quantity(act))
    if kind == "spectrum":
        figs += _spectral_figures(comps, figdir, k, unit)
    else:
        first = next(iter(comps.values()))
        order = incidence_order(groups or {}, first.points)
        if map_inc is None and order:
            map_inc, map_wl = (order[0][0], order[0][1]), (order[0][2] if map_wl is None else map_wl)
        n_inc = len(order)
        left = f" ({n_inc - 24} more in the group tables)" if n_inc > 24 else ""
        figs.append(_fig("fig-value-grid", value_grid(comps, order, figdir / "fig-value-grid.png", unit),
                         "BSDF of the actual record and every model at every incidence, one colour scale",
                         f"Rows: actual and models; columns: incidences worst first (up to 8 of {n_inc}); "
                         f"one logarithmic colour scale for all panels.", group="grids"))
        zs = np.concatenate([np.abs(c.points.z.to_numpy(float)) for c in comps.values()])
        zs = zs[np.isfinite(zs)]
        zlim = float(min(10.0, max(3.0, np.percentile(zs, 99) if zs.size else 3.0)))
        for name, c in comps.items():
            s = slug(name)
            figs.append(_fig(f"fig-sigma-grid-{s}", sigma_grid(c, order, figdir / f"fig-sigma-grid-{s}.png", k, zlim),
                             f"Discrepancy of {name} in sigma units at every incidence",
                             f"{name}: one panel per incidence ({n_inc}), worst first{left}; colour scale "
                             f"+-{zlim:.3g} sigma shared by every model.", group="grids"))
        figs += _bsdf_figures(act, comps, recs, figdir, k, map_wl, map_inc)
    figs.append(_fig("fig-bland-altman", bland_altman_grid(comps, figdir / "fig-bland-altman.png", unit),
                     "Bland-Altman plot of every candidate against the actual record, one panel per model",
                     f"Differences against means in {unit}; bias +- 1.96 sd of the differences; colour = incidence."))
    return figs


def _spectral_figures(comps: dict[str, Comparison], figdir: Path, k: float, unit: str) -> list[dict[str, Any]]:
    plt = pyplot()
    first = next(iter(comps.values()))
    chans = list(dict.fromkeys(first.points.channel))
    path, n = spectra_grid(comps, figdir / "fig-spectral-overlay.png", k, unit)
    f1 = _fig("fig-spectral-overlay", path,
              "Spectral overlay of the actual record and every candidate with uncertainty bands, one panel per spectrum",
              f"{n} spectra with {k:g}-sigma bands (actual: instrument and own std; candidates: Monte Carlo std).")
    fig, ax = plt.subplots(figsize=(8, 3.6), dpi=110)
    for (name, c), colour in zip(comps.items(), _COLOURS):
        for ch, q in c.points.groupby("channel", sort=False):
            q = q.sort_values("wavelength_nm", kind="stable")
            for _, qq in q.groupby(["specimen", "geometry"], sort=False, dropna=False):
                ax.plot(qq.wavelength_nm, qq.z, marker="o", ms=3, lw=1, color=colour,
                        ls="-" if ch == chans[0] else "--")
            ax.plot([], [], color=colour, ls="-" if ch == chans[0] else "--", label=f"{name} ({ch})")
    ax.axhspan(-k, k, color="grey", alpha=0.15, label=f"|z| <= {k:g}")
    ax.axhline(0, color="black", lw=0.8)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("z = (virtual - actual) / u_c (sigma)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Discrepancy in units of the combined standard uncertainty", fontsize=10)
    f2 = _fig("fig-spectral-z", _save(fig, figdir / "fig-spectral-z.png"),
              "Discrepancy in sigma units against wavelength for every candidate",
              "z-scores per wavelength; the grey band is the coverage interval.")
    return [f1, f2]


def _select(rec: BSDFRecord, wl: float, inc: tuple[float, float]) -> BSDFRecord:
    t = rec.table
    sel = t[(t.wavelength_nm == wl) & (t.theta_i == inc[0]) & (t.phi_i == inc[1])]
    return BSDFRecord(sel, dict(rec.meta))  # row labels kept: pairs refer to them


def _has_bounds(t: pd.DataFrame) -> bool:
    cols = ["theta_min", "theta_max", "phi_min", "phi_max"]
    return len(t) > 0 and set(cols) <= set(t.columns) and bool(np.all(np.isfinite(t[cols].to_numpy(float))))


def _polar_scatter(t: pd.DataFrame, values: np.ndarray, path: Path, title: str, label: str, cmap: str = "viridis",
                   norm: Any = None) -> Path:
    """A hemispherical map of a record without patch bounds: one dot per direction."""
    plt = pyplot()
    from matplotlib.colors import Normalize

    fig, ax = plt.subplots(subplot_kw={"projection": "polar"}, figsize=(5.6, 4.8), dpi=110)
    r = np.where(t.theta_r.to_numpy(float) > 90, 180 - t.theta_r.to_numpy(float), t.theta_r.to_numpy(float))
    norm = norm or Normalize(vmin=0.0, vmax=max(float(np.nanmax(values)) if len(values) else 1.0, 1e-12))
    sc = ax.scatter(np.radians(t.phi_r.to_numpy(float)), r, c=values, cmap=cmap, norm=norm, s=22)
    if len(t):
        ax.plot([np.radians(float(t.phi_i.iloc[0]))], [float(t.theta_i.iloc[0])], marker="*", color="red", ms=12,
                ls="none", label="incidence")
        ax.legend(loc="lower left", fontsize=7, bbox_to_anchor=(-0.15, -0.12))
    ax.set_ylim(0, 90)
    fig.colorbar(sc, ax=ax, shrink=0.75, pad=0.1, label=label)
    ax.set_title(title, fontsize=10)
    return _save(fig, path)


def _sigma_map(c: Comparison, act_sel: pd.DataFrame, wl: float, inc: tuple[float, float], path: Path,
               k: float) -> Path:
    """z = (virtual - actual) / u_c on the actual's geometry: patches when the actual has bounds."""
    plt = pyplot()
    from matplotlib.colors import Normalize

    p = c.points
    p = p[(p.wavelength_nm == wl) & (p.theta_i == inc[0]) & (p.phi_i == inc[1])]
    z = p.z.to_numpy(float)
    lim = float(min(10.0, max(3.0, np.nanmax(np.abs(z)) if np.isfinite(z).any() else 3.0)))
    norm = Normalize(vmin=-lim, vmax=lim)
    title = f"{c.name}:\n(virtual - actual) / u_c, theta_i = {inc[0]:g} deg, {wl:g} nm"
    panels = [h for h in ("R", "T") if (p.channel == h).any()] or ["R"]
    if not _has_bounds(act_sel):
        return _polar_scatter(p, np.nan_to_num(z), path, title, "z (sigma)", "RdBu_r", norm)
    bounds = act_sel.loc[p.actual_index.to_numpy()] if len(p) else act_sel.iloc[0:0]
    fig, axes = plt.subplots(1, len(panels), subplot_kw={"projection": "polar"}, figsize=(5.4 * len(panels), 4.8),
                             dpi=110, squeeze=False)
    cmap = plt.get_cmap("RdBu_r")
    for ax, h in zip(axes[0], panels):
        m = (p.channel == h).to_numpy()
        b = bounds[m]
        tmin = b.theta_min.to_numpy(float) if h == "R" else 180.0 - b.theta_max.to_numpy(float)
        tmax = b.theta_max.to_numpy(float) if h == "R" else 180.0 - b.theta_min.to_numpy(float)
        pmin, pmax = np.radians(b.phi_min.to_numpy(float)), np.radians(b.phi_max.to_numpy(float))
        zz = z[m]
        colours = np.where(np.isfinite(zz)[:, None], cmap(norm(np.nan_to_num(zz))), (0.85, 0.85, 0.85, 1.0))
        _polar_patches(ax, pmin, pmax, tmin, tmax, colours)
        ax.plot([np.radians(inc[1])], [inc[0]], marker="*", color="black", ms=11, ls="none")
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_yticklabels(["30°", "60°", "90°"])  # radius: theta_r in degrees
        ax.set_title(f"{'reflection' if h == 'R' else 'transmission'} (grey: no z)", fontsize=9)
        fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.75, pad=0.1,
                     label=f"z (sigma); |z| <= {k:g} expected for {nominal_fraction(k):.1%}")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def _bsdf_figures(act: BSDFRecord, comps: dict[str, Comparison], recs: dict[str, Any], figdir: Path, k: float,
                  map_wl: float | None, map_inc: tuple[float, float] | None) -> list[dict[str, Any]]:
    t = act.table
    wl = float(t.wavelength_nm.iloc[0]) if map_wl is None else float(map_wl)
    inc: tuple[float, float] = ((float(t.theta_i.iloc[0]), float(t.phi_i.iloc[0])) if map_inc is None
                                else (float(map_inc[0]), float(map_inc[1])))
    figs: list[dict[str, Any]] = []
    # in-plane curves
    first = next(iter(comps.values()))
    p0 = first.points
    p0 = p0[(p0.wavelength_nm == wl) & (p0.theta_i == inc[0]) & (p0.phi_i == inc[1]) & (p0.channel == "R")]
    act_sel = _select(act, wl, inc)
    sel, signed = _in_plane(p0, act_sel.table, inc, first.aligned.meta.get("angle_tol_deg", 1.0))
    curves = []
    tiny = 1e-12
    if sel.any():
        q = p0[sel].assign(x=signed[sel]).sort_values("x", kind="stable")
        ua = np.sqrt(q.u_instrument ** 2 + np.nan_to_num(q.actual_std) ** 2)
        curves.append(("actual", q.x.to_numpy(), np.maximum(q.actual_value.to_numpy(), tiny),
                       np.maximum((q.actual_value - k * ua).to_numpy(), tiny),
                       np.maximum((q.actual_value + k * ua).to_numpy(), tiny)))
        for name, c in comps.items():
            pc = c.points
            pc = pc[(pc.wavelength_nm == wl) & (pc.theta_i == inc[0]) & (pc.phi_i == inc[1]) & (pc.channel == "R")]
            s2, x2 = _in_plane(pc, act_sel.table, inc, c.aligned.meta.get("angle_tol_deg", 1.0))
            qc = pc[s2].assign(x=x2[s2]).sort_values("x", kind="stable")
            sv = np.nan_to_num(qc.virtual_std)
            curves.append((name, qc.x.to_numpy(), np.maximum(qc.virtual_value.to_numpy(), tiny),
                           np.maximum((qc.virtual_value - k * sv).to_numpy(), tiny),
                           np.maximum((qc.virtual_value + k * sv).to_numpy(), tiny)))
    path = figdir / "fig-in-plane.png"
    if curves:
        plot_in_plane(curves, path, title=f"In-plane BRDF, theta_i = {inc[0]:g} deg, phi_i = {inc[1]:g} deg, "
                                          f"{wl:g} nm ({k:g}-sigma bands)")
        caption = (f"Points with phi_r at phi_i or phi_i + 180 deg (patches containing the plane of incidence); "
                   f"{k:g}-sigma bands.")
    else:
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(7, 2.5), dpi=110)
        ax.text(0.5, 0.5, "no compared point lies in the plane of incidence", ha="center", va="center")
        ax.set_axis_off()
        _save(fig, path)
        caption = "No compared point lies in the plane of incidence."
    figs.append(_fig("fig-in-plane", path, "In-plane BRDF curves of the actual record and every candidate", caption))
    # hemispherical maps
    figs.append(_fig("fig-polar-actual", _map(act_sel, figdir / "fig-polar-actual.png", f"actual: {wl:g} nm, "
                                              f"theta_i = {inc[0]:g} deg"),
                     "Hemispherical map of the actual record",
                     f"Actual record at theta_i = {inc[0]:g} deg, {wl:g} nm (each map has its own colour scale)."))
    for name, c in comps.items():
        s = slug(name)
        rec = recs[name]
        # the candidate's incidence/wavelength nearest to the one shown (what the alignment used)
        pc = c.points[(c.points.wavelength_nm == wl) & (c.points.theta_i == inc[0]) & (c.points.phi_i == inc[1])]
        if len(pc):
            vwl = pc.virtual_wavelength_nm.dropna()
            cwl = float(vwl.iloc[0]) if len(vwl) else wl
            cinc = (float(pc.virtual_theta_i.iloc[0]), float(pc.virtual_phi_i.iloc[0]))
        else:
            cwl, cinc = wl, inc
        csel = _select(rec, cwl, cinc)
        figs.append(_fig(f"fig-polar-{s}", _map(csel, figdir / f"fig-polar-{s}.png", f"{name}: {cwl:g} nm, "
                                                f"theta_i = {cinc[0]:g} deg"),
                         f"Hemispherical map of candidate {name}",
                         f"Candidate {name} (each map has its own colour scale).", group=f"candidate-{s}"))
        figs.append(_fig(f"fig-sigma-{s}", _sigma_map(c, act_sel.table, wl, inc, figdir / f"fig-sigma-{s}.png", k),
                         f"Discrepancy map of candidate {name} in sigma units",
                         f"(virtual - actual) / u_c for {name}; blue: candidate low, red: candidate high.",
                         group=f"candidate-{s}"))
    return figs


def _in_plane(p: pd.DataFrame, act_sel: pd.DataFrame, inc: tuple[float, float], tol: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Which points lie in the plane of incidence (their patch contains phi_i or phi_i + 180, or,
    without patch bounds, their azimuth is within ``tol``) and their signed viewing angle
    (> 0 on the specular side)."""
    phi = p.phi_r.to_numpy(float)
    th = p.theta_r.to_numpy(float)
    if _has_bounds(act_sel) and len(p):
        b = act_sel.loc[p.actual_index.to_numpy()]
        pmin, width = b.phi_min.to_numpy(float), (b.phi_max - b.phi_min).to_numpy(float)
        src = np.mod(inc[1] - pmin, 360.0) < width
        spec = np.mod(inc[1] + 180.0 - pmin, 360.0) < width
    else:
        d_src = np.abs((phi - inc[1] + 180.0) % 360.0 - 180.0)
        d_spec = np.abs((phi - inc[1]) % 360.0 - 180.0)
        src, spec = d_src <= tol, d_spec <= tol
    sel = src | spec
    signed = np.where(spec, th, -th)
    return sel, signed


def _map(sel: BSDFRecord, path: Path, title: str) -> Path:
    if _has_bounds(sel.table):
        return plot_bsdf_polar(sel, path, title=title)
    t = sel.table
    return _polar_scatter(t, t.value.to_numpy(float), path, title, "BSDF (1/sr)")


# --- documents ----------------------------------------------------------------------------
