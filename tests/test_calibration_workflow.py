"""Calibration that cannot be silently wrong, on the lab's own workflow.

The real-bench config ``bench emulate`` prints for the emulators (the real drivers, a
``kind = "real"`` bench), a white stored non-interactively (``bench white --yes``), then the
shipped in-plane plan (``dark = "per-incidence"``) on a Lambertian 0.8: every calibrated value
must hold 0.8/pi = 0.2546 1/sr within its reported uncertainty. The same bench with its lamp
undeclared is refused before any motion, in one line naming the step and the missing part; a
stored white that does not match the plan is refused; ``dark = "none"`` is refused on a detector
with a dark level, and explicit and recorded where the description declares none.

Statistics: each value's z = (value - 0.8/pi) / std, asserted |z| < z* with z* the two-sided
Bonferroni bound for a family-wise false-alarm rate of 1e-3 over every value of the run (the
readings share one white, so the family is positively correlated and the real rate is lower).
Power: the same check on the dark-less run (the issue's 0.34-1.01 1/sr) must fail.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from scipy.stats import norm

from bench.builders.emulated import DEFAULT_EMULATED_CONFIG, Emulators
from bench.cli import main
from bench.store import RunStore

ROOT = Path(__file__).parent.parent
IN_PLANE = ROOT / "fixtures" / "plans" / "in-plane.toml"
TRUTH = 0.8 / math.pi  # Lambertian 0.8: 0.2546 1/sr
FAMILY_ALPHA = 1e-3

pytestmark = pytest.mark.hil


@pytest.fixture(scope="module")
def emulators():
    emu = Emulators(DEFAULT_EMULATED_CONFIG)
    try:
        yield emu
    finally:
        emu.close()


def _write(path: Path, config: dict) -> Path:
    path.write_bytes(tomli_w.dumps(config).encode())
    return path


def _store_white(emu: Emulators, bench_file: Path, out: Path, *extra: str) -> int:
    """`bench white --yes` with the standard mounted on the emulated turntable (what the
    operator confirms), then the specimen back."""
    emu.mount_white(True)
    try:
        return main(["white", "--bench", str(bench_file), "--out", str(out), "--yes", "--integration-s", "0.02",
                     "--averages", "2", *extra])
    finally:
        emu.mount_white(False)


def _z(store_path: Path, run: str) -> tuple[np.ndarray, object]:
    with RunStore(store_path) as store:
        df = store.readings(run)
    return (df["value"].to_numpy() - TRUTH) / df["std"].to_numpy(), df


def _scan(plan: Path, bench: Path, store: Path, capsys) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["scan", str(plan), "--bench", str(bench), "--store", str(store), "--quiet", "--json"])
    out, err = capsys.readouterr()
    return code, out + err


def test_emulate_config_declares_the_calibration_chain(emulators):
    config = emulators.real_bench_config()
    assert config["kind"] == "real" and config["light"] == {"kind": "spectrometer-lamp"}
    assert config["specimen"]["name"] and config["specimen"]["spec"] == "lambert:albedo=0.8"


def test_real_bench_workflow_is_right_or_refused(emulators, tmp_path, capsys):
    import json

    config = emulators.real_bench_config()
    lab = _write(tmp_path / "lab.toml", config)
    # no stored white and no terminal (pytest's stdin): refused before motion, naming the way out
    code, out = _scan(IN_PLANE, lab, tmp_path / "no-white.sqlite", capsys)
    assert code == 2 and "asks for a white reference" in out and "--yes --integration-s 0.02 --averages 2" in out
    white = tmp_path / "white.csv"
    assert _store_white(emulators, lab, white) == 0
    lab = _write(tmp_path / "lab.toml", {**config, "white": {**config["white"], "reference_file": str(white)}})
    store = tmp_path / "runs.sqlite"
    code, out = _scan(IN_PLANE, lab, store, capsys)
    assert code == 0, out
    run = json.loads(out)["run_id"]
    z, df = _z(store, run)
    bound = norm.isf(FAMILY_ALPHA / 2 / z.size)
    assert df["value"].notna().all() and len(df) == 3 * 21 * 3  # theta_i x theta_r x bands, none masked
    assert np.max(np.abs(z)) < bound, df.loc[np.argmax(np.abs(z)), ["theta_i", "theta_r", "value", "std"]]
    with RunStore(store) as s:
        meta = s.run(run)["meta"]
    assert meta["calibration_steps"]["dark"] == "per-incidence" and meta["calibration_steps"]["white_source"] == "file"
    assert meta["specimen"] == "lambert:albedo=0.8" and meta["specimen_name"] == config["specimen"]["name"]

    # the lamp undeclared: the plan's darks are refused before motion, one line, exit 2
    no_lamp = {k: v for k, v in config.items() if k != "light"}
    dark_lab = _write(tmp_path / "no-lamp.toml", {**no_lamp, "white": {**config["white"], "reference_file": str(white)}})
    code, out = _scan(IN_PLANE, dark_lab, tmp_path / "refused.sqlite", capsys)
    assert code == 2 and "darks per incidence" in out and "declares no switchable light" in out
    # and it does not suggest a plan without darks, which this detector's dark level would refuse next
    assert 'dark = "none"' not in out and "dark level, 1000 counts" in out and len(out.strip().splitlines()) == 1
    assert not (tmp_path / "refused.sqlite").exists() or not RunStore(tmp_path / "refused.sqlite").runs()
    assert main(["plan", str(IN_PLANE), "--bench", str(dark_lab), "--json"]) == 2  # bench plan says so too
    assert "darks per incidence" in json.loads(capsys.readouterr().out)["calibration_refused"]

    # a white that does not match the plan (another integration time) is refused
    other = tmp_path / "white-0.05.csv"
    emulators.mount_white(True)
    try:
        assert main(["white", "--bench", str(lab), "--out", str(other), "--yes", "--integration-s", "0.05",
                     "--averages", "2"]) == 0
    finally:
        emulators.mount_white(False)
    mismatched = _write(tmp_path / "mismatch.toml", {**config, "white": {**config["white"], "reference_file": str(other)}})
    code, out = _scan(IN_PLANE, mismatched, tmp_path / "m.sqlite", capsys)
    assert code == 2 and "integration_s = 0.05" in out and "integrates 0.02" in out


def test_without_darks_refused_on_a_detector_with_a_dark_level(emulators, tmp_path, capsys):
    """A bench without a switchable light takes no dark, and its detector (undeclared: the
    emulated unit's) reads a dark level of 1000 counts: a white or a plan without darks is refused
    in one line, nothing written. Power of the workflow check: the same bench declaring no dark
    level (``[detector] dark_counts = 0``, wrongly) is taken with dark = "none" (explicit,
    recorded) and gives the issue's excess at large theta_r, which the same bound detects."""
    import json

    config = {k: v for k, v in emulators.real_bench_config().items() if k != "light"}
    lab = _write(tmp_path / "lab.toml", config)
    white = tmp_path / "white.csv"
    assert _store_white(emulators, lab, white) == 2  # a dark without a lamp: refused ...
    assert "--dark none" not in capsys.readouterr().out
    assert _store_white(emulators, lab, white, "--dark", "none") == 2  # ... and none on a dark level too
    err = capsys.readouterr().err
    assert "takes no dark" in err and "dark level of 1000 counts" in err and len(err.strip().splitlines()) == 1
    assert not white.exists()
    config = {**config, "detector": {"dark_counts": 0.0}}  # the lab declares no dark level
    lab = _write(tmp_path / "lab.toml", config)
    assert _store_white(emulators, lab, white, "--dark", "none") == 0
    lab = _write(tmp_path / "lab.toml", {**config, "white": {**config["white"], "reference_file": str(white)}})
    plan = IN_PLANE.read_text().replace('dark = "per-incidence"', 'dark = "none"')
    plan_file = tmp_path / "in-plane-no-dark.toml"
    plan_file.write_text(plan)
    store = tmp_path / "runs.sqlite"
    code, out = _scan(plan_file, lab, store, capsys)
    assert code == 0, out
    run = json.loads(out)["run_id"]
    z, _ = _z(store, run)
    with RunStore(store) as s:
        assert s.run(run)["meta"]["calibration_steps"]["dark"] == "none"
    capsys.readouterr()
    assert main(["show", run, "--store", str(store)]) == 0
    assert "calibration: dark none, white once (file)" in capsys.readouterr().out
    assert np.max(np.abs(z)) > norm.isf(FAMILY_ALPHA / 2 / z.size)


def test_bench_emulate_prints_a_toml_bench_file(capsys):
    """Item 6: the printed config is TOML (a bench file as is, ports in comments); --json keeps JSON."""
    import json
    import tomllib

    from bench.core.schemas import BenchFile, validate_document

    emulated = str(ROOT / "fixtures" / "benches" / "emulated.toml")
    assert main(["emulate", emulated, "--max-seconds", "0"]) == 0
    config = tomllib.loads(capsys.readouterr().out)
    validate_document(BenchFile, config, "bench emulate output")
    assert config["kind"] == "real" and config["light"]["kind"] == "spectrometer-lamp"
    assert config["specimen"]["spec"] == "lambert:albedo=0.8"
    assert main(["emulate", emulated, "--max-seconds", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["real_bench"]["light"] == config["light"] and set(out["ports"]) >= {"dynamixel_bus", "spectrometer"}
