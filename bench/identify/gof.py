"""Goodness of fit of calibrated readings whose Type A variances are estimated, not known.

A scan's counting noise is the standard deviation of its ``averages`` scans, pooled over the
pixels of a band (:mod:`bench.bands`): an estimate with ``(averages - 1) x pixels`` degrees of
freedom (Welch-Satterthwaite for pixels of equal variance; an upper bound otherwise). Used as if
known, it inflates chi-square by about ``nu / (nu - 2)`` (8 % at nu = 27, the shipped emulated
bench): p < 0.05 in 17 % of correct records instead of 5 %.

:func:`calibrated_p_value` calibrates the p-value by a parametric bootstrap of the linearised fit
with a fixed seed (:data:`DRAWS`, :data:`SEED`): each draw takes readings from the record's own
covariance -- its independent variances, the additive shared terms (darks), the shared scales
(:mod:`bench.identify.scales`) -- redraws the independent Type A variances as
``s^2 chi2_nu / nu`` (:func:`type_a_dof`), refits the parameters (the Jacobian at the optimum),
the scales and the shared terms by the same weighted least squares as the fit, and the p-value is
the fraction of draws whose statistic reaches the record's (plus one over draws plus one). With
every dof infinite (a virtual body's binomial noise, readings without budgets) it is the
chi-square law's, which the fit reports as before. Only the independent Type A terms are redrawn:
a shared estimate (a dark, the white reading) is one draw for many readings, worth about one
degree of freedom of the statistic.

The same estimated variances make the parameters' standard errors too small: weights ``1 / s^2``
are noisy (the estimate scatters more than with the true weights, by ``(nu - 2) / (nu - 4)`` in
variance) and on average too large (``E[1 / s^2] = nu / (nu - 2) / sigma^2``, so the Fisher
information they give is too large): with Type A noise alone the estimate's spread is
``sqrt(nu / (nu - 4))`` of its reported standard error, 1.08 at nu = 27 (a 95 % interval then covers
93 %). :func:`interval_inflation` measures that ratio per parameter by the same bootstrap (the
weighted least-squares estimate of each draw, its spread over the draws against the mean of the
covariance its weights report); the fit widens its intervals by it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from bench.identify.scales import SCALE_INPUTS

__all__ = ["DRAWS", "SEED", "ReadingNoise", "reading_noise", "type_a_dof", "calibrated_p_value",
           "interval_inflation"]

#: parametric bootstrap draws of the p-value (its resolution 1 / (DRAWS + 1))
DRAWS = 2000
#: the bootstrap's fixed seed (the p-value of a record is reproducible)
SEED = 20261206


def _mapping(v: Any) -> Mapping[str, Any]:
    return v if isinstance(v, Mapping) else {}


def type_a_dof(meta: Mapping[str, Any], wavelengths: Sequence[float]) -> np.ndarray:
    """Degrees of freedom of each reading's Type A (counting-noise) standard uncertainty:
    ``(averages - 1) x pixels of its band`` for a spectrometer that reports the scans' spread
    (``averages`` from the run's plan, the band's pixels from the bench description's
    ``pixels_per_band``, 1 without bands); infinite for a virtual body (binomial noise of its
    counted rays) or a single scan (the shot-noise estimate from the signal)."""
    desc = _mapping(meta.get("bench_description"))
    n = len(wavelengths)
    if meta.get("bench_kind", desc.get("kind")) == "virtual":
        return np.full(n, math.inf)
    averages = int(_mapping(meta.get("plan")).get("averages", 1) or 1)
    if averages <= 1:
        return np.full(n, math.inf)
    extra = _mapping(_mapping(desc.get("spectrometer")).get("extra"))
    bands, pixels = extra.get("bands_nm"), extra.get("pixels_per_band")
    out = np.full(n, float(averages - 1))
    if isinstance(bands, Sequence) and isinstance(pixels, Sequence) and len(bands) == len(pixels) and bands:
        centres = np.asarray(bands, float)
        for i, w in enumerate(wavelengths):
            out[i] *= float(pixels[int(np.argmin(np.abs(centres - float(w))))])
    return out


@dataclass(frozen=True)
class ReadingNoise:
    """A record's covariance less its shared scales, as ``diag(own2) + shared shared^T``;
    ``type_a2`` the part of ``own2`` estimated from the scans, with ``dof`` degrees of freedom."""

    own2: np.ndarray
    type_a2: np.ndarray
    shared: np.ndarray
    dof: np.ndarray


def reading_noise(budgets: Sequence[Any], std: np.ndarray, dof: np.ndarray) -> ReadingNoise:
    """:class:`ReadingNoise` of readings with GUM budgets (``std`` for those without one, known)."""
    parsed = [json.loads(b) if isinstance(b, str) else b for b in budgets]
    own2 = np.array(std, dtype=float) ** 2
    type_a2 = np.zeros(len(parsed))
    columns: dict[tuple[str, str], dict[int, float]] = {}
    for i, b in enumerate(parsed):
        if not isinstance(b, Mapping) or not b.get("components"):
            continue
        value = float(b.get("value", 0.0))
        shared2 = 0.0
        for c in b["components"]:
            shared, contribution = c.get("shared"), float(c["contribution"])
            if shared is None:
                type_a2[i] += contribution**2 if c["type"] == "A" else 0.0
                continue
            shared2 += contribution**2
            if not (c["name"] in SCALE_INPUTS and value != 0.0):
                columns.setdefault((str(c["name"]), str(shared)), {})[i] = (float(c["sensitivity"])
                                                                            * float(c["standard_uncertainty"]))
        own2[i] = max(float(b["combined"]) ** 2 - shared2, 0.0)
    u = np.zeros((len(parsed), len(columns)))
    for k, rows in enumerate(columns.values()):
        for i, v in rows.items():
            u[i, k] = v
    return ReadingNoise(own2, np.minimum(type_a2, own2), u, np.asarray(dof, float))


def _solve(e: np.ndarray, x: np.ndarray, w: np.ndarray, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``e`` and ``w`` (draws x readings): (``c`` minimising
    ``sum w (e - x c)^2 + sum prior c^2``, the normal matrix ``x^T diag(w) x + diag(prior)``)."""
    q = x.shape[1]
    normal = (w @ (x[:, :, None] * x[:, None, :]).reshape(len(x), q * q)).reshape(-1, q, q) + np.diag(prior)
    return np.linalg.solve(normal, ((w * e) @ x)[..., None])[..., 0], normal


