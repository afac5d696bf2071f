"""Plans designed to identify a model: the most information on its free parameters per bench second.

For Gaussian readings the Fisher information of a set of points is ``F = J^T C^-1 J``, with ``J``
the derivative of each predicted calibrated reading (BRDF per band, :mod:`bench.identify.design_noise`)
with respect to the free parameters at the prior guess (central differences on the specimen's
density), and ``C`` the readings' covariance as the fit counts it: each reading's own noise, one
additive error per dark and wavelength shared by the readings that dark corrects (with
``dark = "per-incidence"`` every reading of an incidence: a point at a new incidence brings a new
dark), and the relative scale errors shared by the record (the white reading per wavelength, the
white standard's certificate). Each shared term is rank one, so ``C^-1`` follows from the
Sherman-Morrison formula level by level (darks, white reading, certificate:
:mod:`bench.identify.design_information`), ``F`` is a few sums
over points of small matrices, and the greedy design adds, at each step, the candidate with the
largest criterion gain per marginal bench second (:class:`bench.identify.time_model.TimeModel`),
then exchanges chosen points for better ones of no greater cost, and trims to the budget with
``bench plan``'s own estimate.

Criteria (maximised): ``D`` = log det F, ``A`` = -trace(F^-1), ``E`` = smallest eigenvalue of F.
The Cramer-Rao bound ``sqrt(diag F^-1)`` gives the predicted standard errors, reported as 95 %
interval widths (``2 x 1.96 x se``).

A design at one guess of the parameters is only as good as the guess (a rough, dark plastic designed
for at the default prior lost most of the gain over the uniform plan). By default the design is
pseudo-Bayesian: the criterion is averaged over a fixed set of parameter points spread over a prior
range (:meth:`ModelPoint.prior_points`: the guess and :data:`PRIOR_DRAWS` Latin-hypercube points,
each free parameter log-uniform from guess / spread to guess x spread within its bounds), each
point's information scaled by its readings' relative sensitivity so that no point outweighs the
others by the size of its signal. The predicted widths are the Cramer-Rao bound at the guess itself,
with their range over the prior points (:attr:`Design.width_range`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from time import monotonic
from typing import Any, Mapping, Sequence

import numpy as np

from bench.config import Bench
from bench.core.errors import ConfigError, SpecimenError
from bench.core.geometry import Geometry
from bench.exposure import unsaturated
from bench.identify.design_information import Information, dark_groups
from bench.identify.design_noise import ReadingModel
from bench.identify.prediction import Band, predicted_brdf
from bench.identify.time_model import ReadingSettings, TimeModel
from virtual.specimens import DeclaredSpecimen

__all__ = ["ModelPoint", "Information", "PriorInformation", "prior_information", "information", "prior_sensitivities",
           "mean_criterion", "PRIOR_SPREAD", "PRIOR_DRAWS", "Sensitivities", "sensitivities", "criterion", "Design", "design_plan", "CRITERIA",
           "interval_widths", "Z95", "design_for_bench", "integration_choices", "dark_groups"]

CRITERIA = ("D", "A", "E")
#: two-sided 95 % normal quantile: predicted interval width = 2 x Z95 x Cramer-Rao standard error
Z95 = 1.959963984540054
#: relative step of the central differences (of the parameter's range when the value is 0)
_REL_STEP = 1e-4
#: default prior range of a design: each free parameter from its guess / 4 to its guess x 4
PRIOR_SPREAD = 4.0
#: parameter points drawn over the prior range (besides the guess itself), fixed seed
PRIOR_DRAWS = 8


@dataclass(frozen=True)
class ModelPoint:
    """A specimen family at one point of its parameter space, with the parameters to identify."""

    family: type[DeclaredSpecimen]
    values: Mapping[str, float]
    free: tuple[str, ...]
    #: prior range factor: the design averages over guess / spread .. guess x spread (1: at the guess only)
    spread: float = 1.0

    def specimen(self, values: Mapping[str, float] | None = None) -> DeclaredSpecimen:
        return self.family.from_keywords(dict(values if values is not None else self.values))

    def spec(self) -> str:
        return f"{self.family.name}:" + ",".join(f"{k}={v:g}" for k, v in self.values.items())

    def prior_points(self, draws: int = PRIOR_DRAWS, seed: int = 0) -> list["ModelPoint"]:
        """The guess, then ``draws`` points of a fixed-seed Latin hypercube over the prior range: each
        free parameter log-uniform in [guess / spread, guess x spread] clipped to its declared bounds
        (uniform from its lower bound over 1/spread of its range when the guess is 0). Points the
        family refuses are left out. Only the guess when ``spread`` <= 1."""
        here = replace(self, spread=1.0)
        if self.spread <= 1.0 or not self.free or draws < 1:
            return [here]
        declared = {p.name: p for p in self.family.parameters}
        rng = np.random.default_rng(seed)
        cube = np.stack([(rng.permutation(draws) + rng.random(draws)) / draws for _ in self.free], axis=1)
        out = [here]
        for row in cube:
            values = dict(self.values)
            for k, u in zip(self.free, row):
                p, v = declared[k], float(self.values[k])
                lo, hi = (max(v / self.spread, p.lo), min(v * self.spread, p.hi)) if v > 0 else \
                    (p.lo, p.lo + (p.hi - p.lo) / self.spread)
                values[k] = lo * (hi / lo) ** u if lo > 0 else lo + (hi - lo) * u
            try:
                self.specimen(values)
            except (SpecimenError, ValueError):
                continue
            out.append(replace(here, values=values))
        return out

    def steps(self) -> dict[str, float]:
        declared = {p.name: p for p in self.family.parameters}
        out = {}
        for k in self.free:
            p, v = declared[k], float(self.values[k])
            h = _REL_STEP * (abs(v) if v != 0 else (p.hi - p.lo))
            out[k] = min(h, (p.hi - v) / 2 if p.hi > v else h, (v - p.lo) / 2 if v > p.lo else h)
        return out


@dataclass
class PriorInformation:
    """The information at each parameter point of a prior range, stacked: ``total`` gives
    ``(points, p, p)`` and ``with_each`` ``(len(cand), points, p, p)``. ``parts[m]`` is point m's
    own information, ``infos[m]`` the same scaled by the readings' relative sensitivity there
    against the guess's (``parts[0]``, the guess, unscaled), so no point outweighs the others by
    the size of its signal."""

    parts: list[Information]
    infos: list[Information]

    def total(self, idx: Sequence[int] | np.ndarray) -> np.ndarray:
        return np.stack([i.total(idx) for i in self.infos])

    def with_each(self, idx: Sequence[int], cand: np.ndarray) -> np.ndarray:
        return np.stack([i.with_each(idx, cand) for i in self.infos], axis=1)


def prior_information(model: ModelPoint, pool: Sequence[Geometry], readings: ReadingModel, shared_scale: bool = True,
                      sens: "Sensitivities | Sequence[Sensitivities] | None" = None,
                      groups: np.ndarray | None = None) -> PriorInformation:
    """The information of ``pool`` at each of ``model.prior_points()`` (:class:`PriorInformation`;
    ``groups``: which dark each point is read with, :func:`dark_groups`)."""
    models = model.prior_points()
    sens_all = prior_sensitivities(models, pool, readings, sens)
    parts = [information(m, pool, readings, shared_scale, x, groups) for m, x in zip(models, sens_all)]
    scales = [_relative_scale(x) for x in sens_all]
    return PriorInformation(parts, [i.scaled(s / scales[0]) for i, s in zip(parts, scales)])


def mean_criterion(fisher: np.ndarray, name: str = "D") -> np.ndarray:
    """The criterion averaged over the parameter points (the one-but-last two axes are each Fisher
    matrix, the axis before them the points): the pseudo-Bayesian criterion."""
    f = np.asarray(fisher, dtype=float)
    p = f.shape[-1]
    return np.asarray(criterion(f.reshape(-1, p, p), name)).reshape(f.shape[:-2]).mean(axis=-1)


def _relative_scale(sens: "Sensitivities") -> float:
    """How strongly the readings respond to the parameters, relative to their size (mean over the
    readings of sum_k (dy/dk / y)^2): the scale that makes the points of a prior range comparable,
    independent of how the points are read."""
    f = sens.brdf[..., None]
    ok = np.isfinite(f) & (np.abs(f) > 0) & np.isfinite(sens.jacobian)
    r = np.where(ok, sens.jacobian / np.where(ok, f, 1.0), 0.0)
    s = float((r**2).sum(axis=-1).mean())
    return s if s > 0 and math.isfinite(s) else 1.0


@dataclass(frozen=True)
class Sensitivities:
    """The model's predicted readings ``brdf`` (points, wavelengths) at the prior and their
    derivatives ``jacobian`` (points, wavelengths, free parameters): they do not depend on how
    the points are read, so one computation serves every reading setting."""

    brdf: np.ndarray
    jacobian: np.ndarray


def sensitivities(model: ModelPoint, candidates: Sequence[Geometry], wavelengths: np.ndarray,
                  aperture_deg: float = 0.0, white: Geometry | None = None,
                  bands: Sequence[Band] | None = None) -> Sensitivities:
    """Predicted readings (:func:`bench.identify.prediction.predicted_brdf`, the fit's prediction:
    a detector of half-angle ``aperture_deg`` calibrated against a white read at ``white``, a
    spectral specimen's band the mean over its ``bands`` wavelengths) and their central-difference
    derivatives at the prior."""
    f0 = predicted_brdf(model.specimen(), candidates, wavelengths, aperture_deg, white, bands)
    jac = []
    for k, h in model.steps().items():
        up = dict(model.values, **{k: model.values[k] + h})
        dn = dict(model.values, **{k: model.values[k] - h})
        jac.append((predicted_brdf(model.specimen(up), candidates, wavelengths, aperture_deg, white, bands)
                    - predicted_brdf(model.specimen(dn), candidates, wavelengths, aperture_deg, white, bands))
                   / (2 * h))
    return Sensitivities(f0, np.stack(jac, axis=-1))


def prior_sensitivities(models: Sequence[ModelPoint], pool: Sequence[Geometry], readings: ReadingModel,
                        given: Sensitivities | Sequence[Sensitivities] | None = None) -> list[Sensitivities]:
    """The sensitivities of ``pool`` at each of ``models`` (the prior range's points); ``given``: those
    already computed (of the first points, or a single one: the guess's)."""
    have = [] if given is None else [given] if isinstance(given, Sensitivities) else list(given)
    return have[:len(models)] + [sensitivities(m, pool, readings.wavelengths, readings.aperture_deg,
                                               readings.standard.geometry, readings.bands)
                                 for m in models[len(have):]]


def information(model: ModelPoint, candidates: Sequence[Geometry], readings: ReadingModel,
                shared_scale: bool = True, sens: Sensitivities | None = None,
                groups: np.ndarray | None = None) -> Information:
    """The per-candidate Fisher information of ``model``'s free parameters on a bench body.

    The readings' covariance is the record's (:func:`bench.identify.likelihood.record_covariance`,
    the budgets' full covariance): each reading's own noise, each dark's error as one offset shared
    by the readings it corrects (``groups``: :func:`dark_groups` of ``candidates`` read as the
    readings' settings say, the default), the white reading's and the certificate's as relative
    scales shared by the record. ``shared_scale`` False counts the white's terms in each reading's
    own variance (a diagonal covariance but for the darks), which designs for an error that
    averages away and, against the fit, chose 2.6x wider plans (docs/design.md).
    """
    sens = sens or sensitivities(model, candidates, readings.wavelengths, readings.aperture_deg,
                                 readings.standard.geometry, readings.bands)
    f0 = sens.brdf
    parts = readings.noise(f0, candidates)
    sigma, white2, cert2 = parts.own, parts.white**2, parts.certificate**2
    if not shared_scale:
        sigma = np.sqrt(sigma**2 + (white2 + cert2) * f0**2)
        white2, cert2 = np.zeros_like(white2), np.zeros_like(cert2)
    ok = np.isfinite(sigma) & (sigma > 0) & np.isfinite(f0) & np.isfinite(parts.dark)
    w = np.where(ok, 1.0 / np.where(ok, sigma, 1.0) ** 2, 0.0)  # own variance^-1 (0 for a masked reading)
    f = np.where(ok, f0, 0.0)
    g = np.where(ok, parts.dark, 0.0)
    j = np.where(ok[..., None], sens.jacobian, 0.0)  # (n, wavelengths, p)
    if groups is None:
        groups = dark_groups(candidates, readings.settings.dark)
    return Information(np.einsum("nwi,nw,nwj->nwij", j, w, j), j * (w * f)[..., None], f * w * f,
                       j * (w * g)[..., None], f * w * g, g * w * g, np.asarray(groups, dtype=int),
                       white2, cert2, f0, sigma)


def criterion(fisher: np.ndarray, name: str = "D") -> np.ndarray:
    """The design criterion of one or many Fisher matrices (larger is better; -inf if singular)."""
    f = np.asarray(fisher, dtype=float)
    one = f.ndim == 2
    f = f[None] if one else f
    eig = np.linalg.eigvalsh(f)  # ascending
    tiny = eig[:, -1:] * 1e-12
    singular = (eig <= np.maximum(tiny, 0.0)).any(axis=1) | (eig[:, -1] <= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        if name == "D":
            v = np.log(np.where(eig > 0, eig, 1.0)).sum(axis=1)
        elif name == "A":
            v = -(1.0 / np.where(eig > 0, eig, 1.0)).sum(axis=1)
        elif name == "E":
            v = eig[:, 0].copy()
        else:
            raise ConfigError(f"design criterion must be one of {', '.join(CRITERIA)}, got {name!r}")
    v = np.where(singular, -np.inf, v)
    return v[0] if one else v


def interval_widths(fisher: np.ndarray, names: Sequence[str]) -> dict[str, float]:
    """Predicted 95 % interval width of each parameter (Cramer-Rao), inf if not identifiable."""
    try:
        cov = np.linalg.inv(fisher)
    except np.linalg.LinAlgError:
        return {k: math.inf for k in names}
    d = np.diag(cov)
    return {k: (2 * Z95 * math.sqrt(v) if v > 0 and math.isfinite(v) else math.inf) for k, v in zip(names, d)}


@dataclass
class Design:
    """A designed set of points and what it is predicted to give."""

    points: list[Geometry]
    seconds: float
    estimate: dict[str, Any]
    criterion: str
    value: float
    widths: dict[str, float]
    fisher: np.ndarray
    model: ModelPoint
    settings: ReadingSettings
    #: why the search stopped before it was done (its time limit), or None: it finished
    stopped: str | None = None
    #: each parameter's predicted width (min, max) over the prior range's points (the guess's alone when
    #: the design is at the guess)
    width_range: dict[str, tuple[float, float]] | None = None
    #: how many parameter points the criterion averaged (1: a design at the guess alone)
    prior_points: int = 1


def design_plan(model: ModelPoint, candidates: Sequence[Geometry], readings: ReadingModel, time: TimeModel,
                seconds: float, criterion_name: str = "D", seed_points: Sequence[Geometry] = (),
                sens: Sensitivities | Sequence[Sensitivities] | None = None, shared_scale: bool = True,
                deadline: float | None = None) -> Design:
    """Choose points among ``candidates`` that maximise the criterion within ``seconds`` of bench time.

    Past ``deadline`` (``time.monotonic()``), once a point is chosen, the search stops with the
    points chosen so far (within the budget) and says so in :attr:`Design.stopped`.

    ``seed_points`` are measured already (a sequential design's earlier steps): they count in the
    information, not in the time. ``sens``: the sensitivities of ``candidates + seed_points`` at
    the prior range's points (:func:`prior_sensitivities`; computed when not given). The criterion
    is averaged over :meth:`ModelPoint.prior_points` (the guess alone when ``model.spread`` is 1);
    :attr:`Design.widths` are the Cramer-Rao widths at the guess. Raises :class:`ConfigError` when
    no free parameter is given, or
    when the budget cannot buy a design that identifies every free parameter.
    """
    if not model.free:
        raise ConfigError(f"model {model.spec()} has no free parameter: mark the ones to design for "
                          f"with '?', e.g. {model.family.name}:{model.family.parameters[0].name}=?")
    if criterion_name not in CRITERIA:
        raise ConfigError(f"design criterion must be one of {', '.join(CRITERIA)}, got {criterion_name!r}")
    _refuse_unaffordable(model, candidates, time, seconds)
    pool = list(candidates) + list(seed_points)
    info = prior_information(model, pool, readings, shared_scale, sens,
                             dark_groups(pool, readings.settings.dark, measured=len(seed_points)))
    exact = info.parts[0]  # at the guess: the predicted widths
    n_cand = len(candidates)
    p = len(model.free)
    fixed = list(range(len(candidates), len(pool)))
    # keeps log det finite until p points are chosen
    ridge = np.stack([np.eye(p) * max(np.trace(i.own[:n_cand].mean(axis=0)) / p if n_cand else 1.0, 1e-300) * 1e-9
                      for i in info.infos])
    chosen: list[int] = []
    spent = 0.0
    stopped = None
    while True:
        if deadline is not None and len(chosen) >= p and monotonic() > deadline:
            stopped = f"the time limit passed while choosing points ({len(chosen)} chosen)"
            break
        free = np.array([k for k in range(n_cand) if k not in chosen], dtype=int)
        if free.size == 0:
            break
        pts = [pool[i] for i in chosen]
        cost = time.marginal([pool[k] for k in free], pts)
        fits = spent + cost <= seconds
        if not fits.any():
            break
        base = mean_criterion(info.total(fixed + chosen) + ridge, criterion_name)
        gain = mean_criterion(info.with_each(fixed + chosen, free) + ridge[None], criterion_name) - base
        score = np.where(fits, gain / cost, -np.inf)
        best = int(np.argmax(score))
        if not np.isfinite(score[best]) or gain[best] <= 0:
            break
        chosen.append(int(free[best]))
        spent += float(cost[best])

    if stopped is None:
        chosen, stopped = _exchange(info, pool, chosen, fixed, n_cand, time, seconds, criterion_name, ridge,
                                    deadline=deadline)
    while chosen and time.seconds([pool[i] for i in chosen])["seconds"] > seconds:
        # the marginal costs were approximate: drop the point whose loss hurts least
        losses = [mean_criterion(info.total(fixed + chosen[:j] + chosen[j + 1:]) + ridge, criterion_name)
                  for j in range(len(chosen))]
        chosen.pop(int(np.argmax(losses)))
    fisher = exact.total(fixed + chosen) if (fixed or chosen) else np.zeros((p, p))
    value = float(mean_criterion(info.total(fixed + chosen), criterion_name)) if (fixed or chosen) else -math.inf
    spread = [interval_widths(i.total(fixed + chosen), model.free) for i in info.parts] if (fixed or chosen) else []
    if not chosen or not np.isfinite(value):
        least = time.seconds([pool[i] for i in chosen[:1]] or [candidates[0]])["seconds"] if n_cand else math.nan
        raise _no_design(model, seconds, least)
    points = [pool[i] for i in chosen]
    est = time.seconds(points)
    return Design(points, float(est["seconds"]), est, criterion_name, value,
                  interval_widths(fisher, model.free), fisher, model, readings.settings, stopped,
                  {k: (min(w[k] for w in spread), max(w[k] for w in spread)) for k in model.free}, len(info.parts))


def _refuse_unaffordable(model: ModelPoint, candidates: Sequence[Geometry], time: TimeModel, seconds: float) -> None:
    """Refuse a budget in which no candidate alone fits, as the greedy search would after its
    first step, but before the information, whose sensitivities over the prior range are the
    design's whole cost."""
    if candidates and not (time.marginal(list(candidates), []) <= seconds).any():
        raise _no_design(model, seconds, time.seconds([candidates[0]])["seconds"])


def _no_design(model: ModelPoint, seconds: float, least: float) -> ConfigError:
    """The refusal of a budget that buys no design identifying every free parameter."""
    return ConfigError(f"a budget of {seconds:g} s buys no design that identifies {', '.join(model.free)} of "
                       f"{model.family.name} on this bench (one point alone takes {least:.3g} s; at least "
                       f"{len(model.free)} informative points are needed): give more --budget-seconds")


def _exchange(info: PriorInformation, pool: Sequence[Geometry], chosen: list[int], fixed: list[int], n_cand: int,
              time: TimeModel, seconds: float, name: str, ridge: np.ndarray, rounds: int = 3,
              deadline: float | None = None) -> tuple[list[int], str | None]:
    """Fedorov-style exchange: swap a chosen point for an unchosen one when the criterion rises and
    the plan's estimated time stays within the budget. Returns the points and why the exchange
    stopped early (past ``deadline``), or None."""
    chosen = list(chosen)
    for _ in range(rounds):
        improved = False
        for j in range(len(chosen)):
            if deadline is not None and monotonic() > deadline:
                return chosen, "the time limit passed while exchanging points"
            rest = chosen[:j] + chosen[j + 1:]
            free = np.array([k for k in range(n_cand) if k not in chosen], dtype=int)
            if free.size == 0:
                return chosen, None
            now = float(mean_criterion(info.total(fixed + chosen) + ridge, name))
            vals = mean_criterion(info.with_each(fixed + rest, free) + ridge[None], name)
            for k in np.argsort(-vals)[:5]:  # the best few swaps, checked against the budget
                if not vals[k] > now + 1e-12 * max(1.0, abs(now)):
                    break
                trial = rest + [int(free[k])]
                if time.seconds([pool[i] for i in trial])["seconds"] <= seconds:
                    chosen = trial
                    improved = True
                    break
        if not improved:
            break
    return chosen, None


def design_for_bench(model: ModelPoint, bench: Bench, candidates: Sequence[Geometry], seconds: float,
                     settings: Sequence[ReadingSettings], criterion_name: str = "D",
                     seed_points: Sequence[Geometry] = (), shared_scale: bool = True,
                     max_seconds: float | None = None) -> Design:
    """The best design over several ways of reading the points (e.g. integration times): each
    has its own noise and time per point; the one with the largest criterion wins. Raises as
    :func:`design_plan` when none fits the budget. With ``max_seconds`` (wall clock) the search
    stops once a design exists and the time has passed, with the best design so far and the
    reason in :attr:`Design.stopped`. Each way of reading chooses among the candidates the bench's
    detector does not saturate at its integration time (as ``bench plan`` and ``bench scan`` refuse:
    :func:`bench.exposure.unsaturated`), so a short integration may take a bright point a long one
    may not."""
    from bench.identify.design_noise import bench_reading_model
    from bench.identify.time_model import bench_time_model

    pool = list(candidates) + list(seed_points)
    best: Design | None = None
    error: ConfigError | None = None
    sens: list[Sensitivities] | None = None
    deadline = None if max_seconds is None else monotonic() + float(max_seconds)
    cut: str | None = None  # why a design_plan stopped early
    tried = 0
    for s in settings:
        if best is not None and deadline is not None and monotonic() > deadline:
            break
        tried += 1
        readings = bench_reading_model(bench, s)
        time = bench_time_model(bench, s)
        config = getattr(bench, "config", None)
        ok = set(unsaturated(list(candidates), config, s.integration_s)) if config is not None else set(candidates)
        keep = [i for i, g in enumerate(candidates) if g in ok] + list(range(len(candidates), len(pool)))
        try:
            if not ok:
                raise ConfigError(f"every candidate point saturates the detector at {s.integration_s:g} s")
            _refuse_unaffordable(model, [pool[i] for i in keep if i < len(candidates)], time, seconds)
            sens = sens or prior_sensitivities(model.prior_points(), pool, readings)
            d = design_plan(model, [pool[i] for i in keep if i < len(candidates)], readings,
                            time, seconds, criterion_name, seed_points,
                            [Sensitivities(x.brdf[keep], x.jacobian[keep]) for x in sens], shared_scale, deadline)
        except ConfigError as exc:
            error = error or exc
            continue
        cut = cut or d.stopped
        if best is None or d.value > best.value:
            best = d
    if best is None:
        assert error is not None
        raise error
    if cut is None and tried == len(settings):
        return replace(best, stopped=None)
    return replace(best, stopped=f"the time limit of {max_seconds:g} s passed{': ' + cut if cut else ''}; the best "
                                 f"design of {tried} of {len(settings)} integration times")


def integration_choices(base: ReadingSettings, times: Sequence[float]) -> list[ReadingSettings]:
    """``base`` read with each integration time of ``times``."""
    return [replace(base, integration_s=float(t)) for t in times]
