"""Eq. 3.5 / 3.12: the Hoeffding ray budget, computed with exact decimal arithmetic, and the
time a budget takes (:func:`budget_report`)."""

from __future__ import annotations

import math
from decimal import ROUND_CEILING, Decimal, localcontext

from bench.core.errors import BudgetError
from virtual.bounds._checks import check_delta, check_patches, check_uncertainty, real, whole

__all__ = ["hoeffding_rays", "hoeffding_per_patch", "estimate_time", "budget_report"]


def hoeffding_per_patch(v: float, delta: float) -> int:
    """``ceil(ln(2/delta) / (2 v^2))`` decided exactly.

    ``v`` and ``delta`` are binary floats, i.e. exact rationals, which :class:`~decimal.Decimal`
    represents exactly. ``ln(2/delta)`` is irrational (Lindemann: the log of a rational other
    than 1 is transcendental), so the quotient is never an integer; computing it to 60
    significant digits and checking it is not within 1e-40 (relative) of an integer makes the
    ceiling exact. Should that check ever fail, the precision is raised (up to 1000 digits).
    """
    prec = 60
    while True:
        with localcontext() as ctx:
            ctx.prec = prec
            q = (Decimal(2) / Decimal(delta)).ln() / (2 * Decimal(v) * Decimal(v))
            n = q.to_integral_value(rounding=ROUND_CEILING)
            gap = min(n - q, q - (n - 1))
            if gap > q * Decimal(10) ** (20 - prec) or prec >= 1000:
                return max(1, int(n))
        prec *= 2


def hoeffding_rays(uncertainty: float, delta: float, patches: int = 1) -> int:
    """Rays needed by the Hoeffding bound: seed eq. 3.5 (``patches=1``) and eq. 3.12.

    ``N = patches * ceil(ln(2/delta) / (2 v^2))``, so that one count's estimate ``n/N`` is within
    ``v`` of its probability with probability at least ``1 - delta``.

    Parameters
    ----------
    uncertainty
        ``v``, the uncertainty of the instrument to compare with; finite, in (0, 1].
    delta
        The confidence of the seed (a failure probability), in (0, 1).
    patches
        ``m``, the number of collector patches of eq. 3.12; an integer >= 1.

    Returns
    -------
    int
        A Python int (never overflows): 105967 for ``v=0.005, delta=0.01`` and 95370300 with
        ``patches=900``. The ceiling is decided with exact decimal arithmetic.

    Raises
    ------
    BudgetError
        Naming the bad value.
    """
    v = check_uncertainty(uncertainty)
    d = check_delta(delta)
    m = check_patches(patches)
    return m * hoeffding_per_patch(v, d)



def estimate_time(n_rays: int, rays_per_second: float) -> float:
    """Seconds to cast ``n_rays`` at ``rays_per_second`` (no simulation is run).

    ``inf`` when the time does not fit a float (ray counts beyond ~1e308).

    Raises
    ------
    BudgetError
        For a negative or non-integer ray count, or a rate that is not finite and > 0.
    """
    n = whole(n_rays, "n_rays", 0)
    rate = real(rays_per_second, "rays_per_second")
    if not (math.isfinite(rate) and rate > 0.0):
        raise BudgetError(f"rays_per_second must be finite and > 0, got {rays_per_second!r}")
    try:
        return n / rate
    except OverflowError:
        return math.inf


def budget_report(uncertainty: float, delta: float, patches: int = 1,
                  rays_per_second: float = 1e7) -> dict[str, float | int]:
    """Ray count of eq. 3.5/3.12 and the time it would take, computed instantly.

    Returns
    -------
    dict
        ``{"N": int, "seconds": float, "uncertainty": v, "delta": delta, "patches": m,
        "rays_per_second": rate}``; ``N`` is exact (a Python int, e.g. ~2.6e12 at ``v=1e-6``).
    """
    n = hoeffding_rays(uncertainty, delta, patches)
    return {
        "N": n,
        "seconds": estimate_time(n, rays_per_second),
        "uncertainty": float(uncertainty),
        "delta": float(delta),
        "patches": int(patches),
        "rays_per_second": float(rays_per_second),
    }
