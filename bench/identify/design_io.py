"""Inputs and outputs of a design: the prior guess of a model, and the plan file a design writes.

The prior is the model string's fixed values and the family's declared defaults, overridden by
``--prior p=value,...`` for the free parameters (each inside the bounds the model string gives
it). The written plan is an ordinary ``kind = "list"`` plan (``bench plan`` validates it and
``bench scan`` runs it on any body); a header comment and its ``description`` say how it was
designed and the interval widths the Cramer-Rao bound predicts.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import tomli_w

from bench.core.errors import InputError, SpecimenError
from bench.core.outputs import atomic_write
from bench.identify.design import PRIOR_SPREAD, Design, ModelPoint, integration_choices
from bench.identify.model_spec import ModelSpec, parse_model_spec
from bench.identify.time_model import ReadingSettings
from bench.plans import load_plan

__all__ = ["model_point", "prior_lines", "parse_prior", "parse_values", "design_table", "write_design", "widths_text", "design_inputs"]


def parse_values(text: str | None, option: str, what: str = "VALUE", positive: bool = False) -> dict[str, float]:
    """``p=number,q=number`` -> ``{p: number}``; a bad token is one line naming ``option`` and it."""
    out: dict[str, float] = {}
    for token in (t.strip() for t in (text or "").split(",")):
        if not token:
            continue
        key, eq, value = (s.strip() for s in token.partition("="))
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not eq or not key or not math.isfinite(v) or (positive and v <= 0):
            raise InputError(f"{option} token {token!r}: expected name={what} with a finite number"
                             + (" > 0" if positive else ""))
        if key in out:
            raise InputError(f"{option} token {token!r}: {key} given twice")
        out[key] = v
    return out


def parse_prior(text: str | None) -> dict[str, float]:
    """``--prior p=value,...`` -> ``{p: value}``."""
    return parse_values(text, "--prior")


def model_point(spec: ModelSpec, prior: Mapping[str, float] | None = None, spread: float = PRIOR_SPREAD) -> ModelPoint:
    """The model of a parsed model string (:class:`bench.identify.model_spec.ModelSpec`) at its
    prior guess: fixed values, declared defaults, and ``prior`` for the free parameters; a design
    averages over guess / ``spread`` .. guess x ``spread`` (:meth:`ModelPoint.prior_points`; 1: at
    the guess alone)."""
    family = spec.family
    values = {p.name: float(p.default) for p in family.parameters if not p.choices}
    values.update({k: v for k, v in spec.fixed.items()})
    free = {p.name: p for p in spec.free}
    values.update({p.name: float(p.start()) for p in spec.free})
    for k, v in (prior or {}).items():
        declared = spec.canonical(k)
        k = declared if declared is not None and declared in free else k  # an alias (albedo) names its parameter
        if k not in free:
            raise InputError(f"--prior {k}={v:g}: {k} is not a free parameter of {spec.text!r} "
                             f"(free: {', '.join(free)})")
        p = free[k]
        if not p.lo <= v <= p.hi:
            raise InputError(f"--prior {k}={v:g}: outside the model's bounds [{p.lo:g}, {p.hi:g}] for {k}")
        values[k] = float(v)
    point = ModelPoint(family, values, tuple(free), float(spread))
    try:
        point.specimen()
    except SpecimenError as exc:
        raise InputError(f"--prior: {exc}") from None
    return point


def design_inputs(model: str, prior: str | Mapping[str, float] | None = None, like: str | Path | None = None,
                  integration_s: str | Sequence[float] = "0.02",
                  spread: float | None = None) -> tuple[ModelSpec, ModelPoint, list[ReadingSettings]]:
    """The parsed model, the model at its prior and the reading settings a design chooses from,
    from ``--prior``, ``--prior-spread``, ``--like`` and ``--integration-s`` as ``bench plan --design`` /
    ``bench scan --sequential`` take them (``prior`` may also be a mapping, ``integration_s`` a sequence)."""
    spec = parse_model_spec(model)
    point = model_point(spec, parse_prior(prior) if prior is None or isinstance(prior, str) else dict(prior),
                        PRIOR_SPREAD if spread is None else spread)
    base = ReadingSettings.like(load_plan(like)) if like else ReadingSettings()
    if isinstance(integration_s, str):
        times = [float(t) for t in integration_s.split(",") if t.strip()]
    else:
        times = [float(t) for t in integration_s]
    return spec, point, integration_choices(base, times)


def as_written(values: Mapping[str, Any], labels: Mapping[str, str] | None) -> dict[str, Any]:
    """``values`` keyed by each parameter's name as the model string wrote it (``albedo`` for a
    Lambertian's ``reflectance``): a design reports the names its user gave."""
    return {(labels or {}).get(k, k): v for k, v in values.items()}


