"""What ``bench emulate`` prints is the emulated bench: the same plan scanned on
``fixtures/benches/emulated.toml`` (the emulated body) and on the printed real description over
emulators started from the same file reads the same counts within noise.

The emulated detector is non-linear and the emulated bench corrects it (``[spectrometer]
nonlinearity = true``); a printed description without that key reads 1-3 % low on bright
readings. The plan takes no white and no dark, so the readings compared are the detector's own
band counts. Bound: each band's difference against ``Z`` standard deviations of the difference
of two independent readings, from the emulator's noise model per pixel (read noise 6 counts,
shot noise of 0.1 count per electron, averaged over the plan's scans; the band averages several
pixels, so the real deviation is smaller). ``Z`` is the two-sided Bonferroni bound for a
family-wise false-alarm rate of 1e-3 over the compared values. Power: the description with
the correction switched off must differ by more than the bound.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from scipy.stats import norm

from bench.builders.emulated import Emulators
from bench.cli import main
from bench.core.parsing import read_toml
from bench.store import RunStore

ROOT = Path(__file__).parent.parent
EMULATED = ROOT / "fixtures" / "benches" / "emulated.toml"
FAMILY_ALPHA = 1e-3
AVERAGES = 2

PLAN = f"""name = "bright"
kind = "in-plane"
integration_s = 0.05
averages = {AVERAGES}
dark = "none"
white = "none"

[in_plane]
theta_i = [30]
theta_r = [0, 30, 60]
phi_i = 0
"""


def _signal(plan: Path, bench: Path, store: Path, capsys) -> np.ndarray:
    import json

    capsys.readouterr()
    code = main(["scan", str(plan), "--bench", str(bench), "--store", str(store), "--quiet", "--json"])
    out = capsys.readouterr().out
    assert code == 0, out
    with RunStore(store) as s:
        df = s.readings(json.loads(out)["run_id"])
    return df.sort_values(["idx", "wavelength_nm"])["signal"].to_numpy(dtype=float)


@pytest.fixture(scope="module")
def emulators():
    emu = Emulators(read_toml(EMULATED, "bench config"))
    try:
        yield emu
    finally:
        emu.close()


def test_printed_description_keeps_the_emulated_spectrometer_settings(emulators):
    printed = emulators.real_bench_config()
    assert printed["spectrometer"]["nonlinearity"] is True
    assert printed["emulated"]["aperture_deg"] == 1.0  # the detector cone every body reads


def test_printed_description_reads_as_the_emulated_bench(emulators, tmp_path, capsys):
    plan = tmp_path / "bright.toml"
    plan.write_text(PLAN)
    reference = _signal(plan, EMULATED, tmp_path / "emulated.sqlite", capsys)
    printed = emulators.real_bench_config()
    lab = tmp_path / "lab.toml"
    lab.write_bytes(tomli_w.dumps(printed).encode())
    over_emulators = _signal(plan, lab, tmp_path / "printed.sqlite", capsys)
    assert reference.shape == over_emulators.shape == (9,)
    assert reference.max() > 20000  # bright enough for the non-linearity to show (1e-6 per count)
    sd = np.sqrt(2.0 * (6.0**2 + 0.1 * np.maximum(reference, 0.0)) / AVERAGES)
    bound = norm.isf(FAMILY_ALPHA / 2 / reference.size)
    z = (over_emulators - reference) / sd
    assert np.max(np.abs(z)) < bound, (reference, over_emulators)

    # power: the description as it was printed before, without the detector's correction
    uncorrected = {**printed, "spectrometer": {**printed["spectrometer"], "nonlinearity": False}}
    lab.write_bytes(tomli_w.dumps(uncorrected).encode())
    raw = _signal(plan, lab, tmp_path / "raw.sqlite", capsys)
    assert np.max(np.abs((raw - reference) / sd)) > bound
    assert math.isclose(float(np.median(raw / reference)), 1.0, abs_tol=0.05)  # same bench, only compressed
