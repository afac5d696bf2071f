"""Maximum-likelihood identification of a model from a record: :func:`fit_record`.

The likelihood is the record's own (:mod:`bench.identify.likelihood`): residuals whose sum of
squares is the deviance ``-2 log L + const``. The fit:

1. a bounded global step: the deviance at the declared defaults and at a scrambled Sobol set
   of ``starts`` points inside the bounds (:mod:`scipy.stats.qmc`), ranked;
2. bounded local fits (:func:`scipy.optimize.least_squares`, trust-region reflective,
   finite-difference Jacobian) from the defaults and the best-ranked starts
   (:data:`LOCAL_STARTS` in all); the lowest deviance is the optimum;
3. intervals at ``confidence``: ``"profile"`` -- where the profile deviance (the others
   re-optimized) exceeds its minimum by the chi-square quantile with one degree of freedom
   (roots by :func:`scipy.optimize.brentq`); ``"hessian"`` -- ``value -/+ sqrt(q) se`` with the
   covariance the inverse of the Fisher information ``J^T J`` at the optimum (fast; exact for a
   model linear in its parameters). An interval that reaches a bound stops there;
4. goodness of fit: the deviance at the optimum as chi2 (for counts the G statistic; its chi-square
   law needs most expected counts above a few), ``dof`` = independent data less free parameters,
   the p-value; the parameters' correlation from the covariance.

``converged`` is the local fit's own verdict (a tolerance met, not the evaluation limit).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable

import numpy as np

from bench.core.errors import InputError, SpecimenError
from bench.core.records import BSDFRecord
from bench.identify.gof import DRAWS, calibrated_p_value, interval_inflation
from bench.identify.identifiability import Identifiability, flat_profiles, identifiability
from bench.identify.likelihood import FitInput, GaussianReadings, Group, Likelihood, likelihood_for
from bench.identify.model_spec import ModelSpec, parse_model_spec

__all__ = ["ParameterEstimate", "FitResult", "fit_record", "INTERVALS"]

INTERVALS = ("profile", "hessian")
#: relative finite-difference step of the Jacobian: well above the quadrature's ~1e-7 relative noise
DIFF_STEP = 1e-5
#: the same where rays are counted (common random numbers: the counts change in steps of single
#: rays, so the step must span many of them)
RAYS_DIFF_STEP = 1e-2
#: tolerance of a profile's inner fits: the profile deviance to ~1e-6 of its threshold (chi2 quantile)
PROFILE_TOL = 1e-8
#: evaluations a local fit may take, per free parameter plus one (beyond: not converged)
MAX_EVALUATIONS = 100

#: each residual at a point the model family refuses (outside its joint constraints)
REFUSED = 1e6
#: a calibrated reading this many of its own standard uncertainties from the fitted model is named
#: an outlier (a correct model puts |z| > 5 on one reading of 1.7 million)
OUTLIER_Z = 5.0

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ParameterEstimate:
    """One fitted parameter: value, interval at the fit's confidence, unit, standard error."""

    name: str
    value: float
    ci: tuple[float, float]
    unit: str
    stderr: float


