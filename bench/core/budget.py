"""GUM uncertainty budget of a calibrated reading, and the covariance of a run's readings.

The measurement model of one calibrated reading (one wavelength of one point; see
:mod:`bench.core.calibration`) with every input quantity the bench description declares::

    f = (S + e_read - D) / t / W * R_w / pi * cos(theta_w) / cos(theta_r)
        * (1 + d_drift) * (1 + d_nonlinearity) * (1 + d_aperture)
        + sum over axes a of  c_a * d_a

(with repeated whites the drift is estimated and corrected for: ``(1 + d_drift)`` becomes
``1 / (1 + d_drift)``, ``d_drift = delta * k``, see the table and below).

======================================  ====  ==========================================  =============
input (component name)                  type  standard uncertainty                        shared by
======================================  ====  ==========================================  =============
``S`` counting noise                    A     shot part of the reading's std (counts)     --
``e_read`` read noise                   A     ``[instrument] read_noise / sqrt(averages)``  --
``D`` dark reading                      A     the dark reading's std (counts)             readings using that dark
``W`` white reference reading           A     std of the dark-corrected white rate        the run, per wavelength
``R_w`` white standard certificate      B     ``[white] uncertainty``                     the whole run
``d_drift`` lamp drift                  B     ``[instrument] lamp_drift * k`` (k-th lit      --
                                              reading since the white)
``d_drift`` lamp drift (repeated        A     ``k * u(delta)``, ``k = m - (N-1)/2`` lit       the run
whites: estimate ``delta * k``)               readings since the repeats' centroid
``d_nonlinearity`` nonlinearity         B     ``[uncertainty] nonlinearity`` (relative)   --
``d_aperture`` detector solid angle     B     ``[uncertainty] aperture`` (relative)       --
``d_a`` positioning <axis>              B     ``[instrument] positioning_error_deg`` (deg)  --
======================================  ====  ==========================================  =============

An input is in the budget when the description declares it (or, for the dark, when the plan
takes darks; for the Type A lamp drift, when the plan takes repeated whites); so every body of
one description gives budgets of the same components.

Lamp drift from repeated whites (a plan's ``white = "repeated"``, :mod:`bench.core.calibration`):
the ``N`` white readings give ``delta``, the lamp's relative drift per lit reading, with its
standard error ``u(delta)`` by least squares (Type A, ``N - 2`` degrees of freedom, not carried
into ``k``). The reading, the ``m``-th lit reading since the first white, is *corrected* for it
(GUM 3.2.4: correct for recognised systematic effects): ``d_drift = delta k`` is the estimate,
the model divides by ``1 + d_drift``, and the component's standard uncertainty is ``k u(delta)``
(sensitivity ``-f / (1 + d_drift)``). The Type A evaluation *replaces* a declared ``[instrument]
lamp_drift`` (Type B, uncorrected): the estimate is knowledge of this run's lamp. ``delta`` is
one quantity for the whole run, so the component is shared (``"run"``): two readings covary by
``c_i k_i c_j k_j u(delta)^2``, as the white certificate's term. Runs with one white
(``white = "once"``) are calibrated and budgeted as before.

The sensitivity of a component is the model's partial derivative at the estimates (``uncertainties``
differentiates the model), except for positioning, whose slope ``c_a`` comes from the caller
(the specimen model's slope, or the calibration's own cosine). Contribution ``|c| u``.

* ``linear`` (GUM law of propagation): ``u_c^2 = sum contribution^2`` (the inputs of one
  reading are independent), ``U = k u_c``.
* ``mc`` (GUM Supplement 1): the same model evaluated on ``mc_samples`` draws of the inputs
  (normal, numpy PCG64 from a fixed seed); ``u_c`` the draws' standard deviation, ``U`` half the
  probabilistically symmetric interval of coverage ``erf(k / sqrt 2)``, ``k = U / u_c``.

Between readings, the inputs marked shared are one quantity: :func:`readings_and_covariance`
builds the run's full covariance (``cov_ij = sum_s c_is c_js u_s^2`` over shared inputs, the
white standard's term once for the whole run) with ``uncertainties``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bench.core.errors import ConfigError
from bench.core.schemas import UncertaintyTable, validate_document

__all__ = ["Input", "Component", "Budget", "UncertaintyTable", "uncertainty_table", "declared", "reading_inputs",
           "calibrated_value", "evaluate_budget", "calibration_budgets", "cosine_slopes", "linear_budget", "mc_budget", "readings_and_covariance",
           "budget_summary", "budget_covariance", "COMPONENT_KEYS", "AXES"]

#: the keys of one component in ``bench show --json`` and the store
COMPONENT_KEYS = ("name", "type", "standard_uncertainty", "sensitivity", "contribution")
#: the goniometer axes a positioning component may be declared for
AXES = ("theta_i", "phi_i", "theta_r", "phi_r")

COUNTING, READ_NOISE, DARK, WHITE_READING = "counting noise", "read noise", "dark reading", "white reference reading"
WHITE_CERTIFICATE, LAMP_DRIFT = "white standard certificate", "lamp drift"
NONLINEARITY, APERTURE = "nonlinearity", "detector solid angle"


def positioning(axis: str) -> str:
    return f"positioning {axis}"


@dataclass(frozen=True)
class Input:
    """An input quantity of the measurement model: estimate, standard uncertainty, GUM type, and
    ``shared``: readings whose inputs have the same name and ``shared`` key share the quantity."""

    name: str
    type: str
    value: float
    standard_uncertainty: float
    shared: str | None = None


@dataclass(frozen=True)
class Component:
    """One line of a budget (``sensitivity`` signed, ``contribution = |sensitivity| u``)."""

    name: str
    type: str
    standard_uncertainty: float
    sensitivity: float
    contribution: float
    shared: str | None = None

    def as_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in COMPONENT_KEYS}
        if self.shared is not None:
            d["shared"] = self.shared
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Component":
        return cls(str(d["name"]), str(d["type"]), float(d["standard_uncertainty"]), float(d["sensitivity"]),
                   float(d["contribution"]), d.get("shared"))


@dataclass(frozen=True)
class Budget:
    """The budget of one reading: its components, ``combined`` (u_c), ``expanded`` (U) and ``k``."""

    value: float
    components: tuple[Component, ...]
    combined: float
    expanded: float
    k: float
    method: str = "linear"

    def as_dict(self) -> dict[str, Any]:
        return {"components": [c.as_dict() for c in self.components], "combined": self.combined,
                "expanded": self.expanded, "k": self.k, "method": self.method, "value": self.value}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Budget":
        return cls(float(d.get("value", math.nan)), tuple(Component.from_dict(c) for c in d["components"]),
                   float(d["combined"]), float(d["expanded"]), float(d["k"]), str(d.get("method", "linear")))


def uncertainty_table(description: Mapping[str, Any], source: str = "bench config") -> UncertaintyTable:
    """The validated ``[uncertainty]`` table of a bench description (defaults when absent)."""
    return validate_document(UncertaintyTable, description.get("uncertainty") or {}, f"{source} [uncertainty]")


def declared(description: Mapping[str, Any]) -> dict[str, float]:
    """The budget's declared magnitudes: the ``[instrument]`` effects (what the virtual body
    simulates) and the ``[uncertainty]`` knowledge components."""
    u = uncertainty_table(description)
    # a declared [detector] carries the read noise the bodies simulate (bench.builders.detector);
    # the builders refuse it declared in both tables
    inst = {**{k: v for k, v in (description.get("detector") or {}).items() if k == "read_noise"},
            **(description.get("instrument") or {})}

    def effect(key: str) -> float:
        v = inst.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"bench config [instrument]: key {key}: expected a finite number, got {v!r}")
        return abs(float(v))

    return {"read_noise": effect("read_noise"), "positioning_deg": effect("positioning_error_deg"),
            "lamp_drift": effect("lamp_drift"), "nonlinearity": u.nonlinearity, "aperture": u.aperture}


def reading_inputs(description: Mapping[str, Any], *, signal: float, u_signal: float, averages: int,
                   dark: float | None, u_dark: float, dark_key: str | None, white_rate: float, u_white_rate: float,
                   white_rf: float, u_white_rf: float, wavelength_nm: float, lit_index: int,
                   drift: Any = None) -> list[Input]:
    """The inputs of one reading's model as the description declares them (see the module table).
    ``u_signal`` is the reading's whole std; the declared read noise is split off it. ``drift``: the
    calibration's :class:`~bench.core.calibration.LampDrift` (repeated whites), which replaces the
    declared Type B lamp drift by its Type A estimate; ``lit_index`` then counts from the first white."""
    decl = declared(description)
    u_read = decl["read_noise"] / math.sqrt(max(averages, 1))
    u_shot = math.sqrt(max(u_signal**2 - u_read**2, 0.0))
    wl = f"{wavelength_nm:g} nm"
    out = [Input(COUNTING, "A", signal, u_shot)]
    if decl["read_noise"]:
        out.append(Input(READ_NOISE, "A", 0.0, u_read))
    if dark is not None:
        out.append(Input(DARK, "A", dark, u_dark, None if dark_key is None else f"{dark_key}, {wl}"))
    out.append(Input(WHITE_READING, "A", white_rate, u_white_rate, f"run, {wl}"))
    out.append(Input(WHITE_CERTIFICATE, "B", white_rf, u_white_rf, "run"))
    if drift is not None:
        k = drift.offset(lit_index)
        out.append(Input(LAMP_DRIFT, "A", drift.per_lit_reading * k, abs(k) * drift.standard_uncertainty, "run"))
    elif decl["lamp_drift"]:
        out.append(Input(LAMP_DRIFT, "B", 0.0, decl["lamp_drift"] * max(lit_index, 0)))
    if decl["nonlinearity"]:
        out.append(Input(NONLINEARITY, "B", 0.0, decl["nonlinearity"]))
    if decl["aperture"]:
        out.append(Input(APERTURE, "B", 0.0, decl["aperture"]))
    if decl["positioning_deg"]:
        out.extend(Input(positioning(a), "B", 0.0, decl["positioning_deg"]) for a in AXES)
    return out


def calibrated_value(x: Mapping[str, Any], *, integration_s: float, cos_ratio: float,
                     slopes: Mapping[str, float], drift_corrected: bool = False) -> Any:
    """The measurement model (module docstring) on inputs ``x`` by component name: floats,
    ``uncertainties`` numbers or numpy arrays of draws alike. ``cos_ratio = cos theta_w / cos
    theta_r``; ``slopes`` the positioning sensitivities per axis (value per degree);
    ``drift_corrected``: the lamp drift is an estimate the reading is corrected for (divided by
    ``1 + d_drift``), not an uncorrected effect (times ``1 + d_drift``)."""
    net = x[COUNTING] + x.get(READ_NOISE, 0.0) - x.get(DARK, 0.0)
    f = net / integration_s / x[WHITE_READING] * x[WHITE_CERTIFICATE] / math.pi * cos_ratio
    if drift_corrected and LAMP_DRIFT in x:
        f = f / (1.0 + x[LAMP_DRIFT])
    for name in (NONLINEARITY, APERTURE) if drift_corrected else (LAMP_DRIFT, NONLINEARITY, APERTURE):
        if name in x:
            f = f * (1.0 + x[name])
    for a in AXES:
        if positioning(a) in x:
            f = f + float(slopes.get(a, 0.0)) * x[positioning(a)]
    return f


def linear_budget(inputs: Sequence[Input], model: Callable[[Mapping[str, Any]], Any], k: float = 2.0) -> Budget:
    """GUM law of propagation: sensitivities by ``uncertainties``' derivatives of ``model``."""
    from uncertainties import ufloat

    # an input known exactly (u = 0) still gets its sensitivity: a unit std does not change a derivative
    xs = {i.name: ufloat(i.value, i.standard_uncertainty or 1.0, i.name) for i in inputs}
    y = model(xs)
    comps = tuple(_component(i, float(y.derivatives.get(xs[i.name], 0.0))) for i in inputs)
    u = math.sqrt(sum(c.contribution**2 for c in comps))
    return Budget(float(y.nominal_value), comps, u, k * u, float(k), "linear")


