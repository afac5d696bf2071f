"""The residual figure of a fit: one panel per incidence/wavelength block (or per spectrum and
quantity), the residuals against the patch index or the wavelength, with the +-2 band a good
fit stays inside about 95 % of the time. matplotlib loads only when a figure is drawn."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bench.core.outputs import save_figure
from bench.identify.fit import FitResult

__all__ = ["plot_residuals", "MAX_PANELS"]

#: panels drawn at most (a record of many incidences shows its first ones and says so)
MAX_PANELS = 12


def plot_residuals(result: FitResult, path: str | Path) -> Path:
    """Draw ``result``'s residuals (deviance residuals for counts, whitened for readings)."""
    from compare.figures import pyplot

    plt = pyplot()
    groups = result.groups[:MAX_PANELS] or ()
    n = max(len(groups), 1)
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), dpi=110, squeeze=False)
    for ax, g in zip(axes.ravel(), groups):
        r = result.residuals[g.start:g.stop]
        ax.axhspan(-2.0, 2.0, color="0.9", zorder=0)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.plot(np.asarray(g.x)[:len(r)], r, ".", ms=3)
        ax.set_title(g.label, fontsize=9)
        ax.set_xlabel(result.xlabel, fontsize=8)
        ax.set_ylabel("residual", fontsize=8)
    for ax in axes.ravel()[len(groups):]:
        ax.set_visible(False)
    more = f" (first {MAX_PANELS} of {len(result.groups)} blocks)" if len(result.groups) > MAX_PANELS else ""
    fig.suptitle(f"{result.specimen}: chi2 {result.chi2:.4g}, dof {result.dof}{more}", fontsize=9)
    fig.tight_layout()
    out = Path(path)
    save_figure(fig, out)
    plt.close(fig)
    return out
