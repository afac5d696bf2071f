"""Accuracy versus time: sweep a scene's knobs, measure error against an exact reference and wall
time, and find the Pareto front.

For a simulated scene (:class:`virtual.scene.Scene`) the sweep covers

* ray count ``N`` (``budget = "fixed"``),
* sampling strategy of a conical beam's disks: ``rejection`` (eq. 3.3) and ``polar`` (eq. 3.4)
  in the kernel, ``jittered`` and ``sobol`` as precomputed points (spectrophotometer scenes
  without per-ray effects); for a goniophotometer the strategy also picks the kernel shape
  (rejection: ray by ray; polar: the vectorized block kernel, for the models it serves),
* collector subdivision (goniophotometer): equal angle / equal solid angle / equal PSA,
* budget rule: ``eq3.5`` (eq. 3.5, or 3.12 with ``m`` patches, at the scene's ``v`` and
  ``delta``) against ``adaptive`` (:func:`virtual.bounds.run_adaptive`, same guarantee),
* the exact fast path (one multinomial over quadrature probabilities; its time includes the
  quadrature).

Each row has the error against the scene's reference (:meth:`Scene.reference`: quadrature of
the model over every patch, or a closed form), the wall time, and the error predicted by theory:
``predicted_bound`` -- Hoeffding with a union bound over the ``m`` estimated columns,
``sqrt(ln(2m/delta) / (2N))`` in probability, scaled to the reading's units (plus ``z u`` for
declared instrument noise), which ``max_abs_error`` exceeds with probability ``<= delta`` --
``predicted_rms``, ``sqrt(mean_j p_j (1 - p_j) / N)`` likewise scaled, and ``predicted_max``, the
variance-aware (normal) value of the max error, ``max_j z_{delta/(2m)} sqrt(p_j (1 - p_j) / N)``
(Hoeffding's bound is loose for small patch probabilities; this one is what to expect).

A ``physical`` scene is not simulated: its scan duration against angular step and averaging
is the application's (:mod:`bench.tradeoff_physical`, which needs plans).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np

from bench.core.errors import InputError
from bench.core.outputs import save_figure
from virtual.collector import parse_collector
from virtual.scene import Scene
from virtual.bounds import adaptive_plan, hoeffding_rays, run_adaptive
from virtual.effects import spectro_point_counts
from virtual.engine import measurement_seed
from virtual.sampling import sample_disk

__all__ = ["sweep", "pareto_front", "plot_tradeoff", "ROW_KEYS",
           "DEFAULT_RAYS", "STRATEGIES", "BUDGETS"]

ROW_KEYS = ("config", "strategy", "collector", "budget", "method", "N", "seconds", "max_abs_error", "rms_error",
            "predicted_bound", "predicted_rms", "predicted_max", "within_bound", "pareto")
DEFAULT_RAYS = (10_000, 100_000, 1_000_000)
STRATEGIES = ("rejection", "polar", "jittered", "sobol")
BUDGETS = ("fixed", "eq3.5", "adaptive")


# --- helpers ------------------------------------------------------------------------------------


def _scales(scene: Scene) -> np.ndarray:
    """Per column: the factor from a per-ray probability to the reading's unit."""
    if scene.instrument == "goniophotometer":
        psa = np.asarray(scene.collector.psa)
        if scene.effects.aperture is not None:
            psa = np.concatenate([psa, scene.effects.aperture.psa()])
        return 1.0 / psa
    sph = scene.effects.sphere
    if sph is not None and scene.observable == "reflectance":
        return np.array([sph.reference_reflectance / sph.reference_efficiency()])
    return np.array([1.0])


def _active(ref: np.ndarray, values: np.ndarray) -> np.ndarray:
    return (np.abs(ref) > 0) | (np.abs(values) > 0)


