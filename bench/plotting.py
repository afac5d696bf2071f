"""Figures people can act on. matplotlib is imported here only, with the Agg backend."""

from __future__ import annotations

from pathlib import Path

from bench.instruments import Spectrum

__all__ = ["plot_spectrum", "pyplot"]


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