def _component(i: Input, c: float) -> Component:
    return Component(i.name, i.type, float(i.standard_uncertainty), c, abs(c) * float(i.standard_uncertainty), i.shared)


def mc_budget(inputs: Sequence[Input], model: Callable[[Mapping[str, Any]], Any], k: float = 2.0,
              samples: int = 20_000, seed: Any = 0) -> Budget:
    """GUM Supplement 1: ``model`` on ``samples`` normal draws of the inputs (numpy PCG64 seeded by
    ``seed``, an int or a tuple spawn key); components as in :func:`linear_budget`."""
    lin = linear_budget(inputs, model, k)
    key = tuple(seed) if isinstance(seed, (tuple, list)) else (int(seed),)
    rng = np.random.default_rng(np.random.SeedSequence(key[0], spawn_key=key[1:]))
    draws = {i.name: rng.normal(i.value, i.standard_uncertainty, samples) if i.standard_uncertainty > 0
             else np.full(samples, float(i.value)) for i in inputs}
    y = np.asarray(model(draws), dtype=float)
    u = float(np.std(y, ddof=1))
    p = math.erf(k / math.sqrt(2.0))
    lo, hi = np.quantile(y, [(1.0 - p) / 2.0, (1.0 + p) / 2.0])
    big_u = float(hi - lo) / 2.0
    return Budget(lin.value, lin.components, u, big_u, big_u / u if u > 0 else float(k), "mc")


