"""A calibration belongs to the body that measured it (:mod:`bench.calibration_chain`): a white
records its origin (body, bench, detector), files keep it, a run on another body or detector
refuses it in one line before any motion, a resumed run keeps its own body; and a white that
does not look like the standard is refused (the declared detector's level, the last accepted
white's level and spectral shape). Fast: synthetic readings and the virtual body only."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bench.builders.detector import RESPONSE_GAIN
from bench.calibration_chain import (DECLARED_FLOOR, LEVEL_TOLERANCE, SHAPE_TOLERANCE, check_origin,
                                     check_white_level, decide_calibration, expected_white_rate, resumed_calibration,
                                     white_origin)
from bench.cli import main
from bench.config import load_bench
from bench.core.calibration import Calibration, WhiteStandard
from bench.core.errors import CalibrationRefused, InputError
from bench.core.parsing import read_toml
from bench.core.roles import InstrumentInfo, Reading
from bench.io.white import WhiteReference, read_white_reference, write_white_reference
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore

BENCHES = Path(__file__).resolve().parent.parent / "fixtures" / "benches"
WL = np.array([450.0, 550.0, 650.0])
PLAN = {"name": "short", "kind": "list", "integration_s": 0.02, "averages": 2, "dark": "once", "white": "once",
        "order": "as-given", "list": {"points": [[30, 0, 10, 180], [30, 0, 30, 180]]}}
DETECTOR = {"counts_per_ms": 1500.0}


def _origin(body="emulated", serial="EMU00001", wl=WL, cpm=1500.0):
    return {"body": body, "bench": "lab", "detector": {"model": "USB2000+", "serial": serial,
                                                       "wavelengths_nm": [float(w) for w in wl], "counts_per_ms": cpm}}


def _fake_bench(kind="emulated", serial="EMU00001", config=None, wl=WL):
    """What the chain's checks look at: kind, name, config, white standard and the detector."""
    info = InstrumentInfo(kind="spectrometer", model="USB2000+", serial=serial, firmware="x")
    spec = SimpleNamespace(describe=lambda: info, wavelengths=np.asarray(wl, float))
    return SimpleNamespace(kind=kind, name="lab", config=dict(config or {}), white=WhiteStandard(0.99, 0.005),
                           spectrometer=spec)


def _reading(signal, t=0.02, std=None, dark=False):
    s = np.asarray(signal, float)
    return Reading(WL.copy(), s, np.zeros(s.size, bool), t, 2, timestamp=1796040000.0, dark=dark,
                   std=np.sqrt(np.maximum(s, 1.0) / 2) / 10 if std is None else np.asarray(std, float))


def _white(net_per_s, t=0.02, dark_level=1000.0, origin=None):
    """A white whose dark-corrected rate is ``net_per_s`` (counts/s per band)."""
    d = np.full(WL.shape, dark_level)
    return Calibration(WhiteStandard(0.99, 0.005), _reading(np.asarray(net_per_s) * t + d, t),
                       _reading(d, t, dark=True), origin=origin)


def _expected_peak():  # the declared detector's rate for the 0.99 standard at 45 deg, counts/s
    return RESPONSE_GAIN * 1500.0 * 1000.0 * 0.99 / math.pi * math.cos(math.radians(45))


# --- origin: recorded, kept in files, old files read and say what they lack -------------------


