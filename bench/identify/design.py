"""Plans designed to identify a model: the most information on its free parameters per bench second.

For Gaussian readings the Fisher information of a set of points is ``F = J^T C^-1 J``, with ``J``
the derivative of each predicted calibrated reading (BRDF per band, :mod:`bench.identify.design_noise`)
with respect to the free parameters at the prior guess (central differences on the specimen's
density), and ``C`` the readings' covariance: each reading's own noise plus one relative scale
error shared by the whole record (the white standard). With that rank-one term ``C^-1`` follows
from the Sherman-Morrison formula, so ``F`` is a sum over points of small matrices and the
greedy design adds, at each step, the candidate with the largest criterion gain per marginal
bench second (:class:`bench.identify.time_model.TimeModel`), then exchanges chosen points for
better ones of no greater cost, and trims to the budget with ``bench plan``'s own estimate.

Criteria (maximised): ``D`` = log det F, ``A`` = -trace(F^-1), ``E`` = smallest eigenvalue of F.
The Cramer-Rao bound ``sqrt(diag F^-1)`` gives the predicted standard errors, reported as 95 %
interval widths (``2 x 1.96 x se``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from time import monotonic
from typing import Any, Mapping, Sequence

import numpy as np

from bench.core.errors import ConfigError
from bench.core.geometry import Geometry
from bench.identify.design_noise import ReadingModel
from bench.identify.prediction import predicted_brdf
from bench.identify.time_model import ReadingSettings, TimeModel

__all__ = ["ModelPoint", "Information", "information", "Sensitivities", "sensitivities", "criterion", "Design", "design_plan", "CRITERIA",
           "interval_widths", "Z95", "design_for_bench", "integration_choices"]

CRITERIA = ("D", "A", "E")
#: two-sided 95 % normal quantile: predicted interval width = 2 x Z95 x Cramer-Rao standard error
Z95 = 1.959963984540054
#: relative step of the central differences (of the parameter's range when the value is 0)
_REL_STEP = 1e-4


@dataclass(frozen=True)
class ModelPoint:
    """A specimen family at one point of its parameter space, with the parameters to identify."""

    family: type
    values: Mapping[str, float]
    free: tuple[str, ...]

    def specimen(self, values: Mapping[str, float] | None = None) -> Any:
        return self.family.from_keywords(dict(values if values is not None else self.values))

    def spec(self) -> str:
        return f"{self.family.name}:" + ",".join(f"{k}={v:g}" for k, v in self.values.items())

    def steps(self) -> dict[str, float]:
        declared = {p.name: p for p in self.family.parameters}
        out = {}
        for k in self.free:
            p, v = declared[k], float(self.values[k])
            h = _REL_STEP * (abs(v) if v != 0 else (p.hi - p.lo))
            out[k] = min(h, (p.hi - v) / 2 if p.hi > v else h, (v - p.lo) / 2 if v > p.lo else h)
        return out


@dataclass
class Information:
    """Per-candidate pieces of the Fisher information: ``own[k]`` = J_k^T D_k^-1 J_k, ``cross[k]`` =
    J_k^T D_k^-1 f_k and ``self_[k]`` = f_k^T D_k^-1 f_k (D the own variances), and the shared
    relative variance ``rho2``."""

    own: np.ndarray  # (n, p, p)
    cross: np.ndarray  # (n, p)
    self_: np.ndarray  # (n,)
    rho2: float
    brdf: np.ndarray  # (n, wavelengths) predicted
    sigma: np.ndarray  # (n, wavelengths) own noise

    def total(self, idx: Sequence[int] | np.ndarray) -> np.ndarray:
        """Fisher information of the points ``idx`` (each measured once)."""
        idx = np.asarray(idx, dtype=int)
        a = self.own[idx].sum(axis=0)
        b = self.cross[idx].sum(axis=0)
        c = float(self.self_[idx].sum())
        return a - self.rho2 * np.outer(b, b) / (1.0 + self.rho2 * c)

    def with_each(self, idx: Sequence[int], cand: np.ndarray) -> np.ndarray:
        """Fisher information of ``idx`` plus each one of ``cand``: ``(len(cand), p, p)``."""
        idx = np.asarray(idx, dtype=int)
        a = self.own[idx].sum(axis=0)[None] + self.own[cand]
        b = self.cross[idx].sum(axis=0)[None] + self.cross[cand]
        c = float(self.self_[idx].sum()) + self.self_[cand]
        return a - (self.rho2 / (1.0 + self.rho2 * c))[:, None, None] * np.einsum("ni,nj->nij", b, b)


@dataclass(frozen=True)
class Sensitivities:
    """The model's predicted readings ``brdf`` (points, wavelengths) at the prior and their
    derivatives ``jacobian`` (points, wavelengths, free parameters): they do not depend on how
    the points are read, so one computation serves every reading setting."""

    brdf: np.ndarray
    jacobian: np.ndarray


def sensitivities(model: ModelPoint, candidates: Sequence[Geometry], wavelengths: np.ndarray,
                  aperture_deg: float = 0.0, white: Geometry | None = None) -> Sensitivities:
    """Predicted readings (:func:`bench.identify.prediction.predicted_brdf`, the fit's prediction:
    a detector of half-angle ``aperture_deg`` calibrated against a white read at ``white``) and
    their central-difference derivatives at the prior."""
    f0 = predicted_brdf(model.specimen(), candidates, wavelengths, aperture_deg, white)
    jac = []
    for k, h in model.steps().items():
        up = dict(model.values, **{k: model.values[k] + h})
        dn = dict(model.values, **{k: model.values[k] - h})
        jac.append((predicted_brdf(model.specimen(up), candidates, wavelengths, aperture_deg, white)
                    - predicted_brdf(model.specimen(dn), candidates, wavelengths, aperture_deg, white)) / (2 * h))
    return Sensitivities(f0, np.stack(jac, axis=-1))


def information(model: ModelPoint, candidates: Sequence[Geometry], readings: ReadingModel,
                shared_scale: bool = True, sens: Sensitivities | None = None) -> Information:
    """The per-candidate Fisher information of ``model``'s free parameters on a bench body.

    ``shared_scale`` (default True): count the white standard's relative uncertainty as one error
    common to the whole record (rank-one covariance), as the fit's likelihood does
    (:func:`bench.identify.likelihood.readings_and_covariance`: the budgets' full covariance);
    False counts it in each reading's own variance (a diagonal covariance), which designs for an
    error that averages away and, against the fit, chose 2.6x wider plans (README, "Accuracy per
    bench-minute").
    """
    sens = sens or sensitivities(model, candidates, readings.wavelengths, readings.aperture_deg,
                                 readings.standard.geometry)
    f0 = sens.brdf
    sigma, rho = readings.noise(f0, candidates)
    if not shared_scale:
        sigma, rho = np.sqrt(sigma**2 + (rho * f0) ** 2), 0.0
    ok = np.isfinite(sigma) & (sigma > 0) & np.isfinite(f0)
    w = np.where(ok, 1.0 / np.where(ok, sigma, 1.0) ** 2, 0.0)  # D^-1 (0 for a masked reading)
    f = np.where(ok, f0, 0.0)
    j = np.where(ok[..., None], sens.jacobian, 0.0)  # (n, wavelengths, p)
    own = np.einsum("nwi,nw,nwj->nij", j, w, j)
    cross = np.einsum("nwi,nw,nw->ni", j, w, f)
    self_ = np.einsum("nw,nw,nw->n", f, w, f)
    return Information(own, cross, self_, rho * rho, f0, sigma)


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


def design_plan(model: ModelPoint, candidates: Sequence[Geometry], readings: ReadingModel, time: TimeModel,
                seconds: float, criterion_name: str = "D", seed_points: Sequence[Geometry] = (),
                sens: Sensitivities | None = None, shared_scale: bool = True, deadline: float | None = None) -> Design:
    """Choose points among ``candidates`` that maximise the criterion within ``seconds`` of bench time.

    Past ``deadline`` (``time.monotonic()``), once a point is chosen, the search stops with the
    points chosen so far (within the budget) and says so in :attr:`Design.stopped`.

    ``seed_points`` are measured already (a sequential design's earlier steps): they count in the
    information, not in the time. ``sens``: the sensitivities of ``candidates + seed_points``
    (computed when not given). Raises :class:`ConfigError` when no free parameter is given, or
    when the budget cannot buy a design that identifies every free parameter.
    """
    if not model.free:
        raise ConfigError(f"model {model.spec()} has no free parameter: mark the ones to design for "
                          f"with '?', e.g. {model.family.name}:{model.family.parameters[0].name}=?")
    if criterion_name not in CRITERIA:
        raise ConfigError(f"design criterion must be one of {', '.join(CRITERIA)}, got {criterion_name!r}")
    pool = list(candidates) + list(seed_points)
    info = information(model, pool, readings, shared_scale, sens)
    fixed = list(range(len(candidates), len(pool)))
    n_cand = len(candidates)
    p = len(model.free)
    scale = np.trace(info.own[:n_cand].mean(axis=0)) / p if n_cand else 1.0
    ridge = np.eye(p) * max(scale, 1e-300) * 1e-9  # keeps log det finite until p points are chosen

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
        base = criterion(info.total(fixed + chosen) + ridge, criterion_name)
        gain = criterion(info.with_each(fixed + chosen, free) + ridge[None], criterion_name) - base
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
        losses = [criterion(info.total(fixed + chosen[:j] + chosen[j + 1:]) + ridge, criterion_name)
                  for j in range(len(chosen))]
        chosen.pop(int(np.argmax(losses)))
    fisher = info.total(fixed + chosen) if (fixed or chosen) else np.zeros((p, p))
    value = float(criterion(fisher, criterion_name))
    if not chosen or not np.isfinite(value):
        least = time.seconds([pool[i] for i in chosen[:1]] or [candidates[0]])["seconds"] if n_cand else math.nan
        raise ConfigError(f"a budget of {seconds:g} s buys no design that identifies {', '.join(model.free)} of "
                          f"{model.family.name} on this bench (one point alone takes {least:.3g} s; at least {p} "
                          f"informative points are needed): give more --seconds")
    points = [pool[i] for i in chosen]
    est = time.seconds(points)
    return Design(points, float(est["seconds"]), est, criterion_name, value,
                  interval_widths(fisher, model.free), fisher, model, readings.settings, stopped)


def _exchange(info: Information, pool: Sequence[Geometry], chosen: list[int], fixed: list[int], n_cand: int,
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
            now = criterion(info.total(fixed + chosen) + ridge, name)
            vals = criterion(info.with_each(fixed + rest, free) + ridge[None], name)
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


def design_for_bench(model: ModelPoint, bench: Any, candidates: Sequence[Geometry], seconds: float,
                     settings: Sequence[ReadingSettings], criterion_name: str = "D",
                     seed_points: Sequence[Geometry] = (), shared_scale: bool = True,
                     max_seconds: float | None = None) -> Design:
    """The best design over several ways of reading the points (e.g. integration times): each
    has its own noise and time per point; the one with the largest criterion wins. Raises as
    :func:`design_plan` when none fits the budget. With ``max_seconds`` (wall clock) the search
    stops once a design exists and the time has passed, with the best design so far and the
    reason in :attr:`Design.stopped`."""
    from bench.identify.design_noise import bench_reading_model
    from bench.identify.time_model import bench_time_model

    pool = list(candidates) + list(seed_points)
    best: Design | None = None
    error: ConfigError | None = None
    sens = None
    deadline = None if max_seconds is None else monotonic() + float(max_seconds)
    cut: str | None = None  # why a design_plan stopped early
    tried = 0
    for s in settings:
        if best is not None and deadline is not None and monotonic() > deadline:
            break
        tried += 1
        readings = bench_reading_model(bench, s)
        sens = sens or sensitivities(model, pool, readings.wavelengths, readings.aperture_deg,
                                    readings.standard.geometry)
        try:
            d = design_plan(model, candidates, readings, bench_time_model(bench, s), seconds, criterion_name,
                            seed_points, sens, shared_scale, deadline)
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