def _statistics(e: np.ndarray, x: np.ndarray, w: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Per row of ``e`` and ``w``: ``min_c sum w (e - x c)^2 + sum prior c^2`` (the fit's deviance,
    linearised)."""
    c, _normal = _solve(e, x, w, prior)
    r = e - c @ x.T
    return np.sum(w * r * r, axis=1) + np.sum(prior * c * c, axis=1)


def _draws(noise: ReadingNoise, loadings: np.ndarray, draws: int, seed: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Chunks of (readings' errors, their estimated independent variances): errors from the
    record's covariance (independent, additive shared terms and scales by ``loadings``), the
    independent Type A variances redrawn as ``s^2 chi2_nu / nu``."""
    rng = np.random.default_rng(seed)
    n = len(noise.own2)
    estimated = np.isfinite(noise.dof) & (noise.type_a2 > 0)
    nu = np.where(estimated, noise.dof, 1.0)
    known2 = noise.own2 - np.where(estimated, noise.type_a2, 0.0)
    for start in range(0, draws, CHUNK):
        m = min(CHUNK, draws - start)
        e = (np.sqrt(noise.own2) * rng.standard_normal((m, n))
             + rng.standard_normal((m, loadings.shape[1])) @ loadings.T)
        yield e, known2 + np.where(estimated, noise.type_a2 * rng.chisquare(nu, size=(m, n)) / nu, 0.0)


#: draws evaluated at once (memory: CHUNK x readings x parameters)
CHUNK = 250


def calibrated_p_value(chi2: float, jac: np.ndarray, scales: np.ndarray, noise: ReadingNoise,
                       draws: int = DRAWS, seed: int = SEED) -> float | None:
    """The p-value of ``chi2`` by the parametric bootstrap of the module docstring; ``jac`` the
    model's derivative (readings x free parameters) at the optimum, ``scales`` the shared
    scales' absolute loadings (``mu a``). None when every dof is infinite (chi-square holds)."""
    dof = noise.dof
    estimated = np.isfinite(dof) & (noise.type_a2 > 0)
    if not estimated.any():
        return None
    n = len(noise.own2)
    free = np.asarray(jac, float).reshape(n, -1)
    if free.size:  # the fit's span only: a parameter no reading depends on adds no column
        u, sv, _ = np.linalg.svd(free, full_matrices=False)
        free = u[:, sv > 1e-10 * sv.max()] if sv.max() > 0 else free[:, :0]
    x = np.hstack([free, noise.shared, scales])
    prior = np.concatenate([np.zeros(free.shape[1]), np.ones(noise.shared.shape[1] + scales.shape[1])])
    loadings = np.hstack([noise.shared, scales])
    stats = np.concatenate([_statistics(e, x, 1.0 / own_hat, prior)
                            for e, own_hat in _draws(noise, loadings, draws, seed)])
    return float((1 + np.count_nonzero(stats >= chi2)) / (draws + 1))


def interval_inflation(jac: np.ndarray, scales: np.ndarray, noise: ReadingNoise, draws: int = DRAWS,
                       seed: int = SEED) -> np.ndarray | None:
    """Per free parameter (a column of ``jac``): the spread of its weighted least-squares estimate
    over the bootstrap's draws (:func:`calibrated_p_value`'s, weights the redrawn variances) over
    the standard error those weights report (the root mean of the covariance's diagonal), at
    least 1 (the bootstrap's own scatter, about ``1 / sqrt(2 draws)``, never narrows an interval).
    None when every dof is infinite (the reported errors hold) or when the parameters are not
    all identified (a singular ``jac``: no spread to measure)."""
    estimated = np.isfinite(noise.dof) & (noise.type_a2 > 0)
    n = len(noise.own2)
    free = np.asarray(jac, float).reshape(n, -1)
    if not estimated.any() or not free.size or np.linalg.matrix_rank(free) < free.shape[1]:
        return None
    scale = np.sqrt(np.sum(free * free, axis=0))  # columns of unit norm: a well-conditioned normal matrix
    x = np.hstack([free / scale, noise.shared, scales])
    k = free.shape[1]
    prior = np.concatenate([np.zeros(k), np.ones(x.shape[1] - k)])
    loadings = np.hstack([noise.shared, scales])
    estimates, reported = [], []
    for e, own_hat in _draws(noise, loadings, draws, seed):
        c, normal = _solve(e, x, 1.0 / own_hat, prior)
        estimates.append(c[:, :k])
        reported.append(np.linalg.inv(normal)[:, np.arange(k), np.arange(k)])
    spread = np.concatenate(estimates).var(axis=0, ddof=1)
    return np.maximum(np.sqrt(spread / np.concatenate(reported).mean(axis=0)), 1.0)
