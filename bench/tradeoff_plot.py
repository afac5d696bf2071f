"""The accuracy-versus-time picture of ``bench tradeoff``: repeated sweeps, medians, small multiples.

:func:`repeated_sweep` runs :func:`virtual.tradeoff.sweep` ``repeats`` (>= 3) times under
different seeds and merges the rows per configuration: ``seconds`` is the median wall time,
``seconds_lo``/``seconds_hi`` the fastest and slowest run, the errors are averaged, ``N`` is the
median (the adaptive rule's N varies with the seed) and the Pareto front is recomputed from the
medians (:func:`virtual.tradeoff.pareto_front`), so one noisy run does not decide it.

:func:`plot_small_multiples` draws one log-log panel per collector (goniophotometer) or per
strategy family (spectrophotometer), a distinct colour per configuration family, every point
labelled with its N, the timing spread as a horizontal bar, the Pareto front of the medians as a
grey step line, units on both axes, and the legend below the panels (never over data).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from bench.core.outputs import save_figure
from virtual import tradeoff

__all__ = ["repeated_sweep", "plot_small_multiples", "MIN_REPEATS"]

MIN_REPEATS = 3


def _key(r: dict[str, Any]) -> tuple:
    n = None if r["budget"] != "fixed" else int(r["N"])
    return (r["method"], r["strategy"], r["collector"], r["budget"], n)


def repeated_sweep(scene: Any, *, rays: Sequence[int] | None = None, repeats: int = MIN_REPEATS,
                   seed: int | None = None, progress: bool = False) -> list[dict[str, Any]]:
    """Rows of ``repeats`` independent sweeps merged per configuration (see the module docstring);
    ``progress`` draws a bar with an ETA over the sweeps on stderr."""
    from tqdm import tqdm

    repeats = max(int(repeats), MIN_REPEATS)
    base = int(seed if seed is not None else scene.seed)
    runs = [tradeoff.sweep(scene, rays=rays, repeats=1, seed=base + 7919 * k)
            for k in tqdm(range(repeats), disable=not progress, desc="tradeoff", unit="sweep", leave=False,
                          dynamic_ncols=True)]
    merged: dict[tuple, list[dict[str, Any]]] = {}
    for rows in runs:
        for r in rows:
            merged.setdefault(_key(r), []).append(r)
    out = []
    for rs in merged.values():
        secs = np.array([r["seconds"] for r in rs], float)
        row = dict(rs[0])
        row.update({"seconds": float(np.median(secs)), "seconds_lo": float(secs.min()), "seconds_hi": float(secs.max()),
                    "repeats": len(rs), "N": int(np.median([r["N"] for r in rs])),
                    "max_abs_error": float(np.mean([r["max_abs_error"] for r in rs])),
                    "rms_error": float(np.sqrt(np.mean([r["rms_error"] ** 2 for r in rs]))),
                    "within_bound": all(r["within_bound"] for r in rs)})
        if "saved_fraction" in row and row.get("hoeffding_N"):
            row["saved_fraction"] = 1.0 - row["N"] / row["hoeffding_N"]
        row["config"] = f"{row['method']}/{row['strategy']}/{row['collector']}/{row['budget']}/N={row['N']}"
        out.append(row)
    front = tradeoff.pareto_front([(r["seconds"], r["max_abs_error"]) for r in out])
    for r, f in zip(out, front):
        r["pareto"] = bool(f)
    return out


def _panel_of(r: dict[str, Any]) -> str:
    return f"collector {r['collector']}" if r["collector"] != "-" else (
        f"strategy {r['strategy']}" if r["strategy"] != "-" else "all configurations")


def _family(r: dict[str, Any]) -> str:
    parts = [r["method"], r["budget"]] + ([r["strategy"]] if r["strategy"] != "-" and r["collector"] != "-" else [])
    return " / ".join(parts)


def plot_small_multiples(rows: Sequence[dict[str, Any]], path: str, *, title: str = "", error_unit: str = "",
                         ) -> str:
    """The small-multiple Pareto plot (see the module docstring); returns ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        panels.setdefault(_panel_of(r), []).append(r)
    families = sorted({_family(r) for r in rows})
    colours = dict(zip(families, plt.get_cmap("tab10").colors * 3))
    n = len(panels)
    cols = min(3, n)
    nrows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 4.2 * nrows + 0.9), squeeze=False,
                             sharey=True, layout="constrained")
    unit = f" ({error_unit})" if error_unit else ""
    for ax, (name, rs) in zip(axes.flat, sorted(panels.items())):
        for fam in families:
            fr = sorted((r for r in rs if _family(r) == fam), key=lambda r: r["seconds"])
            if not fr:
                continue
            x = np.array([r["seconds"] for r in fr])
            y = np.array([max(r["max_abs_error"], 1e-16) for r in fr])
            lo = np.array([r.get("seconds_lo", r["seconds"]) for r in fr])
            hi = np.array([r.get("seconds_hi", r["seconds"]) for r in fr])
            ax.errorbar(x, y, xerr=[x - lo, hi - x], fmt="o-" if len(fr) > 1 else "o", color=colours[fam], ms=4,
                        lw=1.2, capsize=2, label=fam)
            for xi, yi, r in zip(x, y, fr):
                ax.annotate(f"N={r['N']:.3g}", (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=6,
                            color=colours[fam])
        front = sorted((r for r in rs if r["pareto"]), key=lambda r: r["seconds"])
        if front:
            ax.step([r["seconds"] for r in front], [max(r["max_abs_error"], 1e-16) for r in front], where="post",
                    color="0.4", lw=2.0, alpha=0.35)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time, median of repeats (s)")
        ax.set_ylabel(f"max |error| against the exact reference{unit}")
        ax.set_title(name, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    for ax in list(axes.flat)[n:]:
        ax.set_axis_off()
    handles, labels = [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    reps = sorted({int(r.get("repeats", 1)) for r in rows})
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 4), fontsize=8,
               title=f"configuration family; bars: fastest-slowest of {'/'.join(map(str, reps))} runs; grey step: "
                     f"Pareto front of the medians", title_fontsize=8)
    fig.suptitle(title or "accuracy versus time", fontsize=10)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
