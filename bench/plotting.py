"""Deprecated: figures moved to :mod:`compare.figures`; this module re-exports them for one release."""

from __future__ import annotations

from compare.figures import plot_bsdf_polar, plot_in_plane, plot_spectrum, pyplot

__all__ = ["plot_spectrum", "plot_bsdf_polar", "plot_in_plane", "pyplot"]
