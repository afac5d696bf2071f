"""Tensor Gauss-Legendre cubature on rectangles, cells refined until an error estimate that is
checked passes (what numerical texts call adaptive cubature).

One primitive, used for every integral over a parameter square that the virtual instruments
certify (the visible-normal expectations of :mod:`virtual.specimens.physics`, the independent
albedo references of :mod:`virtual.quadrature`): every cell is integrated with ``order^2``
nodes and again as the sum of its four children; a cell is accepted when both agree to
``max(rtol |fine|, atol)``, else its children are refined in turn (vectorized over all open
cells of a level). The returned error is the sum of the accepted cells' ``|coarse - fine|`` --
pessimistic for smooth integrands (the fine estimate is far better than the difference), of the
right order for kinks. Integrands must be continuous for the estimate to mean anything; a jump
(an indicator) converges only like the length of its curve times the cell size.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable

import numpy as np

from bench.core.errors import SimulationError
from bench.core.geometry import gauss_legendre

__all__ = ["gauss_rule", "integrate_rectangle"]


@lru_cache(maxsize=16)
def gauss_rule(order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tensor Gauss-Legendre nodes ``(u, v)`` on [0, 1]^2 and their weights (summing to 1)."""
    x, w = gauss_legendre(order)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    u, v = np.meshgrid(x, x, indexing="ij")
    return u.ravel(), v.ravel(), np.outer(w, w).ravel()


def _estimate(func: Callable[[np.ndarray, np.ndarray], np.ndarray], cells: np.ndarray,
              order: int) -> np.ndarray:
    u, v, w = gauss_rule(order)
    u0, u1, v0, v1 = (cells[:, i:i + 1] for i in range(4))
    uu = u0 + (u1 - u0) * u
    vv = v0 + (v1 - v0) * v
    f = np.asarray(func(uu.ravel(), vv.ravel()), dtype=np.float64).reshape(uu.shape)
    return np.sum(f * w, axis=1) * ((u1 - u0) * (v1 - v0))[:, 0]


def _split(cells: np.ndarray) -> np.ndarray:
    u0, u1, v0, v1 = cells.T
    um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    kids = np.stack([np.column_stack([u0, um, v0, vm]), np.column_stack([u0, um, vm, v1]),
                     np.column_stack([um, u1, v0, vm]), np.column_stack([um, u1, vm, v1])], axis=1)
    return kids.reshape(-1, 4)


def integrate_rectangle(func: Callable[[np.ndarray, np.ndarray], np.ndarray],
                       bounds: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0),
                       start: tuple[int, int] = (4, 4), order: int = 6, rtol: float = 1e-10,
                       atol: float = 1e-12, max_level: int = 30,
                       max_cells: int = 400_000) -> tuple[float, float, int]:
    """``int int func(u, v) du dv`` over ``bounds = (u0, u1, v0, v1)``, refining cells until they converge.

    Parameters
    ----------
    func : callable
        Vectorized: ``func(u, v)`` with 1-D arrays returns the integrand at each point.
    bounds : tuple
        The rectangle.
    start : (int, int)
        Initial grid of cells.
    order : int
        Gauss-Legendre nodes per axis and cell.
    rtol, atol : float
        Per-cell acceptance ``|coarse - fine| <= max(rtol |fine|, atol)``.
    max_level, max_cells : int
        Limits; exceeding them raises :class:`SimulationError`.

    Returns
    -------
    value, error, n_evals : float, float, int
    """
    u0, u1, v0, v1 = bounds
    gu = np.linspace(u0, u1, start[0] + 1)
    gv = np.linspace(v0, v1, start[1] + 1)
    a, b = np.meshgrid(np.arange(start[0]), np.arange(start[1]), indexing="ij")
    cells = np.column_stack([gu[a.ravel()], gu[a.ravel() + 1], gv[b.ravel()], gv[b.ravel() + 1]])
    coarse = _estimate(func, cells, order)
    n_evals = len(cells) * order * order
    total, err = 0.0, 0.0
    for _ in range(max_level):
        if len(cells) == 0:
            return total, err, n_evals
        kids = _split(cells)
        fine_k = _estimate(func, kids, order)
        n_evals += len(kids) * order * order
        fine = fine_k.reshape(-1, 4).sum(axis=1)
        diff = np.abs(fine - coarse)
        ok = diff <= np.maximum(rtol * np.abs(fine), atol)
        total += float(fine[ok].sum())
        err += float(diff[ok].sum())
        bad = ~ok
        cells = kids.reshape(-1, 4, 4)[bad].reshape(-1, 4)
        coarse = fine_k.reshape(-1, 4)[bad].ravel()
        if len(cells) > max_cells:
            raise SimulationError(f"cubature: more than {max_cells} open cells (integrand not continuous?)")
    if len(cells):
        raise SimulationError(f"cubature did not converge in {max_level} levels ({len(cells)} cells open)")
    return total, err, n_evals
