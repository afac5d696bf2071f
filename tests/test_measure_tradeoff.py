"""What ``bench gonio --relative-uncertainty`` means, and the tradeoff picture.

* ``--relative-uncertainty V`` is a relative uncertainty of each patch's BSDF: the achieved relative
  half-width of the brightest and the dimmest patch of interest is about V (below 1.2 V), and a
  budget the time limit cannot pay names the patches it cannot serve;
* ``--patch-probability-uncertainty V`` keeps eq. 3.12 (the old trap: a tiny N, dim patches off
  by more than 50 %), and the output says which meaning was used;
* ``bench tradeoff``: timings are the median of >= 3 seeded sweeps with their spread, the Pareto
  front is computed from the medians, the plot is written.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tests.helpers.cli import run_bench

ROOT = Path(__file__).resolve().parent.parent


def _bench(*args):
    r = run_bench(*args, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_gonio_uncertainty_is_a_relative_bsdf_uncertainty():
    out = json.loads(_bench("gonio", "--specimen", "lambert:albedo=0.8", "--relative-uncertainty", "0.05", "--seed", "1",
                            "--json"))
    assert out["uncertainty"]["mode"] == "relative BSDF" and out["uncertainty"]["v"] == 0.05
    a = out["achieved"]
    for which in ("brightest", "dimmest_of_interest"):
        assert 0.03 < a[which]["relative_half_width"] < 0.06, a
    assert a["max_relative_half_width"] < 0.06
    text = _bench("gonio", "--specimen", "lambert:albedo=0.8", "--relative-uncertainty", "0.05", "--seed", "1")
    assert "uncertainty: relative BSDF half-width 0.05" in text and "achieved relative half-width: brightest" in text


def test_patch_probability_uncertainty_keeps_eq_3_12_and_says_so():
    out = json.loads(_bench("gonio", "--specimen", "lambert:albedo=0.8", "--patch-probability-uncertainty", "0.005",
                            "--seed", "1", "--json"))
    assert out["uncertainty"]["mode"] == "patch probability (eq. 3.12)"
    assert out["N"] < 100_000 and out["achieved"]["dimmest_of_interest"]["relative_half_width"] > 0.5  # the trap
    text = _bench("gonio", "--specimen", "lambert:albedo=0.8", "--patch-probability-uncertainty", "0.005", "--seed",
                  "1")
    assert "an absolute bound on each patch's probability, not on its BSDF" in text


def test_relative_uncertainty_names_the_patches_it_cannot_serve():
    text = _bench("gonio", "--specimen", "plastic:alpha=0.1,eta=1.5,kd=0.5", "--relative-uncertainty", "0.01", "--seed", "1",
                  "--max-seconds", "0.05", "--method", "fast")
    assert "cannot meet it for" in text and "within --max-seconds 0.05" in text


def test_relative_patch_rays_formula():
    from virtual.bounds import relative_patch_rays

    r = relative_patch_rays(np.array([0.01, 0.001]), 0.1, 0.01)
    z = 2.5758293035489004
    assert r["N"] == int(np.ceil(z * z * 0.999 / (0.01 * 0.001))) and r["p_min"] == 0.001
    capped = relative_patch_rays(np.array([0.01, 0.001]), 0.1, 0.01, max_rays=100_000)
    assert capped["capped"] and capped["unreachable"] == [1] and capped["N"] == 100_000


def test_tradeoff_medians_spread_and_pareto_from_medians(tmp_path):
    from bench.tradeoff_plot import plot_small_multiples, repeated_sweep
    from virtual.scene import load_scene
    from virtual.tradeoff import pareto_front

    scene = load_scene(ROOT / "fixtures" / "scenes" / "lambert-bare.toml")
    rows = repeated_sweep(scene, rays=[10_000, 100_000], repeats=2)  # raised to the minimum of 3
    assert rows and all(r["repeats"] == 3 for r in rows)
    assert all(r["seconds_lo"] <= r["seconds"] <= r["seconds_hi"] for r in rows)
    front = pareto_front([(r["seconds"], r["max_abs_error"]) for r in rows])
    assert [r["pareto"] for r in rows] == front.tolist()
    png = plot_small_multiples(rows, str(tmp_path / "t.png"), title="t", error_unit="1")
    assert Path(png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = _bench("tradeoff", str(ROOT / "fixtures" / "scenes" / "lambert-bare.toml"), "--rays", "10000",
                  "--plot", str(tmp_path / "cli.png"))
    assert "seconds: median of 3 runs" in text and (tmp_path / "cli.png").is_file()
