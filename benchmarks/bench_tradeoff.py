"""Accuracy versus time on the fixture scenes: the `bench tradeoff` tables, with the
Pareto-optimal configurations and the plots written next to the working directory."""

from __future__ import annotations

from pathlib import Path

from benchmarks.common import table
from virtual.scene import load_scene
from virtual.tradeoff import plot_tradeoff, sweep

SCENES = Path(__file__).resolve().parent.parent / "fixtures" / "scenes"


def run(out_dir: str = "benchmark-out", repeats: int = 3) -> str:
    Path(out_dir).mkdir(exist_ok=True)
    parts = []
    for name in ("lambert-bare", "conical-grazing", "gonio-ggx"):
        sc = load_scene(SCENES / f"{name}.toml")
        rows = sweep(sc, repeats=repeats)
        png = plot_tradeoff(rows, str(Path(out_dir) / f"tradeoff-{name}.png"), title=name)
        parts.append(table(f"{name}: error vs time ({repeats} seeded runs per row; * = Pareto front; plot {png})",
                           ["strategy", "collector", "budget", "method", "N", "seconds", "max_abs_error",
                            "predicted_max", "predicted_bound", "rms_error", "predicted_rms", "pareto"],
                           [[r["strategy"], r["collector"], r["budget"], r["method"], r["N"], r["seconds"],
                             r["max_abs_error"], r["predicted_max"], r["predicted_bound"], r["rms_error"],
                             r["predicted_rms"], "*" if r["pareto"] else ""] for r in rows]))
    return "\n\n".join(parts)


if __name__ == "__main__":
    print(run())