def test_a_white_file_keeps_its_origin_and_an_old_file_says_what_it_lacks(tmp_path):
    cal = _white(np.full(3, 1e5), origin=_origin())
    path = write_white_reference(tmp_path / "w.csv", WhiteReference.from_calibration(cal, bench="lab"))
    back = read_white_reference(path)
    assert back.origin == _origin() and back.lacks == [] and back.calibration(WhiteStandard()).origin == _origin()
    assert back.provenance()["body"] == "emulated"
    assert Calibration.from_dict(cal.as_dict()).origin == _origin()  # a run's calibration keeps it too
    old = write_white_reference(tmp_path / "old.csv", WhiteReference(cal.white, cal.white_dark, "2026-11-30"))
    ref = read_white_reference(old)  # written before origins were recorded: still readable
    assert ref.origin is None and ref.lacks == ["body", "detector"]
    with pytest.raises(CalibrationRefused, match=r"records no body or detector .*bench white --bench BENCH.toml "
                                                 r"--body emulated --out FILE --force"):
        check_origin("white reference old.csv", ref.origin, _fake_bench())
    bad = path.read_text().replace('"origin": {"body": "emulated"', '"origin": {"body": 3')
    (tmp_path / "bad.csv").write_text(bad)
    with pytest.raises(InputError, match="origin must be an object"):
        read_white_reference(tmp_path / "bad.csv")


def test_another_body_or_detector_is_refused_in_one_line():
    check_origin("w", _origin(), _fake_bench())  # same body, same unit, same wavelengths: taken
    cases = {"measured on the emulated body; bench 'lab' runs on the virtual body": (_origin(), _fake_bench("virtual")),
             "the virtual body measures its own standard": (_origin(), _fake_bench("virtual")),
             "measured on the virtual body; bench 'lab' runs on the emulated": (_origin("virtual"), _fake_bench()),
             "read with detector USB2000\\+ #EMU00002": (_origin(serial="EMU00002"), _fake_bench()),
             "holds wavelengths 2 at 450..550 nm": (_origin(wl=WL[:2]), _fake_bench()),
             "counts_per_ms = 1000": (_origin(cpm=1000.0), _fake_bench())}
    for why, (origin, bench) in cases.items():
        with pytest.raises(CalibrationRefused, match=why) as info:
            check_origin("w", origin, bench)
        assert "\n" not in str(info.value)
    # the virtual detector's serial names its seed: another seed is the same twin
    check_origin("w", _origin("virtual", serial="seed-1"), _fake_bench("virtual", serial="seed-2"))


def _virtual_bench(**kw):
    d = read_toml(BENCHES / "emulated.toml")
    d.update(kw)
    return load_bench(d, body="virtual")


def test_the_twin_refuses_the_hardware_white_before_any_motion(tmp_path):
    """The reported symptom: an emulated bench's white file named by [white] reference_file and a
    scan on ``--body virtual``: refused in one line (exit 2) before any motion, no run stored."""
    hw = _white(np.array([0.145, 0.499, 0.886]) * _expected_peak(), origin=_origin())  # hardware counts
    white = write_white_reference(tmp_path / "w.csv", WhiteReference.from_calibration(hw, bench="emulated"))
    d = read_toml(BENCHES / "emulated.toml")
    d["white"] = {**d["white"], "reference_file": str(white)}
    with load_bench(d, body="virtual") as b:
        moves = []
        b.goniometer.move_to = lambda g: moves.append(g)
        with RunStore(tmp_path / "r.sqlite") as store:
            with pytest.raises(CalibrationRefused, match="measured on the emulated body"):
                run_scan(b, plan_from_dict(PLAN), store)
            assert moves == [] and store.runs() == []
    import tomli_w

    (tmp_path / "lab.toml").write_text(tomli_w.dumps(d))
    (tmp_path / "plan.toml").write_text(tomli_w.dumps(PLAN))
    assert main(["scan", str(tmp_path / "plan.toml"), "--bench", str(tmp_path / "lab.toml"), "--body", "virtual",
                 "--store", str(tmp_path / "cli.sqlite"), "--quiet"]) == 2


