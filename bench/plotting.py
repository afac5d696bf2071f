"""Figures people can act on. matplotlib is imported here only, with the Agg backend."""

from __future__ import annotations

from pathlib import Path

from bench.core.roles import Spectrum

__all__ = ["plot_spectrum", "plot_bsdf_polar", "plot_in_plane", "pyplot"]


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
    ax.set_ylabel("fraction")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"{s.meta.get('specimen', '')} at {s.geometry}, N = {int(s.N[0]):,} rays/wavelength",
                 fontsize=10)
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p)
    plt.close(fig)
    return p


def plot_bsdf_polar(record, path: str | Path, wavelength_nm: float | None = None, title: str | None = None,
                    norm=None) -> Path:
    """Hemispherical (polar) maps of a patch record: radius = theta, angle = phi, colour = BSDF.

    One panel per hemisphere that received light (reflection, transmission), log colour scale
    when the values span more than two decades (or the given matplotlib ``norm``, so several
    maps can share one scale); the incidence is marked.
    """
    import numpy as np
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
        ax.bar(x=0.5 * (pmin + pmax), height=tmax - tmin, width=pmax - pmin, bottom=tmin, color=colours,
               edgecolor="none", align="center")
        ti, pi_ = float(sub.theta_i.iloc[0]), float(sub.phi_i.iloc[0])
        ax.plot([np.radians(pi_)], [ti], marker="*", color="red", ms=12, ls="none", label="incidence")
        if h == "R":
            ax.plot([np.radians(pi_ + 180.0)], [ti], marker="o", mfc="none", mec="white", ms=10, ls="none",
                    label="specular")
        ax.set_ylim(0, 90)
        ax.set_yticks([30, 60, 90])
        ax.set_title(("BRDF (reflection)" if h == "R" else "BTDF (transmission)") + " [1/sr]", fontsize=10)
        fig.colorbar(plt.cm.ScalarMappable(norm=panel_norm, cmap=cmap), ax=ax, shrink=0.75, pad=0.1)
        ax.legend(loc="lower left", fontsize=7, bbox_to_anchor=(-0.15, -0.12))
    meta = record.meta
    fig.suptitle(title or f"{meta.get('specimen', '')}\ntheta_i = {ti:g} deg, {wavelength_nm:g} nm, "
                 f"{meta.get('rays', 0):,} rays ({meta.get('method', '')})", fontsize=10)
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p)
    plt.close(fig)
    return p


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
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p)
    plt.close(fig)
    return p
