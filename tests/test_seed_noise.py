"""``--seed`` governs every body's noise, and repeated triggers scatter as the detector says.

* emulated body: ``bench scan --seed 1`` and ``--seed 2`` read different noise (the run's seed
  wins over ``[emulated] seed``), of the same bench (within noise of each other);
* virtual body with a declared ``[detector]``: the detector's read noise follows the seed;
* virtual body: repeated triggers at one geometry scatter as the reading's reported standard
  deviation says. Statistics: the sample variance of ``N`` repeats per band against the
  reported variance, chi-square with ``N - 1`` dof, two-sided, 1e-3 per band (3 bands: 3e-3
  family-wise); power: bit-identical repeats (the old behaviour) have variance 0, below the
  lower bound; and a variance 4x the reported one is above the upper bound.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import tomli_w
from scipy.stats import chi2

from bench.config import load_bench
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.store import RunStore
from helpers.cli import run_main

ROOT = Path(__file__).parent.parent
BENCHES = ROOT / "fixtures" / "benches"
ALPHA = 1e-3
PLAN = {"name": "seeds", "kind": "in-plane", "integration_s": 0.02, "averages": 2, "dark": "none", "white": "none",
        "in_plane": {"theta_i": [30], "theta_r": [0, 30, 60], "phi_i": 0}}


def _signal(capsys, tmp_path: Path, bench: Path, seed: int, name: str, *extra: str) -> np.ndarray:
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps(PLAN))
    store = tmp_path / f"{name}.sqlite"
    code, out, err = run_main(capsys, "scan", plan, "--bench", bench, "--store", store, "--seed", seed, "--json",
                              "-q", *extra)
    assert code == 0, err
    with RunStore(store) as s:
        df = s.readings(json.loads(out)["run_id"])
    return df.sort_values(["idx", "wavelength_nm"])["signal"].to_numpy(dtype=float)


def test_seed_governs_the_emulated_body(tmp_path, capsys):
    one = _signal(capsys, tmp_path, BENCHES / "emulated.toml", 1, "one")
    two = _signal(capsys, tmp_path, BENCHES / "emulated.toml", 2, "two")
    assert not np.array_equal(one, two)
    # different noise, the same bench: within 6 sd of the emulator's noise per pixel (read 6
    # counts, shot 0.1 count per electron, 2 scans averaged) of each other
    sd = np.sqrt(2.0 * (36.0 + 0.1 * one) / 2)
    assert np.all(np.abs(one - two) < 6 * sd)


def test_seed_governs_the_declared_detector_of_the_virtual_body(tmp_path, capsys):
    d = read_toml(BENCHES / "virtual.toml", "bench config")
    d["detector"] = {"read_noise": 6.0}
    bench = tmp_path / "twin.toml"
    bench.write_text(tomli_w.dumps(d))
    one = _signal(capsys, tmp_path, bench, 1, "one")
    two = _signal(capsys, tmp_path, bench, 2, "two")
    again = _signal(capsys, tmp_path, bench, 1, "again")
    assert np.array_equal(one, again) and not np.array_equal(one, two)


def _variance_within(samples: np.ndarray, variance: float) -> bool:
    n = samples.size
    stat = (n - 1) * samples.var(ddof=1) / variance
    return chi2.ppf(ALPHA / 2, n - 1) < stat < chi2.isf(ALPHA / 2, n - 1)


def test_repeated_triggers_scatter_as_the_reported_uncertainty():
    d = read_toml(BENCHES / "virtual.toml", "bench config")
    d["virtual"] = {**d["virtual"], "rays": 100000}  # binomial scatter well above float rounding
    with load_bench(d, seed=5, body="virtual") as bench:
        bench.goniometer.move_to(Geometry(30, 0, 20, 180))
        readings = [bench.spectrometer.acquire(0.02, 2) for _ in range(60)]
    signal = np.array([r.signal for r in readings])
    reported = np.mean([np.asarray(r.std) ** 2 for r in readings], axis=0)
    for band in range(signal.shape[1]):
        assert _variance_within(signal[:, band], reported[band])
        assert not _variance_within(signal[:, band], 4 * reported[band])  # power: a 2x wider scatter is seen
        assert not _variance_within(np.full(60, signal[0, band]) + 1e-12 * np.arange(60), reported[band])