def test_the_twin_takes_its_own_white_and_a_file_of_its_own_body(tmp_path, capsys):
    """`bench white --body virtual` records the virtual origin; a run on the virtual body takes
    it (the twin's own white), and its values are those of a white measured in the run."""
    import tomli_w

    lab = tmp_path / "lab.toml"
    lab.write_text(tomli_w.dumps(read_toml(BENCHES / "emulated.toml")))
    out = tmp_path / "w.csv"
    assert main(["white", "--bench", str(lab), "--body", "virtual", "--out", str(out), "--integration-s", "0.02",
                 "--averages", "2"]) == 0
    ref = read_white_reference(out)
    assert ref.origin["body"] == "virtual" and ref.origin["detector"]["wavelengths_nm"] == [450.0, 550.0, 650.0]
    d = read_toml(lab)
    d["white"] = {**d["white"], "reference_file": str(out)}
    with load_bench(d, body="virtual") as b, RunStore(tmp_path / "r.sqlite") as store:
        chain = decide_calibration(b, plan_from_dict(PLAN))
        assert chain.source == "file"
        run = run_scan(b, plan_from_dict(PLAN), store).run_id
        info = store.run(run)
        values = store.readings(run)
    assert info["meta"]["calibration_steps"]["white_body"] == "virtual"
    assert info["meta"]["white_reference"]["body"] == "virtual"
    truth = 0.8 / math.pi  # the description's Lambertian 0.8
    z = (values.value - truth) / values["std"]
    assert np.all(np.abs(z) < 4.0)  # Sidak over 6 values at two-sided 1e-3 family-wise: 3.9


def test_a_resumed_run_keeps_the_body_of_its_white():
    cal = _white(np.full(3, 1e5), origin=_origin("virtual", serial="seed-3"))
    info = {"calibration": cal.as_dict(), "meta": {"bench_kind": "virtual"}}
    plan = plan_from_dict({**PLAN, "dark": "none"})
    assert resumed_calibration(_fake_bench("virtual", serial="seed-9"), plan, "r1", info).origin["body"] == "virtual"
    with pytest.raises(CalibrationRefused, match="run r1 was calibrated on the virtual body; .* --body virtual"):
        resumed_calibration(_fake_bench("emulated"), plan, "r1", info)
    older = {"calibration": {k: v for k, v in cal.as_dict().items() if k != "origin"}, "meta": {"bench_kind": "virtual"}}
    with pytest.raises(CalibrationRefused, match="calibrated on the virtual body"):  # an older run: its meta says
        resumed_calibration(_fake_bench("emulated"), plan, "r1", older)


# --- a white that does not look like the standard --------------------------------------------


def test_the_declared_level_refuses_more_light_than_the_standard_gives_and_none():
    bench = _fake_bench(config={"detector": DETECTOR})
    peak = _expected_peak()
    np.testing.assert_allclose(expected_white_rate(bench, WL), peak)
    lamp = np.array([0.145, 0.499, 0.886])  # the emulated lamp at the bands: a band reads less, never more
    check_white_level("w", _white(lamp * peak), bench)
    check_white_level("w", _white(np.full(3, peak)), bench)  # the virtual body's flat lamp
    with pytest.raises(CalibrationRefused, match=r"reads 1\.30 x the declared detector's response .* at 650 nm"):
        check_white_level("w", _white(lamp * peak * np.array([1, 1, 1.3 / 0.886])), bench)
    with pytest.raises(CalibrationRefused, match="brightest band reads 0.010"):
        check_white_level("w", _white(np.full(3, 0.01 * peak)), bench)
    assert DECLARED_FLOOR > 0.01
    # a real body that declares no counts_per_ms: no declared level to compare with
    check_white_level("w", _white(np.full(3, 10 * peak)), _fake_bench("real"))
    # a saturated white is masked by the calibration (and says so), not refused as "no light"
    sat = _white(np.full(3, 3 * peak))
    sat = Calibration(sat.standard, Reading(WL, sat.white.signal, np.ones(3, bool), 0.02, 2, std=sat.white.std),
                      sat.white_dark)
    check_white_level("w", sat, bench)
    # five repeated whites under a declared lamp drift of 5 % per lit reading: the mean reads 1.1 x
    reps = [_reading(np.full(3, peak * (1 + 0.05 * j) * 0.02 + 1000.0)) for j in range(5)]
    drifting = Calibration.from_repeats(WhiteStandard(0.99), reps, _reading(np.full(3, 1000.0), dark=True))
    check_white_level("w", drifting, _fake_bench(config={"detector": DETECTOR, "instrument": {"lamp_drift": 0.05}}))
    with pytest.raises(CalibrationRefused, match="more than the standard can give"):
        check_white_level("w", Calibration.from_repeats(WhiteStandard(0.99), [_reading(r.signal * 1.2) for r in reps],
                                                        _reading(np.full(3, 1000.0), dark=True)), bench)


