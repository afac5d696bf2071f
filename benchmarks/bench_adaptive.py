"""Adaptive ray budgets against eq. 3.5: rays used by the adaptive stopping rule of the
CLI measurements (adaptive_measure) for several reflectances, same (v, delta) guarantee."""

from __future__ import annotations

import time

import numpy as np

from benchmarks.common import table
from bench.adaptive import adaptive_measure
from virtual.bounds import hoeffding_rays
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.spectrophotometer import VirtualSpectrophotometer


def run(v: float = 0.005, delta: float = 0.01, seeds: int = 20) -> str:
    eq35 = hoeffding_rays(v, delta)
    rows = []
    for r in (0.01, 0.05, 0.2, 0.5, 0.8, 0.95):
        used, secs = [], []
        for seed in range(seeds):
            sp = VirtualSpectrophotometer(f"lambert:reflectance={r}", rays=10, seed=seed)
            t0 = time.perf_counter()
            res = adaptive_measure(sp, v, delta, geometry="8/d", wavelengths="550")
            secs.append(time.perf_counter() - t0)
            used.append(res["N"])
        u = np.array(used)
        mark = "yes" if u.max() <= eq35 / 4 else "no"
        rows.append([r, eq35, int(np.median(u)), int(u.max()), float(np.median(u)) / eq35, mark,
                     float(np.median(secs))])
    out = table(f"Adaptive stopping vs eq. 3.5 (v = {v}, delta = {delta}, {seeds} seeds per row; acceptance: "
                f"R = 0.05 uses <= 1/4 of eq. 3.5)",
                ["R", "eq. 3.5 N", "adaptive N (median)", "adaptive N (max)", "median / eq. 3.5", "<= 1/4",
                 "seconds (median)"], rows)
    g_rows = []
    for spec in ("lambert:albedo=0.8", "ggx:alpha=0.2,eta=1.5,k=0"):
        g = VirtualGoniophotometer(spec, collector="equal-psa:9x36", rays=10, seed=1)
        t0 = time.perf_counter()
        res = adaptive_measure(g, 0.002, delta, theta_i=30.0)
        g_rows.append([spec, res["hoeffding_N"], res["N"], res["N"] / res["hoeffding_N"], res["mode"],
                       time.perf_counter() - t0])
    out += "\n\n" + table("Goniophotometer, 9x36 equal-PSA patches, v = 0.002 (per-patch probability), eq. 3.12",
                          ["specimen", "eq. 3.12 N", "adaptive N", "ratio", "plan", "seconds"], g_rows)
    return out


if __name__ == "__main__":
    print(run())