@dataclass(frozen=True)
class FitResult:
    """What :func:`fit_record` found. ``parameters`` in the model string's order; ``covariance``
    and ``fisher`` (``J^T J`` of the residuals, the Fisher information) in the same order."""

    model: str
    family: str
    specimen: str
    parameters: dict[str, ParameterEstimate]
    fixed: dict[str, float]
    covariance: np.ndarray
    fisher: np.ndarray
    correlation: np.ndarray
    chi2: float
    dof: int
    p_value: float
    converged: bool
    message: str
    likelihood: str
    interval: str
    confidence: float
    n_evaluations: int
    residuals: np.ndarray = field(repr=False)
    groups: tuple[Group, ...] = field(repr=False, default=())
    xlabel: str = ""
    #: how ``p_value`` was found: the chi-square law, or the bootstrap of estimated Type A variances
    p_value_method: str = "chi-square"
    #: which parameters the record does not identify, and why (None: not assessed, a stopped fit)
    identifiability: Identifiability | None = None
    #: declared name -> the name as the model string wrote it (the JSON and the printout use it)
    labels: dict[str, str] = field(default_factory=dict)
    #: readings more than :data:`OUTLIER_Z` standard uncertainties from the fitted model (calibrated readings)
    outliers: tuple[dict[str, Any], ...] = ()

    def label(self, name: str) -> str:
        return self.labels.get(name, name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.parameters)

    @property
    def values(self) -> np.ndarray:
        return np.array([p.value for p in self.parameters.values()])

    @property
    def method(self) -> str:
        return f"{self.likelihood} likelihood, {self.interval} intervals"

    def to_json(self) -> dict[str, Any]:
        """The stable JSON of ``bench fit --json``."""
        names = self.names
        return {
            "model": self.model,
            "parameters": {self.label(n): {"value": p.value, "ci": [p.ci[0], p.ci[1]], "unit": p.unit}
                           for n, p in self.parameters.items()},
            "correlation": {self.label(a): {self.label(b): _finite(self.correlation[i, j]) for j, b in enumerate(names)}
                            for i, a in enumerate(names)},
            "chi2": self.chi2, "dof": self.dof, "p_value": _finite(self.p_value), "p_value_method": self.p_value_method,
            "converged": self.converged, "method": self.method,
            "identifiability": None if self.identifiability is None else self.identifiability.as_dict(),
            "outliers": [dict(o) for o in self.outliers],
        }


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


class _OutOfTime(Exception):
    """The fit's time limit passed; carries the objective (its best point so far)."""

    def __init__(self, objective: "_Objective") -> None:
        super().__init__("time limit")
        self.objective = objective


class _Objective:
    """Residuals of the model at free-parameter values, cached (profiles revisit points)."""

    def __init__(self, spec: ModelSpec, lik: Likelihood, deadline: float | None = None) -> None:
        self.spec, self.lik = spec, lik
        self.cache: dict[tuple[float, ...], np.ndarray] = {}
        self.deadline = deadline  # time.monotonic() past which no new point is evaluated
        self.best: tuple[float, tuple[float, ...]] | None = None  # (deviance, x) lowest so far
        self.size: int | None = None  # residuals per evaluation, once one succeeded

    def __call__(self, x: np.ndarray) -> np.ndarray:
        key = tuple(float(v) for v in x)
        if key not in self.cache:
            if self.deadline is not None and self.best is not None and time.monotonic() > self.deadline:
                raise _OutOfTime(self)
            try:
                specimen = self.spec.specimen(key)
            except SpecimenError:
                if self.size is None:
                    raise
                # a point the family refuses (e.g. reflectance + transmittance > 1): a wall the search backs off from
                self.cache[key] = np.full(self.size, REFUSED)
                return self.cache[key]
            r = self.cache[key] = np.asarray(self.lik.residuals(specimen), float)
            self.size = len(r)
            dev = float(r @ r)
            if math.isfinite(dev) and (self.best is None or dev < self.best[0]):
                self.best = (dev, key)
        return self.cache[key]

    def deviance(self, x: np.ndarray) -> float:
        r = self(x)
        return float(r @ r)