def test_the_last_accepted_white_refuses_a_specimen_and_another_shape():
    """Level: a Lambertian 0.8 specimen read in place of the 0.99 standard reads 0.81 of the
    accepted white (the reported +24 %); shape: one band 8 % off. Noise alone (fixed seed, 200
    draws at the readings' own std) is never refused: the bound's false-alarm rate is 1e-5 per band."""
    bench = _fake_bench()
    rate = np.array([0.145, 0.499, 0.886]) * _expected_peak()
    accepted = _white(rate)
    check_white_level("w", _white(rate * 1.05), bench, accepted)  # the lamp 5 % brighter: within 10 %
    with pytest.raises(CalibrationRefused, match=r"reads 0\.808 x the accepted white w0.csv"):
        check_white_level("w", _white(rate * 0.8 / 0.99), bench, accepted, "the accepted white w0.csv")
    with pytest.raises(CalibrationRefused, match=r"spectral shape differs .* by \+8\.0% at 650 nm"):
        check_white_level("w", _white(rate * np.array([1, 1, 1.08])), bench, accepted)
    assert LEVEL_TOLERANCE < 1 - 0.8 / 0.99 and SHAPE_TOLERANCE < 0.08
    rng = np.random.default_rng(20261206)
    t, dark = 0.02, 1000.0
    for _ in range(200):
        sig = rate * t + dark
        std = np.sqrt(sig / 2) / 10
        noisy = Calibration(WhiteStandard(), _reading(sig + rng.normal(0, std), t, std),
                            _reading(np.full(3, dark), t, np.full(3, 0.5), dark=True))
        check_white_level("w", noisy, bench, accepted)


def test_bench_white_refuses_a_white_unlike_the_accepted_one_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """`bench white` on the virtual body compares the new white with the one it replaces
    (``--force``) or the bench's reference file: a standard whose certificate the lab mistyped
    in the description (0.80, not 0.99: what the twin then mounts) is refused, nothing written."""
    import tomli_w

    d = read_toml(BENCHES / "emulated.toml")
    lab = tmp_path / "lab.toml"
    lab.write_text(tomli_w.dumps(d))
    first = tmp_path / "w.csv"
    assert main(["white", "--bench", str(lab), "--body", "virtual", "--out", str(first), "--integration-s", "0.05"]) == 0
    d["white"] = {**d["white"], "reflectance_factor": 0.8, "reference_file": str(first)}
    lab.write_text(tomli_w.dumps(d))
    capsys.readouterr()
    out = tmp_path / "w2.csv"
    assert main(["white", "--bench", str(lab), "--body", "virtual", "--out", str(out), "--integration-s", "0.05"]) == 2
    err = capsys.readouterr().err
    assert "x the accepted white" in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_white_origin_of_the_virtual_body():
    with _virtual_bench() as b:
        o = white_origin(b)
    assert o["body"] == "virtual" and o["detector"]["counts_per_ms"] == 1.0e4 / (RESPONSE_GAIN * 1000.0)  # its gain
    assert o["detector"]["wavelengths_nm"] == [450.0, 550.0, 650.0]
    with _virtual_bench(detector=DETECTOR) as b:  # a declared detector sets the twin's gain
        assert white_origin(b)["detector"]["counts_per_ms"] == 1500.0
        with pytest.raises(CalibrationRefused, match="counts_per_ms = 5; bench 'emulated' declares 1500"):
            check_origin("w", o, b)


