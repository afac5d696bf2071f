"""Small-multiple figures of a comparison: every incidence (BSDF) or every spectrum (spectra).

* :func:`sigma_grid` -- one polar panel per incidence (at its worst wavelength), panels ordered
  worst first by the group verdicts, z = (virtual - actual) / u_c on one symmetric colour scale
  shared by every panel and every model (``fig-sigma-grid-<model>``);
* :func:`value_grid` -- the BSDF of the actual record and of every model, rows = records, columns
  = incidences (worst first), one logarithmic colour scale for the whole figure
  (``fig-value-grid``);
* :func:`spectra_grid` -- one panel per (specimen, CIE geometry): actual and models with
  k-sigma bands (``fig-spectral-overlay``);
* :func:`bland_altman_grid` -- one panel per model, differences in the record's unit
  (``fig-bland-altman``).

At most :data:`MAX_PANELS` panels are drawn per figure; when there are more, the worst are drawn
and the caption says how many are left out (the group tables list them all).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from bench.core.outputs import save_figure
from compare.stats import Comparison

__all__ = ["MAX_PANELS", "incidence_order", "sigma_grid", "value_grid", "spectra_grid", "bland_altman_grid",
           "unit_of"]

MAX_PANELS = 24
_COLOURS = ["tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan"]


def unit_of(kind: str, quantity: str) -> str:
    """The unit label of a record's values: ``1/sr`` for a BSDF, ``1`` otherwise."""
    return "1/sr" if kind == "bsdf" and quantity == "BSDF" else "1"


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> Path:
    save_figure(fig, path)
    _plt().close(fig)
    return path


def incidence_order(groups: Mapping[str, pd.DataFrame], points: pd.DataFrame) -> list[tuple[float, float, float]]:
    """(theta_i, phi_i, worst wavelength) of every incidence, worst first: by the lowest group
    p-value over all models (rejects first), ties by angle."""
    worst: dict[tuple[float, float], tuple[float, float]] = {}
    for g in groups.values():
        if not {"theta_i", "phi_i", "wavelength_nm"} <= set(g.columns):
            continue
        for r in g.itertuples(index=False):
            key = (float(r.theta_i), float(r.phi_i))
            p = float(r.p_value) if r.p_value is not None and np.isfinite(r.p_value) else 1.0
            if key not in worst or p < worst[key][0]:
                worst[key] = (p, float(r.wavelength_nm))
    for (ti, pi_), sub in points.groupby(["theta_i", "phi_i"], sort=True):
        worst.setdefault((float(ti), float(pi_)), (1.0, float(sub.wavelength_nm.iloc[0])))
    return [(t, p, w) for (t, p), (_, w) in sorted(worst.items(), key=lambda kv: (kv[1][0], kv[0]))]


def _grid(n: int, per_row: int = 4) -> tuple[int, int]:
    cols = min(per_row, max(n, 1))
    return int(math.ceil(max(n, 1) / cols)), cols


def _panel_points(p: pd.DataFrame, ti: float, pi_: float, wl: float) -> pd.DataFrame:
    return p[(p.theta_i == ti) & (p.phi_i == pi_) & (p.wavelength_nm == wl)]


