"""Reference integrals of a specimen's density over the collector patches.

For an incident direction ``wi`` the probability that a ray leaves through a patch P is

    p(P) = int_P f_s(wi, wo) |cos theta_o| d omega_o
         = int int f_s(wi, wo(theta, phi)) |cos theta| sin theta d theta d phi,

and the directional albedo is the sum over both hemispheres. These numbers are an *independent*
reference for the ray-counting kernels (they use only :meth:`Specimen.bsdf`, never ``scatter``)
and the cell probabilities of the exact fast path (one multinomial draw instead of N rays).

Method: tensor Gauss-Legendre in (theta, phi) on every patch, adaptively refined. A cell is
accepted when its estimate agrees with the sum over its four children (both with ``order^2``
nodes) to ``max(rtol * |value|, atol)``; otherwise the children are refined
in turn, vectorized over all open cells at each level. Narrow lobes that the first nodes might
miss entirely are found from the specimen's :meth:`~virtual.specimens.Specimen.lobes` hints:
cells near a lobe are split until they are no larger than a fraction of its width before the
error test starts.

Certification (:func:`certified_patch_integrals`, what the exact fast path uses): the patch
integrals are accepted only when (a) the sum of the accepted cells' error estimates and (b) the
gap between their total and an *independent* directional albedo are both below
:data:`CERTIFY_TOL`. The independent albedo is the specimen's ``albedo_reference`` when it has
one -- for the microfacet families an expectation over the sampler's own visible normals
(:func:`virtual.specimens.physics.vndf_expectation`), which never evaluates the density and
cannot lose a narrow outgoing lobe -- else the same density integrated over the whole hemisphere
on a different partition. A failed check is retried once with four times finer lobe
resolution, a finer grading, a higher order and ten times tighter cell tolerances; if it still fails the result says why (``certified`` False, ``reason``), and the
goniophotometer counts rays instead (``auto``) or refuses (``fast``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.core.errors import InputError, SimulationError
from virtual.collector import Collector
from virtual.cubature import integrate_rectangle, gauss_rule
from virtual.specimens import Specimen

__all__ = ["PatchIntegrals", "integrate_patches",
           "certified_patch_integrals", "reference_albedo", "CERTIFY_TOL", "CERTIFY_ATTEMPTS"]

#: Bound on the patch probabilities' total error (absolute probability) for the fast path to be
#: used: about 1/10 of the binomial standard deviation of a total near 1/2 at 1e9 rays (3.2e-5 relative),
#: so fast and ray counting stay statistically indistinguishable up to 1e9 rays.
CERTIFY_TOL = 3e-6
#: the settings of :func:`certified_patch_integrals`' attempts, in order (the second: finer lobes,
#: finer grading, a higher order, tighter cells); the first alone is what a caller that certifies
#: later (a fit, at its optimum) integrates with
CERTIFY_ATTEMPTS: tuple[dict[str, Any], ...] = (
    {"lobe_factor": 6.0, "lobe_scale": 1.0, "lobe_grade": 0.5, "order": 5, "rtol": 1e-7, "atol": 1e-9},
    {"lobe_factor": 12.0, "lobe_scale": 0.25, "lobe_grade": 0.25, "order": 8, "rtol": 1e-8, "atol": 1e-10},
)


@dataclass(frozen=True)
class PatchIntegrals:
    """Result of :func:`integrate_patches`.

    Attributes
    ----------
    p : (n_bins,) float
        Probability of leaving through each collector bin (bin order of :class:`Collector`).
    albedo : float
        Directional albedo ``p.sum()``; ``1 - albedo`` is the absorbed fraction.
    reflectance, transmittance : float
        Sums over the upper / lower hemisphere bins.
    error : float
        Sum of the accepted cells' error estimates (|coarse - fine|), a pessimistic bound.
    n_evals : int
        Number of BSDF evaluations.
    reference : float or None
        The independent directional albedo it was checked against (certified results only).
    reference_error : float
        That reference's own error estimate.
    certified : bool
        Whether ``max(error, |albedo - reference| + reference_error) <= tol``.
    reason : str
        Why not, when not certified ("" otherwise).
    """

    p: np.ndarray
    albedo: float
    reflectance: float
    transmittance: float
    error: float
    n_evals: int
    reference: float | None = None
    reference_error: float = 0.0
    certified: bool = False
    reason: str = ""

    @property
    def achieved_error(self) -> float:
        """The certified bound on the total probability's error: the larger of the cells' summed
        error estimate and the gap to the independent albedo (plus that one's own error)."""
        if self.reference is None:
            return self.error
        return max(self.error, abs(self.albedo - self.reference) + self.reference_error)


def _cell_integrals(specimen: Specimen, wi: np.ndarray, wl: float, cells: np.ndarray,
                    order: int, chunk: int = 20_000) -> np.ndarray:
    """In chunks of ``chunk`` cells (bounded memory): see :func:`_cell_integrals_once`."""
    if len(cells) <= chunk:
        return _cell_integrals_once(specimen, wi, wl, cells, order)
    return np.concatenate([_cell_integrals_once(specimen, wi, wl, cells[i:i + chunk], order)
                           for i in range(0, len(cells), chunk)])


def _cell_integrals_once(specimen: Specimen, wi: np.ndarray, wl: float, cells: np.ndarray,
                         order: int) -> np.ndarray:
    """Gauss-Legendre estimate of int f |cos| d omega over each cell (t0, t1, p0, p1) (radians,
    theta measured from the pole of the cell's own hemisphere; column 4 is +1 above, -1 below)."""
    u, v, w = gauss_rule(order)
    t0, t1, p0, p1, side = (cells[:, i:i + 1] for i in range(5))
    t = t0 + (t1 - t0) * u
    ph = p0 + (p1 - p0) * v
    st, ct = np.sin(t), np.cos(t)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), side * ct], axis=-1).reshape(-1, 3)
    f = np.asarray(specimen.bsdf(wi, dirs, wl), dtype=np.float64).reshape(t.shape)
    jac = (t1 - t0) * (p1 - p0)
    return np.sum(f * ct * st * w, axis=1) * jac[:, 0]