def evaluate_budget(inputs: Sequence[Input], model: Callable[[Mapping[str, Any]], Any], table: UncertaintyTable,
                    seed_key: Sequence[int] = ()) -> Budget:
    """The budget by the description's ``method`` (``linear`` or ``mc`` with its seed and samples;
    ``seed_key`` keys the reading's stream apart, so its draws do not depend on the order)."""
    if table.method == "mc":
        return mc_budget(inputs, model, table.k, table.mc_samples, (table.mc_seed, *seed_key))
    return linear_budget(inputs, model, table.k)


def readings_and_covariance(record: Any) -> tuple[np.ndarray, np.ndarray]:
    """The values of a record's readings and their full covariance matrix, one row per table row
    in table order.

    ``record`` is a :class:`~bench.core.records.BSDFRecord` (or a DataFrame) with ``value``,
    ``std`` and, for calibrated scans, an ``uncertainty_budget`` column (dicts or JSON, as
    :meth:`Budget.as_dict`). Readings with a budget are correlated through their shared inputs
    (the white standard's term enters once for the run); a reading without one contributes
    ``std^2`` on the diagonal only (NaN where it has no finite std: no uncertainty to fit with).
    """
    t = getattr(record, "table", record)
    values = t["value"].to_numpy(float)
    std = t["std"].to_numpy(float) if "std" in t else np.full(values.shape, np.nan)
    budgets = [json.loads(b) if isinstance(b, str) else b
               for b in (t["uncertainty_budget"] if "uncertainty_budget" in t else [None] * len(values))]
    cov = budget_covariance(budgets, std)
    plain = np.array([not isinstance(b, Mapping) for b in budgets], dtype=bool)
    missing = plain & ~np.isfinite(std)
    cov[missing, missing] = np.nan
    return values, cov