def widths_text(widths: Mapping[str, float], labels: Mapping[str, str] | None = None) -> str:
    return ", ".join(f"{k} {v:.3g}" for k, v in as_written(widths, labels).items())


def prior_lines(design: Design, prefix: str = "", labels: Mapping[str, str] | None = None) -> list[str]:
    """What the design assumed of the parameters and the widths it predicts, said plainly: the
    Cramer-Rao widths hold at the guess; the fits' widths are those at the specimen's true
    parameters, which may differ severalfold. Parameters named as written (``labels``)."""
    name = lambda k: (labels or {}).get(k, k)  # noqa: E731
    guess = ", ".join(f"{name(k)}={design.model.values[k]:g}" for k in design.model.free)
    if design.prior_points > 1:
        lines = [f"Criterion {design.criterion} averaged over {design.prior_points} parameter points of the prior "
                 f"range (pseudo-Bayesian): each free parameter from its guess / {design.model.spread:g} to its guess "
                 f"x {design.model.spread:g} (guess {guess})."]
    else:
        lines = [f"Designed at the prior guess {guess} alone."]
    lines.append(f"Predicted 95% interval widths (Cramer-Rao at the guess, 2 x 1.96 x se): "
                 f"{widths_text(design.widths, labels)}; conditional on the prior: the fits' widths may differ severalfold "
                 "when the specimen is far from it.")
    lines.append("A one-shot plan cannot correct its guess; `bench scan --sequential` with the same model re-designs "
                 "at each step's fit and is the route to the narrowest intervals far from the prior (docs/design.md).")
    if design.prior_points > 1 and design.width_range:
        lines.append("Over the prior range's points the predicted widths span "
                     + ", ".join(f"{k} {lo:.3g}..{hi:.3g}" for k, (lo, hi) in as_written(design.width_range, labels).items())
                     + ".")
    return [prefix + line for line in lines]


def design_table(design: Design, name: str, model_text: str, labels: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The plan table of a design (``kind = "list"``, points in travel order by ``bench scan``)."""
    prior = ",".join(f"{k}={v:g}" for k, v in as_written(design.model.values, labels).items())
    how = (f"averaged over the prior range (guess / {design.model.spread:g} .. x {design.model.spread:g}) "
           f"around {prior}" if design.prior_points > 1 else f"at {prior}")
    description = (f"{design.criterion}-optimal design for {model_text} {how}; "
                   f"predicted 95% interval widths (Cramer-Rao at the guess): {widths_text(design.widths, labels)}")
    return {"name": name, "kind": "list", "description": description, **design.settings.plan_table(), "order": "travel",
            "points": [[round(g.theta_i, 9), round(g.phi_i, 9), round(g.theta_r, 9), round(g.phi_r, 9)]
                       for g in design.points]}


def write_design(path: str | Path, design: Design, model_text: str, bench_name: str, body: str, candidates: int,
                 seconds: float, labels: Mapping[str, str] | None = None) -> Path:
    """Write the design as a plan file with a header saying how it was designed (parameters
    named as ``labels`` says the model string wrote them)."""
    p = Path(path)
    table = design_table(design, p.stem, model_text, labels)
    est = design.estimate
    header = [
        f"# Designed by `bench plan --design \"{model_text}\" --budget-seconds {seconds:g} --criterion {design.criterion}`",
        f"# on bench {bench_name!r} ({body} body): {len(design.points)} of {candidates} reachable candidate points,",
        f"# prior {', '.join(f'{k}={v:g}' for k, v in as_written(design.model.values, labels).items())}.",
        f"# Estimated bench time {est['seconds']:.4g} s (motion {est['motion_s']:.3g} s, acquisition "
        f"{est['acquisition_s']:.3g} s, references {est['references_s']:.3g} s) of a {seconds:g} s budget.",
        *prior_lines(design, "# ", labels),
    ]
    text = "\n".join(header) + "\n" + tomli_w.dumps(table)
    atomic_write(p, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return p