def _children(cells: np.ndarray) -> np.ndarray:
    """Split every cell in 2 x 2 (rows grouped by parent: 4 consecutive rows per parent)."""
    t0, t1, p0, p1, side = cells.T
    tm, pm = 0.5 * (t0 + t1), 0.5 * (p0 + p1)
    kids = np.stack([
        np.column_stack([t0, tm, p0, pm, side]),
        np.column_stack([t0, tm, pm, p1, side]),
        np.column_stack([tm, t1, p0, pm, side]),
        np.column_stack([tm, t1, pm, p1, side]),
    ], axis=1)
    return kids.reshape(-1, 5)


def _halve(cells: np.ndarray, axis: int) -> np.ndarray:
    """Split every cell in two along theta (axis 0) or phi (axis 1); 2 consecutive rows each."""
    lo, hi = (0, 1) if axis == 0 else (2, 3)
    mid = 0.5 * (cells[:, lo] + cells[:, hi])
    a, b = cells.copy(), cells.copy()
    a[:, hi] = mid
    b[:, lo] = mid
    return np.stack([a, b], axis=1).reshape(-1, 5)


def _near_lobe(cells: np.ndarray, lobes: list[tuple[np.ndarray, float]],
               factor: float, grade: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Masks of cells to split along theta, resp. phi (extent as an arc at the cell's widest).

    A graded mesh around every lobe: a cell within ``factor`` widths of the lobe's centre must
    be no larger than half the width; farther out, no larger than ``grade`` times its distance
    from the centre. The grading resolves heavy tails (a refracted GGX lobe as eta -> 1 has
    mass ~ (w / d)^2 beyond d, reaching far past its width) with O(log(1/w)) cells per lobe."""
    need_t = np.zeros(len(cells), dtype=bool)
    need_p = np.zeros(len(cells), dtype=bool)
    t0, t1, p0, p1, side = cells.T
    dt = t1 - t0
    dp = (p1 - p0) * np.sin(np.minimum(t1, math.pi / 2))
    for d, width in lobes:
        d = np.asarray(d, dtype=float) / np.linalg.norm(d)
        th = math.atan2(math.hypot(d[0], d[1]), abs(d[2]))
        ph = math.atan2(d[1], d[0]) % (2 * math.pi)
        lobe_side = 1.0 if d[2] >= 0.0 else -1.0
        # nearest point of the cell in (theta, phi), phi with wrap-around
        tc = np.clip(th, t0, t1)
        dph = (ph - p0) % (2 * math.pi)
        inside = dph <= (p1 - p0)
        pc = np.where(inside, ph, np.where(dph - (p1 - p0) < 2 * math.pi - dph, p1, p0))
        # great-circle distance by the haversine form (accurate at small angles)
        h = (np.sin(0.5 * (tc - th)) ** 2 + np.sin(tc) * math.sin(th) * np.sin(0.5 * (pc - ph)) ** 2)
        dist = 2.0 * np.arcsin(np.sqrt(np.clip(h, 0.0, 1.0)))
        # lobes reach across the horizon: the other hemisphere is near when the lobe is
        dist = np.where(side == lobe_side, dist, dist + (math.pi / 2 - th) + (math.pi / 2 - tc))
        w = max(float(width), 1e-12)
        limit = np.where(dist < factor * w, 0.5 * w, np.maximum(0.5 * w, grade * dist))
        need_t |= dt > limit
        need_p |= dp > limit
    # theta first: a cell at a pole narrows its phi arc by narrowing in theta
    return need_t, need_p & ~need_t


def integrate_patches(specimen: Specimen, wi: np.ndarray, collector: Collector, wavelength_nm: float,
                      order: int = 5, rtol: float = 1e-7, atol: float = 1e-9,
                      max_level: int = 40, max_cells: int = 2_000_000,
                      lobe_factor: float = 6.0, lobe_scale: float = 1.0, lobe_grade: float = 0.5) -> PatchIntegrals:
    """Per-bin probabilities ``int_P f_s |cos theta_o| d omega`` for one incident direction.

    Parameters
    ----------
    specimen : Specimen
        Must expose a density (``has_density``).
    wi : (3,) array
        Unit vector from the specimen toward the source.
    collector : Collector
        The bins.
    wavelength_nm : float
        Passed to :meth:`Specimen.bsdf`.
    order : int
        Gauss-Legendre nodes per axis and cell.
    rtol, atol : float
        Per-cell acceptance: ``|coarse - fine| <= max(rtol |fine|, atol)`` (atol is an absolute
        probability: kinks such as Oren-Nayar's max(cos theta_i, cos theta_o) converge only
        algebraically, so a relative test alone would refine them without end).
    max_level, max_cells : int
        Refinement limits; exceeding them raises :class:`SimulationError`.
    lobe_factor, lobe_scale : float
        Cells within ``lobe_factor`` widths of a lobe are split to half a width first; the
        specimen's widths are multiplied by ``lobe_scale``; farther out cells are split to at
        most ``lobe_grade`` times their distance from the lobe.

    Returns
    -------
    PatchIntegrals
    """
    if not specimen.has_density:
        raise InputError(f"{type(specimen).__name__} exposes no scattering density to integrate")
    wi = np.asarray(wi, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(wi))
    if not (n > 0 and math.isfinite(n)):
        raise InputError(f"incident direction must be a finite non-zero vector, got {wi}")
    wi = wi / n
    if order < 2:
        raise InputError(f"quadrature order must be >= 2, got {order}")
    wl = float(wavelength_nm)
    b = collector.bin_bounds()
    nb = collector.n_bins
    side = np.where(np.arange(nb) < collector.n_patches, 1.0, -1.0)
    # theta in each hemisphere's own frame (from its pole), so cells never straddle the horizon
    tb = np.where(side > 0, b[:, 0], math.pi - b[:, 0])
    te = np.where(side > 0, b[:, 1], math.pi - b[:, 1])
    cells = np.column_stack([tb, te, b[:, 2], b[:, 3], side])
    owner = np.arange(nb)
    lit_side = 1.0 if wi[2] >= 0.0 else -1.0
    if not specimen.transmits(wl):  # the far hemisphere gets nothing: skip its bins
        keep = side == lit_side
        cells, owner = cells[keep], owner[keep]
    lobes = [(d, w * lobe_scale) for d, w in specimen.lobes(wi, wl)]
    # 1. split the cells near narrow lobes until they resolve them
    for _ in range(3 * max_level):
        if not lobes or len(cells) == 0:
            break
        split_t, split_p = _near_lobe(cells, lobes, factor=lobe_factor, grade=lobe_grade)
        if not (split_t.any() or split_p.any()):
            break
        for axis, split in ((0, split_t), (1, split_p)):
            if axis == 1:  # the theta split doubled those rows
                split = np.concatenate([split[~split_t], np.repeat(split[split_t], 2)])
            cells = np.vstack([cells[~split], _halve(cells[split], axis)])
            owner = np.concatenate([owner[~split], np.repeat(owner[split], 2)])
            if axis == 0:
                split_t = split
        if len(cells) > max_cells:
            raise SimulationError(f"quadrature: more than {max_cells} cells resolving the lobes")
    # 2. adaptive refinement on the error estimate
    p = np.zeros(nb)
    err = 0.0
    n_evals = 0
    coarse = _cell_integrals(specimen, wi, wl, cells, order)
    n_evals += len(cells) * order * order
    for _level in range(max_level):
        if len(cells) == 0:
            break
        kids = _children(cells)
        fine_k = _cell_integrals(specimen, wi, wl, kids, order)
        n_evals += len(kids) * order * order
        fine = fine_k.reshape(-1, 4).sum(axis=1)
        diff = np.abs(fine - coarse)
        ok = diff <= np.maximum(rtol * np.abs(fine), atol)
        np.add.at(p, owner[ok], fine[ok])
        err += float(diff[ok].sum())
        bad = ~ok
        cells = kids.reshape(-1, 4, 5)[bad].reshape(-1, 5)
        coarse = fine_k.reshape(-1, 4)[bad].ravel()
        owner = np.repeat(owner[bad], 4)
        if len(cells) > max_cells:
            raise SimulationError(f"quadrature: more than {max_cells} cells; the density may be singular")
    else:
        if len(cells):
            raise SimulationError(f"quadrature did not converge in {max_level} levels "
                                  f"({len(cells)} cells open)")
    up = p[: collector.n_patches].sum()
    down = p[collector.n_patches:].sum()
    return PatchIntegrals(p=p, albedo=float(up + down), reflectance=float(up if lit_side > 0 else down),
                          transmittance=float(down if lit_side > 0 else up), error=err, n_evals=n_evals)


def _hemisphere_albedo(specimen: Specimen, wi: np.ndarray, wl: float) -> tuple[float, float]:
    """The density integrated over each hemisphere in projected-solid-angle coordinates
    (x = sin^2 theta, phi): a partition unrelated to any collector's."""
    total, err = 0.0, 0.0
    sides = (1.0, -1.0) if specimen.transmits(wl) else ((1.0 if wi[2] >= 0.0 else -1.0),)
    for side in sides:
        def integrand(x: np.ndarray, v: np.ndarray, side: float = side) -> np.ndarray:
            st = np.sqrt(np.clip(x, 0.0, 1.0))
            ct = np.sqrt(np.clip(1.0 - x, 0.0, 1.0))
            ph = 2.0 * math.pi * v
            d = np.stack([st * np.cos(ph), st * np.sin(ph), side * ct], axis=-1)
            return math.pi * np.asarray(specimen.bsdf(wi, d, wl), dtype=float)  # cos dw = pi dx dv
        v, e, _ = integrate_rectangle(integrand, start=(8, 16), order=6, rtol=1e-10, atol=1e-12)
        total, err = total + v, err + e
    return total, err


def reference_albedo(specimen: Specimen, wi: np.ndarray, wavelength_nm: float) -> tuple[float, float]:
    """An independent directional albedo ``(value, error estimate)``: the specimen's
    ``albedo_reference`` (computed in its sampler's space) when it has one, else the density
    over the whole hemisphere in projected-solid-angle coordinates."""
    w = np.asarray(wi, dtype=np.float64).reshape(3)
    w = w / np.linalg.norm(w)
    ref = getattr(specimen, "albedo_reference", None)
    if ref is not None:
        v, e = ref(w, float(wavelength_nm))
        return float(v), float(e)
    return _hemisphere_albedo(specimen, w, float(wavelength_nm))


def certified_patch_integrals(specimen: Specimen, wi: np.ndarray, collector: Collector, wavelength_nm: float,
                              tol: float = CERTIFY_TOL, max_cells: int = 300_000) -> PatchIntegrals:
    """:func:`integrate_patches` with its bound checked (see the module docstring).

    Returns the result with ``reference``, ``certified`` and ``reason`` set; never raises for
    a failed check (the caller decides), only for input errors.
    """
    try:
        ref, ref_err = reference_albedo(specimen, wi, wavelength_nm)
    except SimulationError as e:
        ref, ref_err = None, 0.0
        ref_reason = f"the independent albedo did not converge ({e})"
    # the retry changes the rule's order too: a bias common to a cell and its children (seen
    # at eta = 1 + 1e-6, 60 deg, with order 5: +1.2e-5, invisible to the cells' own estimate,
    # caught by the independent albedo) does not survive a different order
    res: PatchIntegrals | None = None
    reason = ""
    for attempt in CERTIFY_ATTEMPTS:
        try:
            res = integrate_patches(specimen, wi, collector, wavelength_nm, **attempt, max_cells=max_cells)
        except SimulationError as e:
            reason = f"patch quadrature did not converge ({e})"
            continue
        if ref is None:
            reason = ref_reason
            break
        gap = abs(res.albedo - ref) + ref_err
        if res.error <= tol and gap <= tol:
            return PatchIntegrals(res.p, res.albedo, res.reflectance, res.transmittance, res.error, res.n_evals,
                                  ref, ref_err, True, "")
        reason = (f"patch total {res.albedo:.8g} vs independent albedo {ref:.8g} (gap {gap:.2g}), "
                  f"cell error estimate {res.error:.2g}; bound {tol:.2g} not met")
    if res is None:
        nb = collector.n_bins
        return PatchIntegrals(np.zeros(nb), 0.0, 0.0, 0.0, math.inf, 0, ref, ref_err, False, reason)
    return PatchIntegrals(res.p, res.albedo, res.reflectance, res.transmittance, res.error, res.n_evals,
                          ref, ref_err, False, reason)