def budget_covariance(budgets: Sequence[Mapping[str, Any] | None], std: np.ndarray) -> np.ndarray:
    """Covariance of readings from their budgets (``std`` for those without one): each reading is
    linearised as ``y = sum_s c_s u_s X_s + e`` over its shared inputs ``X_s`` (one
    ``uncertainties`` variable per shared input of the run, unit variance) and an independent
    rest ``e`` (its other components); ``uncertainties.covariance_matrix`` does the algebra."""
    import warnings

    from uncertainties import covariance_matrix, ufloat

    def independent(s: float) -> Any:
        with warnings.catch_warnings():  # an exactly known rest (u = 0) is fine here: no derivative is taken
            warnings.simplefilter("ignore", UserWarning)
            return ufloat(0.0, s)

    shared: dict[tuple[str, str], Any] = {}
    ys = []
    for j, b in enumerate(budgets):
        if not isinstance(b, Mapping) or not b.get("components"):
            ys.append(independent(float(std[j]) if np.isfinite(std[j]) else 0.0))
            continue
        comps = [Component.from_dict(c) for c in b["components"]]
        own2 = max(float(b["combined"]) ** 2 - sum(c.contribution**2 for c in comps if c.shared is not None), 0.0)
        y = independent(math.sqrt(own2))
        for c in comps:
            if c.shared is None or c.contribution == 0.0:
                continue
            x = shared.setdefault((c.name, c.shared), ufloat(0.0, 1.0, f"{c.name} ({c.shared})"))
            y = y + c.sensitivity * c.standard_uncertainty * x
        ys.append(y)
    if not ys:
        return np.zeros((0, 0))
    return np.asarray(covariance_matrix(ys), dtype=float)