def _inside(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``x`` clipped a hair inside ``[lo, hi]`` (the trust-region method starts strictly inside)."""
    pad = 1e-9 * (hi - lo)
    return np.clip(x, lo + pad, hi - pad)


def _starts(spec: ModelSpec, starts: int, seed: int) -> list[np.ndarray]:
    """The declared defaults, then ``starts`` scrambled Sobol points in the bounds."""
    out = [spec.start()]
    if starts > 0:
        from scipy.stats import qmc

        m = max(0, math.ceil(math.log2(starts)))
        pts = qmc.Sobol(d=len(spec.free), scramble=True, seed=seed).random_base2(m)[:starts]
        out.extend(qmc.scale(pts, spec.lower, spec.upper))
    return out


#: local fits of the multi-start: from the declared defaults and the best screened starts
LOCAL_STARTS = 3


def _local(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           tol: float = 1e-10, rough: bool = False) -> Any:
    from scipy.optimize import least_squares

    return least_squares(fun, _inside(x0, lo, hi), bounds=(lo, hi), method="trf", x_scale="jac",
                         diff_step=RAYS_DIFF_STEP if rough else DIFF_STEP, max_nfev=MAX_EVALUATIONS * (len(x0) + 1),
                         xtol=tol, ftol=tol, gtol=tol)


def _profile_limit(obj: _Objective, xhat: np.ndarray, dev_min: float, cov: np.ndarray, i: int, side: int,
                   q: float) -> float:
    """Where the profile deviance of parameter ``i`` reaches ``dev_min + q`` on ``side`` (-1/+1),
    or the bound when it does not."""
    from scipy.optimize import brentq

    spec = obj.spec
    lo, hi = spec.lower, spec.upper
    bound = lo[i] if side < 0 else hi[i]
    if xhat[i] == bound:
        return float(bound)
    others = [j for j in range(len(xhat)) if j != i]
    warm = {"x": xhat[others]}

    def excess(v: float) -> float:
        if not others:
            return obj.deviance(np.array([v])) - dev_min - q
        slope = cov[others, i] / cov[i, i] if cov[i, i] > 0 and np.all(np.isfinite(cov[others, i])) else 0.0
        guess = xhat[others] + slope * (v - xhat[i]) if np.all(np.isfinite(slope)) else warm["x"]

        def sub(xo: np.ndarray) -> np.ndarray:
            return obj(np.insert(xo, i, v))

        res = _local(sub, guess, lo[others], hi[others], tol=PROFILE_TOL, rough=obj.lik.counted_rays)
        warm["x"] = res.x
        return 2.0 * float(res.cost) - dev_min - q

    se = math.sqrt(cov[i, i]) if math.isfinite(cov[i, i]) and cov[i, i] > 0 else abs(bound - xhat[i]) / 4.0
    step = max(math.sqrt(q) * se, 1e-12 * (hi[i] - lo[i]))
    near = float(xhat[i])
    for _ in range(60):
        v = float(np.clip(xhat[i] + side * step, lo[i], hi[i]))
        if excess(v) > 0.0:
            return float(brentq(excess, near, v, xtol=1e-3 * se + 1e-14, rtol=1e-10))
        if v == bound:
            return float(bound)
        near, step = v, 2.0 * step
    return float(bound)  # pragma: no cover - the doubling reaches the bound first


def fit_record(record: FitInput, spec: str | ModelSpec, *, confidence: float = 0.95, interval: str = "profile",
               starts: int | None = None, seed: int = 0, likelihood: Likelihood | None = None,
               max_seconds: float | None = None) -> FitResult:
    """Fit the free parameters of ``spec`` to ``record`` by maximum likelihood.

    Parameters
    ----------
    record : BSDFRecord, Spectrum or sequence of Spectrum
        Virtual counts (multinomial) or calibrated readings (Gaussian): see
        :func:`bench.identify.likelihood.likelihood_for`.
    spec : str or ModelSpec
        ``FAMILY:p=?,q=VALUE,r=?lo:hi`` (:func:`bench.identify.model_spec.parse_model_spec`).
    confidence : float
        Confidence of the intervals, in (0, 1).
    interval : ``"profile"`` or ``"hessian"``
    starts : int, optional
        Sobol points of the global step (default ``4 x`` the free parameters; 0: the declared
        defaults only).
    seed : int
        Scrambling seed of the Sobol set (the fit is deterministic given it).
    likelihood : Likelihood, optional
        Use this instead of the record's own (e.g. a caller's covariance).
    max_seconds : float, optional
        Wall-clock limit of the search and the intervals: past it no new point is evaluated and
        the result is the best point so far, ``converged`` False, no intervals (NaN), and
        ``message`` saying so (default: none).

    Returns
    -------
    FitResult

    Notes
    -----
    The search evaluates the fast path's quadrature without its certificate (an independent
    albedo that costs nine tenths of an evaluation) and certifies at the optimum; where that
    fails, the whole fit runs again with every evaluation certified (rays where it cannot be).
    """
    if not (isinstance(confidence, (int, float)) and 0.0 < float(confidence) < 1.0):
        raise InputError(f"confidence must lie in (0, 1), got {confidence!r}")
    if interval not in INTERVALS:
        raise InputError(f"interval must be one of {', '.join(INTERVALS)}, got {interval!r}")
    spec = parse_model_spec(spec) if isinstance(spec, str) else spec
    n = len(spec.free)
    starts = 4 * n if starts is None else int(starts)
    if starts < 0:
        raise InputError(f"starts must be >= 0, got {starts}")
    if max_seconds is not None and not (isinstance(max_seconds, (int, float)) and max_seconds > 0):
        raise InputError(f"max_seconds must be > 0, got {max_seconds!r}")
    lik = likelihood if likelihood is not None else likelihood_for(record)
    lik.defer_certification = True
    deadline = None if max_seconds is None else time.monotonic() + float(max_seconds)
    try:
        result = _fit(spec, lik, confidence, interval, starts, seed, deadline)
        if not lik.certify(spec.specimen(result.values)):
            log.info("fit: the fast path does not certify at the optimum; fitting again certifying every evaluation")
            lik.defer_certification = False
            result = _fit(spec, lik, confidence, interval, starts, seed, deadline)
    except _OutOfTime as out:
        return _stopped(out.objective, float(max_seconds or 0.0), confidence, interval)
    return _identified(record, _calibrated(result, spec, lik), spec, lik)


def _identified(record: FitInput, result: FitResult, spec: ModelSpec, lik: Likelihood) -> FitResult:
    """``result`` with what its Fisher information and intervals say it does not identify."""
    ranges = spec.upper - spec.lower
    ident = identifiability(result.fisher, spec.names, ranges)
    ident = flat_profiles(ident, {k: p.ci for k, p in result.parameters.items()},
                          {p.name: (p.lo, p.hi) for p in spec.free})
    if ident.unidentified:
        log.warning("fit: not identified by the record: %s", ident.text())
    ident = Identifiability(ident.rank, ident.condition,
                            {spec.labels.get(k, k): why for k, why in ident.unidentified.items()})
    return replace(result, identifiability=ident, labels=spec.labels, outliers=_outliers(record, result, spec, lik))


def _zscores(spec: ModelSpec, lik: GaussianReadings, x: np.ndarray,
             scales_from: GaussianReadings | None = None) -> np.ndarray:
    """Each calibrated reading's residual from the model at ``x`` (its shared scales profiled on
    the readings of ``scales_from``, default ``lik``, and applied) over its own standard
    uncertainty (the covariance's diagonal less the shared scales)."""
    specimen = spec.specimen(x)
    mu = lik.predictions(specimen)
    src = lik if scales_from is None else scales_from
    _r, z = src.scales.profile(src.chol, src.values, src.predictions(specimen))
    by_name = dict(zip(src.scales.names, z))
    z = np.array([by_name.get(n, 0.0) for n in lik.scales.names])
    fitted = mu * (1.0 + lik.scales.loadings @ z) if lik.scales.count else mu
    return (lik.values - fitted) / np.sqrt(np.einsum("ij,ij->i", lik.chol, lik.chol))


def _outliers(record: FitInput, result: FitResult, spec: ModelSpec, lik: Likelihood) -> tuple[dict[str, Any], ...]:
    """Calibrated readings more than :data:`OUTLIER_Z` of their own standard uncertainties from
    every model tried: the optimum and, when some are, the refit without them (a gross reading
    drags the optimum -- and a wavelength's shared scale -- so that its neighbours look far too):
    each with its index, geometry, wavelength, value and z (at the refit), largest |z| first."""
    if not isinstance(lik, GaussianReadings):  # only calibrated readings have a residual per reading
        return ()
    rows = lik.rows
    zs = _zscores(spec, lik, result.values)
    far = np.abs(zs) > OUTLIER_Z
    if far.any() and isinstance(record, BSDFRecord) and np.count_nonzero(~far) > len(spec.free):
        t = record.table.copy()
        measured = np.flatnonzero(np.isfinite(t["value"].to_numpy(float)))
        t.loc[t.index[measured[far]], "value"] = np.nan
        try:
            kept = GaussianReadings(BSDFRecord(t, dict(record.meta)))  # the same readings, the far ones out
            refit = _fit(spec, kept, result.confidence, "hessian", 0, 0)
            zs = _zscores(spec, lik, refit.values, scales_from=kept)
            far &= np.abs(zs) > OUTLIER_Z
        except (InputError, np.linalg.LinAlgError, ValueError):
            pass  # the optimum's verdict stands
    keys = ("quantity", "geometry", "theta_i", "phi_i", "theta_r", "phi_r", "wavelength_nm", "value")
    out = [{"reading": int(i), **{k: rows[i][k] for k in keys if k in rows[i]}, "z": float(zs[i])}
           for i in np.flatnonzero(far)]
    return tuple(sorted(out, key=lambda o: -abs(o["z"])))


def _model_jacobian(spec: ModelSpec, lik: GaussianReadings, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(predictions, their central-difference derivative) at ``x`` of a Gaussian likelihood."""
    mu = lik.predictions(spec.specimen(x))
    jac = np.empty((len(mu), len(x)))
    for i in range(len(x)):
        h = DIFF_STEP * (spec.upper[i] - spec.lower[i])
        a, b = x.copy(), x.copy()
        a[i], b[i] = max(x[i] - h, spec.lower[i]), min(x[i] + h, spec.upper[i])
        jac[:, i] = (lik.predictions(spec.specimen(b)) - lik.predictions(spec.specimen(a))) / (b[i] - a[i])
    return mu, jac


def _calibrated(result: FitResult, spec: ModelSpec, lik: Likelihood) -> FitResult:
    """``result`` with its p-value calibrated for estimated Type A variances (:mod:`bench.identify.gof`)
    when the readings carry them."""
    # only calibrated readings carry estimated Type A noise
    if not isinstance(lik, GaussianReadings) or lik.noise is None or result.dof <= 0 or not math.isfinite(result.chi2):
        return result
    noise = lik.noise
    mu, jac = _model_jacobian(spec, lik, result.values)
    scales = mu[:, None] * lik.scales.loadings
    p = calibrated_p_value(result.chi2, jac, scales, noise)
    if p is None:
        return result
    return replace(_widened(result, spec, interval_inflation(jac, scales, noise)), p_value=p,
                   p_value_method=f"parametric bootstrap of estimated Type A variances ({DRAWS} draws, fixed seed)")


def _widened(result: FitResult, spec: ModelSpec, factor: np.ndarray | None) -> FitResult:
    """``result`` with each interval (inside the bounds), standard error and the covariance stretched
    about the estimate by ``factor``: the spread of an estimate weighted by estimated Type A
    variances over the error those weights report (:func:`bench.identify.gof.interval_inflation`)."""
    if factor is None:
        return result
    params = {}
    for i, (name, p) in enumerate(result.parameters.items()):
        f, (lo, hi) = float(factor[i]), p.ci
        ci = (max(float(spec.lower[i]), p.value - f * (p.value - lo)),
              min(float(spec.upper[i]), p.value + f * (hi - p.value)))
        params[name] = replace(p, ci=ci, stderr=p.stderr * f)
    return replace(result, parameters=params, covariance=result.covariance * np.outer(factor, factor))


def _fit(spec: ModelSpec, lik: Likelihood, confidence: float, interval: str, starts: int, seed: int,
         deadline: float | None = None) -> FitResult:
    """Steps 1-4 of the module docstring with one likelihood (:class:`_OutOfTime` past ``deadline``)."""
    from scipy.stats import chi2 as chi2_dist

    n = len(spec.free)
    obj = _Objective(spec, lik, deadline)
    lo, hi = spec.lower, spec.upper
    candidates = _starts(spec, starts, seed)
    # multi-start: local fits from the declared defaults and the best screened starts (a narrow
    # valley -- a glossy lobe under a correlated covariance -- can trap the single best start in
    # a local minimum at a bound); the lowest deviance wins
    ranked = sorted(range(len(candidates)), key=lambda k: obj.deviance(_inside(candidates[k], lo, hi)))
    chosen = [0] + [k for k in ranked if k != 0][:LOCAL_STARTS - 1]
    fits = [_local(obj, candidates[k], lo, hi, rough=lik.counted_rays) for k in chosen]
    res = min(fits, key=lambda f: float(f.cost) if np.isfinite(f.cost) else math.inf)
    xhat = np.asarray(res.x, float)
    r = obj(xhat)
    dev_min = float(r @ r)
    jac = np.asarray(res.jac, float)
    fisher = jac.T @ jac
    try:
        cov = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:  # a parameter no reading depends on: the others' covariance stands
        blind = np.diag(fisher) <= 1e-12 * max(float(np.max(np.diag(fisher))), 1e-300)
        cov = np.full((n, n), np.inf)
        if (~blind).any() and blind.any():
            keep = np.flatnonzero(~blind)
            try:
                cov[np.ix_(keep, keep)] = np.linalg.inv(fisher[np.ix_(keep, keep)])
            except np.linalg.LinAlgError:
                pass
    se = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.nan))
    q = float(chi2_dist.ppf(confidence, 1))
    cis = []
    for i in range(n):
        if interval == "hessian":
            half = math.sqrt(q) * se[i] if math.isfinite(se[i]) else math.inf
            cis.append((max(float(lo[i]), xhat[i] - half), min(float(hi[i]), xhat[i] + half)))
        else:
            cis.append((_profile_limit(obj, xhat, dev_min, cov, i, -1, q),
                        _profile_limit(obj, xhat, dev_min, cov, i, +1, q)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    dof = int(lik.n_data(spec.specimen(xhat))) - n
    p_value = float(chi2_dist.sf(dev_min, dof)) if dof > 0 else math.nan
    params = {p.name: ParameterEstimate(p.name, float(xhat[i]), (float(cis[i][0]), float(cis[i][1])), p.unit,
                                        float(se[i])) for i, p in enumerate(spec.free)}
    return FitResult(model=spec.text, family=spec.family.name, specimen=spec.specimen_string(xhat),
                     parameters=params, fixed=dict(spec.fixed), covariance=cov, fisher=fisher, correlation=corr,
                     chi2=dev_min, dof=dof, p_value=p_value, converged=bool(res.status > 0 and np.isfinite(dev_min)),
                     message=str(res.message), likelihood=lik.kind, interval=interval, confidence=float(confidence),
                     n_evaluations=len(obj.cache), residuals=r, groups=lik.groups, xlabel=lik.xlabel)


def _stopped(obj: _Objective, max_seconds: float, confidence: float, interval: str) -> FitResult:
    """The best point a fit stopped by its time limit reached: not converged, no intervals."""
    from scipy.stats import chi2 as chi2_dist

    spec, lik = obj.spec, obj.lik
    assert obj.best is not None  # the limit is checked only once a point was evaluated
    dev, key = obj.best
    x = np.array(key, float)
    n = len(spec.free)
    nan = np.full((n, n), np.nan)
    dof = int(lik.n_data(spec.specimen(x))) - n
    params = {p.name: ParameterEstimate(p.name, float(x[i]), (math.nan, math.nan), p.unit, math.nan)
              for i, p in enumerate(spec.free)}
    log.info("fit: stopped at the time limit of %g s after %d evaluations", max_seconds, len(obj.cache))
    return FitResult(model=spec.text, family=spec.family.name, specimen=spec.specimen_string(x), parameters=params,
                     fixed=dict(spec.fixed), covariance=nan, fisher=nan.copy(), correlation=nan.copy(), chi2=dev,
                     dof=dof, p_value=float(chi2_dist.sf(dev, dof)) if dof > 0 else math.nan, converged=False,
                     message=f"stopped at the time limit ({max_seconds:g} s) with the best point of "
                             f"{len(obj.cache)} evaluations; no intervals", likelihood=lik.kind, interval=interval,
                     confidence=float(confidence), n_evaluations=len(obj.cache), residuals=obj(x), groups=lik.groups,
                     xlabel=lik.xlabel)