def test_bench_plan_refuses_another_bodys_white_from_the_description_alone(tmp_path, capsys):
    """`bench plan` on the emulated description (nothing opened: the serial is unknown there, the
    body and bands are not) names the foreign white as the calibration refusal, exit 2."""
    import json

    import tomli_w

    twin = _white(np.full(3, 1e5), origin=_origin("virtual", serial="seed-1", cpm=None))
    white = write_white_reference(tmp_path / "w.csv", WhiteReference.from_calibration(twin, bench="twin"))
    d = read_toml(BENCHES / "emulated.toml")
    d["white"] = {**d["white"], "reference_file": str(white)}
    (tmp_path / "lab.toml").write_text(tomli_w.dumps(d))
    (tmp_path / "plan.toml").write_text(tomli_w.dumps(PLAN))
    capsys.readouterr()
    assert main(["plan", str(tmp_path / "plan.toml"), "--bench", str(tmp_path / "lab.toml"), "--json"]) == 2
    shown = json.loads(capsys.readouterr().out)
    assert "measured on the virtual body; bench 'emulated' runs on the emulated body" in shown["calibration_refused"]


def test_bench_white_out_needs_force_and_then_compares_with_the_white_it_replaces(tmp_path, capsys):
    """`--out` names an existing white: refused without `--force` (the file unchanged); with it,
    the new white is compared with the one it replaces: a standard read at 0.80 of it is refused
    and the accepted file kept; the same standard again replaces it."""
    import tomli_w

    d = read_toml(BENCHES / "emulated.toml")
    lab = tmp_path / "lab.toml"
    lab.write_text(tomli_w.dumps(d))
    out = tmp_path / "w.csv"
    args = ["white", "--bench", str(lab), "--body", "virtual", "--out", str(out), "--integration-s", "0.05"]
    assert main(args) == 0
    before = out.read_text()
    capsys.readouterr()
    assert main(args) == 2 and "--force" in capsys.readouterr().err and out.read_text() == before
    lab.write_text(tomli_w.dumps({**d, "white": {**d["white"], "reflectance_factor": 0.8}}))
    assert main(args + ["--force"]) == 2
    err = capsys.readouterr().err
    assert f"x the accepted white {out}" in err and out.read_text() == before
    lab.write_text(tomli_w.dumps(d))
    assert main(args + ["--force"]) == 0 and out.read_text() != before


def test_a_white_without_its_dark_is_bounded_below_only():
    """``--dark none``: the white's counts hold the detector's dark level (at 2 ms, 1000 counts of
    dark are half the standard's light), so only the floor applies."""
    bench = _fake_bench(config={"detector": DETECTOR})
    t = 0.002
    s = np.array([0.145, 0.499, 0.886]) * _expected_peak() * t + 1000.0
    check_white_level("w", Calibration(WhiteStandard(0.99), _reading(s, t)), bench)
    with pytest.raises(CalibrationRefused, match="brightest band"):
        check_white_level("w", Calibration(WhiteStandard(0.99), _reading(np.full(3, 0.5), t)), bench)


def test_bench_resume_on_another_body_is_refused_before_opening(tmp_path, capsys, monkeypatch):
    """A virtual run interrupted after its first point, resumed with `--body emulated`: refused in
    one line from the run's record, before any emulator starts."""
    from bench.core.errors import RunInterrupted

    def interrupt(k, idx):
        raise KeyboardInterrupt

    with _virtual_bench() as b, RunStore(tmp_path / "r.sqlite") as store:
        with pytest.raises(RunInterrupted):
            run_scan(b, plan_from_dict(PLAN), store, on_point=interrupt)
        run = store.runs()[0]["run_id"]
    import bench.config

    monkeypatch.setattr(bench.config, "load_bench", lambda *a, **k: pytest.fail("a body was built"))
    capsys.readouterr()
    assert main(["resume", run, "--store", str(tmp_path / "r.sqlite"), "--body", "emulated"]) == 2
    err = capsys.readouterr().err
    assert f"run {run} was calibrated on the virtual body" in err and len(err.strip().splitlines()) == 1