def _errors(values: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    act = _active(ref, values)
    d = (values - ref)[act] if act.any() else np.zeros(1)
    return float(np.max(np.abs(d))), float(np.sqrt(np.mean(d * d)))


def _predicted_max(scene: Scene, ref: np.ndarray, n: int) -> float:
    """Variance-aware prediction of the max error: ``z_{delta/(2m)} sqrt(p (1-p) / N)`` scaled,
    maximised over the columns (normal approximation; tight where Hoeffding is loose, i.e. for
    small patch probabilities)."""
    from scipy.stats import norm

    scales = np.broadcast_to(_scales(scene), ref.shape)
    p = np.clip(ref / scales, 0.0, 1.0)
    act = np.ones(ref.shape, dtype=bool) if scene.instrument == "spectrophotometer" else _active(ref, ref)
    m = max(1, int(act.sum()))
    z = float(norm.isf(scene.delta / (2.0 * m)))
    return float(np.max((z * np.sqrt(p * (1 - p) / max(n, 1)) * scales)[act]))


def _predicted(scene: Scene, ref: np.ndarray, n: int) -> tuple[float, float]:
    """(Hoeffding/union bound on the max error, expected RMS error) for ``n`` rays."""
    from scipy.stats import norm

    scales = _scales(scene)
    p = np.clip(ref / scales, 0.0, 1.0)
    act = np.ones(ref.shape, dtype=bool) if scene.instrument == "spectrophotometer" else _active(ref, ref)
    m = max(1, int(act.sum()))
    v = math.sqrt(math.log(2.0 * m / scene.delta) / (2.0 * max(n, 1)))
    bound = float(np.max(np.broadcast_to(scales, ref.shape)[act]) * v)
    rms = float(np.sqrt(np.mean((p * (1 - p) / max(n, 1) * np.broadcast_to(scales, ref.shape) ** 2)[act])))
    if scene.effects.noise is not None:
        u = scene.effects.noise.uncertainty
        rel = scene.effects.noise.relative if scene.effects.noise.relative is not None \
            else scene.instrument == "goniophotometer"
        uu = u * (np.abs(ref[act]).max() if rel else 1.0)
        z = float(norm.isf(scene.delta / 2.0 / m))
        bound += z * uu
        rms = math.hypot(rms, u * (math.sqrt(np.mean(ref[act] ** 2)) if rel else 1.0))
    return bound, rms


def _disk_points(n: int, strategy: str, r1: float, r2: float, seed: int) -> np.ndarray:
    """(n, 4): emitter point (x1, y1) and specimen point (x2, y2) by ``strategy``."""

    rng = np.random.default_rng(seed)
    if strategy == "sobol":
        from scipy.stats import qmc

        m = max(0, math.ceil(math.log2(max(n, 1))))
        u = qmc.Sobol(d=4, scramble=True, seed=rng).random_base2(m)[:n]
        out = np.empty((n, 4))
        for i, r in ((0, r1), (2, r2)):
            phi = 2.0 * math.pi * u[:, i]
            rho = r * np.sqrt(u[:, i + 1])
            out[:, i], out[:, i + 1] = rho * np.cos(phi), rho * np.sin(phi)
        return out
    return np.column_stack([sample_disk(n, r1, strategy, rng), sample_disk(n, r2, strategy, rng)])


def _run_points(scene: Scene, n: int, strategy: str, seed: int) -> np.ndarray:
    """Readings of a spectrophotometer scene whose conical beam uses precomputed disk points."""

    b = scene.beam
    args = b.kernel_args(*scene.incidence)
    counts = []
    for i, w in enumerate(scene.wavelengths):
        pts = _disk_points(n, strategy, b.emitter_radius_mm, b.specimen_radius_mm, seed * 1009 + i)
        c = spectro_point_counts(scene.specimen.model, scene.specimen.params(w), args, pts,
                                 measurement_seed(seed, int(round(w * 1000))))
        counts.append(np.concatenate([c, [0, 0]]).astype(np.int64))
    values, _, _ = scene._readings(counts, n, seed)
    return values


def _tracked(scene: Scene) -> np.ndarray:
    """Columns of the kernel counts the adaptive rule watches (the estimated probabilities)."""
    if scene.instrument == "goniophotometer":
        col = scene.collector
        m = col.n_bins if scene.specimen.transmits(float(scene.wavelengths[0])) else col.n_patches
        cols = list(range(m))
        if scene.effects.aperture is not None:
            cols += [col.n_bins + 2 + j for j in range(len(scene.effects.aperture.views))]
        return np.array(cols)
    return np.array([0])


def _spectro_count(scene: Scene, c: np.ndarray) -> int:
    refl, trans, _, missed, cone, detected, stray = (int(x) for x in c[:7])
    if scene.observable == "missed":
        return missed
    if scene.observable == "transmittance":
        return trans
    if scene.effects.sphere is not None:
        return detected + stray
    excl = cone if scene.effects.gloss_trap is not None and scene.effects.gloss_trap.specular == "excluded" else 0
    return refl - excl + stray


def _adaptive(scene: Scene, seed: int) -> tuple[int, np.ndarray, Any]:
    """Run the adaptive rule on the scene (first wavelength); returns (N, values, result)."""

    sc = replace(scene, wavelengths=scene.wavelengths[:1])
    cols = _tracked(sc)
    calls = [0]

    def draw(n_new: int) -> np.ndarray:
        calls[0] += 1
        r = sc.run(rays=n_new, seed=seed * 7919 + calls[0])
        c = r.counts[0]
        if sc.instrument == "spectrophotometer":
            return np.array([_spectro_count(sc, c)], dtype=np.int64)
        return c[cols]

    res = run_adaptive(draw, scene.uncertainty, scene.delta, patches=len(cols))
    scales = _scales(sc)
    if sc.instrument == "spectrophotometer":
        values = res.estimate * scales
    else:
        values = np.zeros(len(scales))
        idx = np.where(cols >= sc.collector.n_bins, cols - 2, cols)
        values[idx] = res.estimate * scales[idx]
    return res.N, values[None, :], res


def _timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


# --- the sweep ----------------------------------------------------------------------------------


def sweep(scene: Scene, rays: Sequence[int] | None = None, strategies: Sequence[str] | None = None,
          collectors: Sequence[str] | None = None, budgets: Sequence[str] | None = None,
          fast: bool | None = None, repeats: int | None = None, seed: int | None = None) -> list[dict[str, Any]]:
    """Rows of the accuracy-versus-time study (keys :data:`ROW_KEYS`); unset arguments come from
    the scene's ``[tradeoff]`` table, then from the defaults.

    ``seconds`` is the median and the errors the mean over ``repeats`` seeded runs (the
    maximum error of each run, then averaged). ``within_bound`` says whether every run's
    maximum error stayed below ``predicted_bound``.

    Raises
    ------
    InputError
        For a physical scene (use :func:`bench.tradeoff_physical.physical_sweep`), an unknown strategy or budget, or a
        scene without a reference.
    """
    if scene.instrument == "physical":
        raise InputError("a physical scene has no simulation to sweep: use bench.tradeoff_physical.physical_sweep")
    t = scene.tradeoff
    rays = [int(float(x)) for x in (rays if rays is not None else t.get("rays", DEFAULT_RAYS))]
    budgets = list(budgets if budgets is not None else t.get("budgets", BUDGETS))
    repeats = int(repeats if repeats is not None else t.get("repeats", 1))
    seed = int(seed if seed is not None else scene.seed)
    for b in budgets:
        if b not in BUDGETS:
            raise InputError(f"unknown budget rule {b!r}; known: {', '.join(BUDGETS)}")
    if scene.beam.kind == "conical":
        default_strats = ["rejection", "polar"] + (["jittered", "sobol"] if _points_ok(scene) else [])
    else:
        default_strats = ["-"]
    strategies = list(strategies if strategies is not None else t.get("strategies", default_strats))
    for s in strategies:
        if s not in STRATEGIES and s != "-":
            raise InputError(f"unknown sampling strategy {s!r}; known: {', '.join(STRATEGIES)}")
        if s in ("jittered", "sobol") and not _points_ok(scene):
            raise InputError(f"strategy {s!r} needs a conical-beam spectrophotometer scene without per-ray effects")
    if scene.instrument == "goniophotometer":
        cols = list(collectors if collectors is not None else t.get("collectors", [str(scene.collector)]))
    else:
        cols = ["-"]
    fast = bool(fast if fast is not None else t.get("fast", True))
    rows: list[dict[str, Any]] = []
    scene.run(rays=1000)  # compile / load kernel caches (and scipy) outside the timings
    for s in strategies:
        if s in ("jittered", "sobol"):
            _run_points(scene, 1024, s, seed)
    if "adaptive" in budgets:  # the plan is pure and cached: certify it outside the timings

        adaptive_plan(scene.uncertainty, scene.delta, len(_tracked(scene)))
    for col_spec in cols:
        sc = scene if col_spec == "-" else replace(scene, collector=parse_collector(col_spec))
        ref, exact = sc.reference()
        if not exact:
            raise InputError(f"scene {scene.name!r} has no exact reference (conical beam on a non-Lambertian "
                             f"specimen, near-field detectors or a sphere on a non-Lambertian specimen)")
        col_name = str(sc.collector) if sc.instrument == "goniophotometer" else "-"
        for strat in strategies:
            st = sc
            if strat in ("rejection", "polar") and sc.beam.kind == "conical":
                st = replace(sc, beam=replace(sc.beam, disk_sampling=strat))
            if "fixed" in budgets:
                for n in rays:
                    rows.append(_row(st, ref, n, strat, col_name, "fixed", "rays", repeats, seed,
                                     lambda s, _st=st, _n=n, _strat=strat: _one(_st, _n, _strat, s)))
            if "eq3.5" in budgets:

                m = sc.collector.n_patches if sc.instrument == "goniophotometer" else 1
                n = hoeffding_rays(sc.uncertainty, sc.delta, m)
                rows.append(_row(st, ref, n, strat, col_name, "eq3.5", "rays", repeats, seed,
                                 lambda s, _st=st, _n=n, _strat=strat: _one(_st, _n, _strat, s)))
            if "adaptive" in budgets and strat in ("rejection", "polar", "-"):
                rows.append(_adaptive_row(st, ref, strat, col_name, repeats, seed))
        if fast and sc.fast_path_possible():
            for n in rays:
                rows.append(_row(sc, ref, n, "-", col_name, "fixed", "fast", repeats, seed,
                                 lambda s, _sc=sc, _n=n: _sc.run(rays=_n, seed=s, method="fast").values))
    front = pareto_front([(r["seconds"], r["max_abs_error"]) for r in rows])
    for i, r in enumerate(rows):
        r["pareto"] = bool(front[i])
    return rows


def _points_ok(scene: Scene) -> bool:
    return (scene.instrument == "spectrophotometer" and scene.beam.kind == "conical" and scene.kernel_flags() == 0
            and scene.effects.gloss_trap is None)


def _one(scene: Scene, n: int, strategy: str, seed: int) -> np.ndarray:
    if strategy in ("jittered", "sobol"):
        return _run_points(scene, n, strategy, seed)
    return scene.run(rays=n, seed=seed, method="rays" if scene.method == "auto" else None).values


def _row(scene: Scene, ref: np.ndarray, n: int, strategy: str, collector: str, budget: str, method: str,
         repeats: int, seed: int, fn: Callable[[int], np.ndarray]) -> dict[str, Any]:
    secs, maxes, rmss = [], [], []
    for k in range(repeats):
        s, values = _timed(lambda: fn(seed + 1000 * k + 1))
        mx, rm = _errors(values, ref)
        secs.append(s)
        maxes.append(mx)
        rmss.append(rm)
    bound, prms = _predicted(scene, ref, n)
    return {"config": f"{method}/{strategy}/{collector}/{budget}/N={n}", "strategy": strategy, "collector": collector,
            "budget": budget, "method": method, "N": int(n), "seconds": float(np.median(secs)),
            "max_abs_error": float(np.mean(maxes)), "rms_error": float(np.sqrt(np.mean(np.square(rmss)))),
            "predicted_bound": bound, "predicted_rms": prms, "predicted_max": _predicted_max(scene, ref, n),
            "within_bound": bool(max(maxes) <= bound)}


def _adaptive_row(scene: Scene, ref: np.ndarray, strategy: str, collector: str, repeats: int,
                  seed: int) -> dict[str, Any]:
    secs, maxes, rmss, ns = [], [], [], []
    hoeff = 0
    for k in range(repeats):
        s, (n, values, res) = _timed(lambda: _adaptive(scene, seed + 1000 * k + 1))
        mx, rm = _errors(values, ref[:1])
        secs.append(s)
        maxes.append(mx)
        rmss.append(rm)
        ns.append(n)
        hoeff = res.hoeffding_N
    scales = _scales(scene)
    cols = _tracked(scene)
    idx = np.where(cols >= scene.collector.n_bins, cols - 2, cols) if scene.instrument == "goniophotometer" else cols
    bound = float(scene.uncertainty * np.max(scales[idx]))
    n_med = int(np.median(ns))
    _, prms = _predicted(scene, ref, n_med)
    return {"config": f"rays/{strategy}/{collector}/adaptive/N={n_med}", "strategy": strategy, "collector": collector,
            "budget": "adaptive", "method": "rays", "N": n_med, "seconds": float(np.median(secs)),
            "max_abs_error": float(np.mean(maxes)), "rms_error": float(np.sqrt(np.mean(np.square(rmss)))),
            "predicted_bound": bound, "predicted_rms": prms, "predicted_max": bound,
            "within_bound": bool(max(maxes) <= bound), "hoeffding_N": int(hoeff), "saved_fraction": 1.0 - n_med / hoeff}


def pareto_front(points: Sequence[tuple[float, float]]) -> np.ndarray:
    """Boolean mask of the points (time, error) that no other point beats in both (ties kept)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    keep = np.ones(len(pts), dtype=bool)
    for i, (t, e) in enumerate(pts):
        dominated = (pts[:, 0] <= t) & (pts[:, 1] <= e) & ((pts[:, 0] < t) | (pts[:, 1] < e))
        keep[i] = not dominated.any()
    return keep


# --- plots --------------------------------------------------------------------------------------


def plot_tradeoff(rows: Sequence[dict[str, Any]], path: str, title: str = "") -> str:
    """Error against time on log-log axes, one marker per configuration family, the Pareto
    front as a step line; written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    families: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        key = f"{r['method']} {r['strategy']} {r['collector']} {r['budget']}".replace(" -", "")
        families.setdefault(key, []).append(r)
    markers = "osD^v<>phX*"
    bound_labelled = False
    for i, (key, rs) in enumerate(sorted(families.items())):
        rs = sorted(rs, key=lambda r: r["seconds"])
        line, = ax.loglog([r["seconds"] for r in rs], [max(r["max_abs_error"], 1e-16) for r in rs],
                          marker=markers[i % len(markers)], linestyle="-" if len(rs) > 1 else "none", label=key,
                          alpha=0.8)
        fixed = [r for r in rs if r["budget"] == "fixed" and r["method"] == "rays"]
        if len(fixed) > 1:  # each configuration's own bound, in its colour
            ax.loglog([r["seconds"] for r in fixed], [r["predicted_bound"] for r in fixed], ":",
                      color=line.get_color(), linewidth=1,
                      label=None if bound_labelled else "predicted bound (Hoeffding), dotted per configuration")
            bound_labelled = True
    front = sorted((r for r in rows if r["pareto"]), key=lambda r: r["seconds"])
    if front:
        ax.step([r["seconds"] for r in front], [max(r["max_abs_error"], 1e-16) for r in front], where="post",
                color="k", linewidth=2.0, alpha=0.4, label="Pareto front")
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("max |error| against the exact reference")
    ax.set_title(title or "accuracy versus time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path