def calibration_budgets(cal: Any, reading: Any, geometry: Any, dark: Any, description: Mapping[str, Any], *,
                        lit_index: int, slopes: Sequence[Mapping[str, float]] | None = None,
                        seed_key: Sequence[int] = (), dark_key: str = "dark") -> list[Budget | None]:
    """The budget of each pixel of ``reading`` calibrated by ``cal`` (a
    :class:`~bench.core.calibration.Calibration`) at ``geometry`` with ``dark``; None where the
    calibration masks the pixel. ``lit_index``: the reading is the k-th lit one since the white;
    ``slopes[i]``: pixel i's positioning sensitivities (default: the calibration's cosine only);
    ``dark_key``: which dark this is (readings of a run with the same key share its noise). With
    repeated whites, ``lit_index`` counts from the first white and the value is drift-corrected."""
    from bench.core.calibration import reading_std

    table = uncertainty_table(description)
    drift = getattr(cal, "lamp_drift", None)
    c = cal.apply(reading, geometry, dark, lit_index=lit_index)
    ref, u_ref, _ = cal.reference_rate()
    wl = np.asarray(reading.wavelengths, dtype=float)
    rf_w = cal.standard.rf(wl)
    u_sig = reading_std(reading)
    d = dark.signal if dark is not None else None
    u_d = reading_std(dark) if dark is not None else None
    cos_r = math.cos(math.radians(geometry.theta_r))
    cos_ratio = abs(math.cos(math.radians(cal.standard.geometry.theta_r))) / abs(cos_r)
    out: list[Budget | None] = []
    for i in range(wl.size):
        if c.mask_reason[i]:
            out.append(None)
            continue
        inputs = reading_inputs(description, signal=float(reading.signal[i]), u_signal=float(u_sig[i]),
                                averages=reading.averages, dark=None if d is None else float(d[i]),
                                u_dark=0.0 if u_d is None else float(u_d[i]), dark_key=dark_key,
                                white_rate=float(ref[i]), u_white_rate=float(u_ref[i]), white_rf=float(rf_w[i]),
                                u_white_rf=float(cal.standard.uncertainty), wavelength_nm=float(wl[i]),
                                lit_index=lit_index, drift=drift)
        s = slopes[i] if slopes is not None else cosine_slopes(float(c.brdf[i]), geometry.theta_r)
        model = _bound_model(reading.integration_s, cos_ratio, s, drift is not None)
        out.append(evaluate_budget(inputs, model, table, (*seed_key, i)))
    return out


def cosine_slopes(value: float, theta_r_deg: float) -> dict[str, float]:
    """Positioning sensitivities of a specimen of unknown angular shape: the calibration divides by
    ``cos theta_r`` at the read-back angle while the signal follows the true one, so
    ``df/dtheta_r = -f tan(theta_r)`` (per degree); the other axes 0."""
    return {"theta_r": -value * math.tan(math.radians(theta_r_deg)) * math.pi / 180.0}


def _bound_model(integration_s: float, cos_ratio: float, slopes: Mapping[str, float], drift_corrected: bool = False):
    def model(x: Mapping[str, Any]) -> Any:
        return calibrated_value(x, integration_s=integration_s, cos_ratio=cos_ratio, slopes=slopes,
                                drift_corrected=drift_corrected)
    return model


def budget_summary(budgets: Sequence[Any]) -> dict[str, Any] | None:
    """A record's budgets in one table (what the compare report shows): per component, in the
    order met, its type, what it is shared by, and over the readings the median standard
    uncertainty, sensitivity and contribution, and the median and largest contribution relative
    to the value (%); plus the median u_c relative to the value, ``k`` and the method(s). None
    when no reading has a budget."""
    parsed = [json.loads(b) if isinstance(b, str) else b for b in budgets]
    parsed = [b for b in parsed if isinstance(b, Mapping) and b.get("components")]
    if not parsed:
        return None
    rows: dict[str, dict[str, Any]] = {}
    for b in parsed:
        v = abs(float(b.get("value", math.nan)))
        for c in b["components"]:
            r = rows.setdefault(c["name"], {"name": c["name"], "type": c["type"], "shared": c.get("shared") is not None,
                                            "u": [], "c": [], "contribution": [], "rel": []})
            r["u"].append(float(c["standard_uncertainty"]))
            r["c"].append(float(c["sensitivity"]))
            r["contribution"].append(float(c["contribution"]))
            r["rel"].append(100.0 * float(c["contribution"]) / v if v > 0 else math.nan)
    comps = [{"name": r["name"], "type": r["type"], "shared": r["shared"], "n_readings": len(r["u"]),
              "standard_uncertainty": float(np.median(r["u"])), "sensitivity": float(np.median(r["c"])),
              "contribution": float(np.median(r["contribution"])), "relative_pct": float(np.nanmedian(r["rel"])),
              "max_relative_pct": float(np.nanmax(r["rel"]))} for r in rows.values()]
    rel_uc = [100.0 * float(b["combined"]) / abs(float(b["value"])) for b in parsed if float(b.get("value", 0.0))]
    return {"n_readings": len(parsed), "components": comps,
            "combined_relative_pct": float(np.median(rel_uc)) if rel_uc else None,
            "k": sorted({float(b["k"]) for b in parsed}), "method": sorted({str(b.get("method", "linear")) for b in parsed})}