def _polar_xy(p: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    th = p.theta_r.to_numpy(float)
    return np.radians(p.phi_r.to_numpy(float)), np.where(th > 90, 180 - th, th)


def sigma_grid(c: Comparison, order: list[tuple[float, float, float]], path: Path, k: float, zlim: float) -> Path:
    """z maps of one model, one polar panel per incidence (``order``), shared colour scale."""
    plt = _plt()
    from matplotlib.colors import Normalize

    shown = order[:MAX_PANELS]
    nr, nc = _grid(len(shown))
    fig, axes = plt.subplots(nr, nc, subplot_kw={"projection": "polar"}, figsize=(3.2 * nc + 1.2, 3.3 * nr),
                             dpi=90, squeeze=False, layout="constrained")
    norm = Normalize(vmin=-zlim, vmax=zlim)
    sc = None
    for ax, (ti, pi_, wl) in zip(axes.flat, shown):
        q = _panel_points(c.points, ti, pi_, wl)
        x, r = _polar_xy(q)
        sc = ax.scatter(x, r, c=np.nan_to_num(q.z.to_numpy(float)), cmap="RdBu_r", norm=norm, s=14)
        ax.plot([np.radians(pi_)], [ti], marker="*", color="black", ms=9, ls="none")
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_yticklabels(["30°", "60°", "90°"], fontsize=6)
        ax.tick_params(labelsize=6)
        ax.set_title(f"θi {ti:g}°, φi {pi_:g}°, {wl:g} nm", fontsize=8)
    for ax in list(axes.flat)[len(shown):]:
        ax.set_axis_off()
    if sc is not None:
        fig.colorbar(sc, ax=axes, shrink=0.8, label=f"z = (virtual − actual)/u_c (σ); |z| ≤ {k:g} expected")
    fig.suptitle(f"{c.name}: discrepancy per incidence, worst first (radius θr in degrees, angle φr)", fontsize=9)
    return _save(fig, path)


def value_grid(comps: Mapping[str, Comparison], order: list[tuple[float, float, float]], path: Path,
               unit: str, max_cols: int = 8) -> Path:
    """Rows: actual and every model; columns: incidences worst first; one log colour scale."""
    plt = _plt()
    from matplotlib.colors import LogNorm

    shown = order[:max_cols]
    first = next(iter(comps.values()))
    rows = [("actual", first, "actual_value")] + [(n, c, "virtual_value") for n, c in comps.items()]
    vals = np.concatenate([c.points[col].to_numpy(float) for _, c, col in rows])
    pos = vals[np.isfinite(vals) & (vals > 0)]
    lo, hi = (float(np.percentile(pos, 1)), float(pos.max())) if pos.size else (1e-3, 1.0)
    norm = LogNorm(vmin=max(lo, hi * 1e-6), vmax=max(hi, lo * 10))
    fig, axes = plt.subplots(len(rows), len(shown), subplot_kw={"projection": "polar"},
                             figsize=(2.8 * len(shown) + 1.2, 2.9 * len(rows)), dpi=90, squeeze=False,
                             layout="constrained")
    sc = None
    for i, (name, c, col) in enumerate(rows):
        for j, (ti, pi_, wl) in enumerate(shown):
            ax = axes[i, j]
            q = _panel_points(c.points, ti, pi_, wl)
            x, r = _polar_xy(q)
            v = q[col].to_numpy(float)
            sc = ax.scatter(x, r, c=np.where(v > 0, v, np.nan), cmap="viridis", norm=norm, s=12)
            ax.set_ylim(0, 90)
            ax.set_yticks([30, 60, 90])
            ax.set_yticklabels(["30°", "60°", "90°"], fontsize=5)
            ax.tick_params(labelsize=5)
            ax.set_title(f"{name}\nθi {ti:g}°, {wl:g} nm", fontsize=7)
    if sc is not None:
        fig.colorbar(sc, ax=axes, shrink=0.8, label=f"BSDF ({unit}), one scale for all panels")
    return _save(fig, path)


def spectra_grid(comps: Mapping[str, Comparison], path: Path, k: float, unit: str) -> tuple[Path, int]:
    """One panel per (specimen, geometry, channel) group; returns the path and the panel count."""
    plt = _plt()
    first = next(iter(comps.values()))
    keys = ["specimen", "geometry", "channel"]
    groups = list(first.points.groupby(keys, sort=True, dropna=False))[:MAX_PANELS]
    nr, nc = _grid(len(groups), 3)
    fig, axes = plt.subplots(nr, nc, figsize=(4.2 * nc, 3.0 * nr), dpi=90, squeeze=False, layout="constrained")
    for ax, (key, p) in zip(axes.flat, groups):
        p = p.sort_values("wavelength_nm", kind="stable")
        ua = np.sqrt(p.u_instrument ** 2 + np.nan_to_num(p.actual_std) ** 2)
        ax.plot(p.wavelength_nm, p.actual_value, color="tab:blue", lw=1.6, label="actual")
        ax.fill_between(p.wavelength_nm, p.actual_value - k * ua, p.actual_value + k * ua, color="tab:blue",
                        alpha=0.2)
        for (name, c), colour in zip(comps.items(), _COLOURS):
            q = c.points
            q = q[(q.specimen.astype(str) == str(key[0])) & (q.geometry.astype(str) == str(key[1]))
                  & (q.channel == key[2])].sort_values("wavelength_nm", kind="stable")
            sv = np.nan_to_num(q.virtual_std)
            ax.plot(q.wavelength_nm, q.virtual_value, color=colour, lw=1.2, label=name)
            ax.fill_between(q.wavelength_nm, q.virtual_value - k * sv, q.virtual_value + k * sv, color=colour,
                            alpha=0.2)
        ax.set_xlabel("wavelength (nm)")
        ax.set_ylabel(f"{key[2]} ({unit})")
        ax.grid(alpha=0.3)
        spec = "" if key[0] is None or str(key[0]) in ("None", "nan") else f"{key[0]}, "
        ax.set_title(f"{spec}{key[1]}", fontsize=8)
    for ax in list(axes.flat)[len(groups):]:
        ax.set_axis_off()
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 6), fontsize=8)
    return _save(fig, path), len(groups)


def bland_altman_grid(comps: Mapping[str, Comparison], path: Path, unit: str) -> Path:
    """One Bland-Altman panel per model, coloured by incidence (BSDF) or group (spectra)."""
    plt = _plt()
    nr, nc = _grid(len(comps), 3)
    fig, axes = plt.subplots(nr, nc, figsize=(4.6 * nc, 3.4 * nr), dpi=90, squeeze=False, layout="constrained")
    for ax, (name, c) in zip(axes.flat, comps.items()):
        p = c.points
        by = "theta_i" if p.theta_i.notna().any() else "geometry"
        for (g, q), colour in zip(p.groupby(by, sort=True), plt.get_cmap("tab10").colors):
            ax.scatter(0.5 * (q.actual_value + q.virtual_value), q["diff"], s=7, alpha=0.6, color=colour,
                       label=f"θi {g:g}°" if by == "theta_i" else str(g))
        ba = c.summary["bland_altman"]
        if ba["bias"] is not None:
            ax.axhline(ba["bias"], color="black", lw=1.2)
        for key in ("lower", "upper"):
            if ba[key] is not None:
                ax.axhline(ba[key], color="black", lw=0.9, ls="--")
        ax.set_xlabel(f"mean of actual and virtual ({unit})")
        ax.set_ylabel(f"virtual − actual ({unit})")
        ax.grid(alpha=0.3)
        ax.set_title(name, fontsize=9)
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    for ax in list(axes.flat)[len(comps):]:
        ax.set_axis_off()
    fig.suptitle("Bland-Altman: bias (solid) and 95 % limits of agreement (dashed)", fontsize=9)
    return _save(fig, path)
