"""The Fisher information of designed points under the record's covariance, in pieces per point.

A calibrated record's readings share errors (:func:`bench.identify.likelihood.record_covariance`,
the budgets' full covariance): each dark's error is an offset common to the readings it corrects,
per wavelength (``dark = "per-incidence"``: every reading of an incidence), the white reading a
relative scale common to the record's readings of a wavelength, the white's certificate one common
to all. Each is a rank-one term of the covariance, so its inverse follows from the Sherman-Morrison
formula level by level -- darks, then the white reading per wavelength, then the certificate -- and
the information of any set of points is a few sums over them, cheap enough for a greedy design to
evaluate every candidate at every step (:mod:`bench.identify.design`). A candidate whose dark no
chosen point uses (a new incidence) brings that dark's error with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from bench.core.geometry import Geometry

__all__ = ["Information", "dark_groups"]


def _dark_level(jj: np.ndarray, jf: np.ndarray, ff: np.ndarray, jg: np.ndarray, fg: np.ndarray,
                gg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sherman-Morrison over one dark's shared offset: from the sums over the readings it corrects
    (one wavelength; any leading axes) of ``j j^T / s^2``, ``j f / s^2``, ``f^2 / s^2`` and the
    same with the dark's loading ``g``, the pieces ``J^T S^-1 J``, ``J^T S^-1 f`` and
    ``f^T S^-1 f`` with ``S`` the own variances plus the dark's rank-one term."""
    k = 1.0 / (1.0 + gg)
    return (jj - k[..., None, None] * jg[..., :, None] * jg[..., None, :], jf - (k * fg)[..., None] * jg,
            ff - k * fg * fg)


@dataclass
class Information:
    """Per-candidate pieces of the Fisher information, per wavelength ``w`` of each candidate ``n``
    (``s`` the reading's own standard deviation, ``f`` its predicted value, ``j`` its derivatives,
    ``g`` its dark's loading): ``jj[n, w]`` = j j^T / s^2, ``jf`` = j f / s^2, ``ff`` = f^2 / s^2,
    ``jg`` = j g / s^2, ``fg`` = f g / s^2, ``gg`` = g^2 / s^2; ``group[n]`` which dark the candidate
    is read with (candidates of one group share it), ``white2[w]`` and ``certificate2[w]`` the
    shared relative variances of the white reading (per wavelength) and of its certificate.

    The covariance of a set of readings is the own variances plus one rank-one term per dark and
    wavelength, per white reading (wavelength) and for the certificate, the record's budgets'
    structure (:func:`bench.identify.likelihood.record_covariance`); its inverse follows level by
    level from the Sherman-Morrison formula (:func:`_dark_level`, then the white's, then the
    certificate's), so the information of any set is a few sums over its points."""

    jj: np.ndarray  # (n, w, p, p)
    jf: np.ndarray  # (n, w, p)
    ff: np.ndarray  # (n, w)
    jg: np.ndarray  # (n, w, p)
    fg: np.ndarray  # (n, w)
    gg: np.ndarray  # (n, w)
    group: np.ndarray  # (n,) int
    white2: np.ndarray  # (w,)
    certificate2: np.ndarray  # (w,)
    brdf: np.ndarray  # (n, wavelengths) predicted
    sigma: np.ndarray  # (n, wavelengths) own noise

    @property
    def _pieces(self) -> tuple[np.ndarray, ...]:
        """The per-reading pieces in :func:`_dark_level`'s order."""
        return self.jj, self.jf, self.ff, self.jg, self.fg, self.gg

    @property
    def own(self) -> np.ndarray:
        """Each candidate's information with nothing shared: ``(n, p, p)``."""
        return self.jj.sum(axis=1)

    def _per_band(self, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
        """The pieces per wavelength of the points ``at`` after their darks, and the raw sums of
        every dark group over the points of ``at`` (zero for a group none of them uses)."""
        groups = int(self.group.max()) + 1 if self.group.size else 0
        sums = []
        for x in self._pieces:
            out = np.zeros((groups, *x.shape[1:]))
            np.add.at(out, self.group[at], x[at])
            sums.append(out)
        used = np.unique(self.group[at])
        a, b, c = _dark_level(*(x[used] for x in sums))
        return a.sum(axis=0), b.sum(axis=0), c.sum(axis=0), sums

    def _shared(self, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The Fisher matrix from the pieces per wavelength (``(..., w, p, p)``, ``(..., w, p)``,
        ``(..., w)``): each wavelength's white reading, then the certificate, counted once."""
        k = self.white2 / (1.0 + self.white2 * c)
        a = a - k[..., None, None] * b[..., :, None] * b[..., None, :]
        b, c = b / (1.0 + self.white2 * c)[..., None], c / (1.0 + self.white2 * c)
        r = np.sqrt(self.certificate2)
        big_b = (r[..., None] * b).sum(axis=-2)
        big_c = (self.certificate2 * c).sum(axis=-1)
        return a.sum(axis=-3) - (1.0 / (1.0 + big_c))[..., None, None] * big_b[..., :, None] * big_b[..., None, :]

    def total(self, idx: Sequence[int] | np.ndarray) -> np.ndarray:
        """Fisher information of the points ``idx`` (each measured once)."""
        a, b, c, _ = self._per_band(np.asarray(idx, dtype=int))
        return self._shared(a, b, c)

    def with_each(self, idx: Sequence[int], cand: np.ndarray) -> np.ndarray:
        """Fisher information of ``idx`` plus each one of ``cand``: ``(len(cand), p, p)``. A
        candidate read with a dark no point of ``idx`` uses (a new incidence) brings that dark."""
        cand = np.asarray(cand, dtype=int)
        a, b, c, sums = self._per_band(np.asarray(idx, dtype=int))
        before = [x[self.group[cand]] for x in sums]
        after = [s + x[cand] for s, x in zip(before, self._pieces)]
        na, nb, nc = _dark_level(*after)
        oa, ob, oc = _dark_level(*before)
        return self._shared(a[None] + na - oa, b[None] + nb - ob, c[None] + nc - oc)

    def scaled(self, s: float) -> "Information":
        """The information divided by ``s`` (every Fisher matrix it gives is F / s)."""
        r = math.sqrt(s)
        return replace(self, jj=self.jj / s, jf=self.jf / r, jg=self.jg / r)


def dark_groups(points: Sequence[Geometry], dark: str, measured: int = 0) -> np.ndarray:
    """Which dark each of ``points`` is corrected with, as ``bench scan`` takes them (ids from 0):
    one per incidence (``per-incidence``), one for the run (``once``), one per point (``per-point``,
    or ``none``: no dark). The last ``measured`` points were read in earlier runs (a sequential
    design's steps), with darks of their own: per incidence, apart from the new points'."""
    n = len(points)
    if dark == "once":
        keys: list[Any] = [("new",) if k < n - measured else ("measured",) for k in range(n)]
    elif dark == "per-incidence":
        keys = [(k < n - measured, g.theta_i, g.phi_i) for k, g in enumerate(points)]
    else:
        keys = list(range(n))
    ids: dict[Any, int] = {}
    return np.array([ids.setdefault(key, len(ids)) for key in keys], dtype=int)
