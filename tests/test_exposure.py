"""Saturation planned, not discovered; planning opens nothing.

* ``bench plan`` predicts each reading's counts from the description (detector, optics,
  specimen, white) and refuses a plan that would saturate in one line naming the reading, its
  predicted counts and the full scale; its expected uncertainty follows integration time and
  averages. ``bench scan`` refuses the same plan before building any body.
* ``bench plan`` on a real description opens no port (the template's ports do not exist here);
  ``bench scan`` on it names the dead or stale port in one line.
* A run whose readings are masked says so: ``completed`` with the reason ``N of M readings
  masked (S saturated)`` in ``bench show``, ``bench runs`` and the scan's JSON.
"""

from __future__ import annotations

import dataclasses
import json
import socket
from pathlib import Path

import pytest
import tomli_w

from bench.core.parsing import read_toml
from bench.exposure import MARGIN_SD, predict_exposure
from bench.plans import load_plan
from helpers.cli import run_main

ROOT = Path(__file__).parent.parent
BENCHES = ROOT / "fixtures" / "benches"
IN_PLANE = ROOT / "fixtures" / "plans" / "in-plane.toml"


def _plan(tmp_path: Path, integration_s: float, averages: int = 2, white: str = "none", dark: str = "none") -> Path:
    doc = {"name": "p", "kind": "in-plane", "integration_s": integration_s, "averages": averages, "dark": dark,
           "white": white, "in_plane": {"theta_i": [30], "theta_r": [0, 30, 60], "phi_i": 0}}
    path = tmp_path / f"plan-{integration_s:g}-{averages}-{white}.toml"
    path.write_text(tomli_w.dumps(doc))
    return path


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_prediction_scales_with_integration_and_refuses_past_full_scale():
    d = read_toml(BENCHES / "emulated.toml", "bench config")
    plan = load_plan(IN_PLANE)
    nominal = predict_exposure(plan, d)
    assert nominal is not None and not nominal.saturates
    mean, sd = nominal.counts()
    assert 0.1 < mean / 65535 < 0.5  # the shipped plan sits well inside the detector
    long = predict_exposure(dataclasses.replace(plan, integration_s=1.0, averages=8), d)
    assert long.saturates and long.counts()[0] > 65535
    t_max = long.longest_integration()
    assert not long.saturates_at(t_max) and long.saturates_at(t_max * 1.001)
    m, s = long.counts(t_max)
    assert m + MARGIN_SD * s == pytest.approx(65535, rel=1e-6)
    # the plan's uncertainty follows its exposure: 10x the integration, less relative noise
    short = predict_exposure(dataclasses.replace(plan, integration_s=0.002), d)
    assert short.relative_noise > 2 * nominal.relative_noise


def test_plain_virtual_description_has_no_full_scale():
    d = {"name": "v", "kind": "virtual", "specimen": {"spec": "lambert:albedo=0.8"}}
    assert predict_exposure(load_plan(IN_PLANE), d) is None


@pytest.mark.parametrize("bench", ["emulated.toml", "virtual.toml"])
def test_plan_and_scan_refuse_a_saturating_plan_before_building_a_body(bench, tmp_path, capsys, monkeypatch):
    plan = _plan(tmp_path, 1.0, 8)
    code, out, err = run_main(capsys, "plan", plan, "--bench", BENCHES / bench)
    line = _one_line(err)
    assert code == 2 and "would saturate" in line and "point 0 (30, 0, 0, 180)" in line and "65535" in line
    code, out, err = run_main(capsys, "plan", plan, "--bench", BENCHES / bench, "--json")
    assert code == 2 and json.loads(out)["exposure"]["saturates"] is True

    import bench.config as config

    def no_body(*args, **kwargs):
        raise AssertionError("a body was built for a refused plan")

    monkeypatch.setattr(config, "load_bench", no_body)
    for body in ("virtual", "emulated"):
        code, out, err = run_main(capsys, "scan", plan, "--bench", BENCHES / bench, "--body", body,
                                  "--store", tmp_path / "runs.sqlite")
        assert code == 2 and "would saturate" in _one_line(err)
    assert not (tmp_path / "runs.sqlite").exists()


def test_plan_expected_uncertainty_follows_integration(tmp_path, capsys):
    got = {}
    for t in (0.002, 0.02):
        code, out, err = run_main(capsys, "plan", _plan(tmp_path, t), "--bench", BENCHES / "emulated.toml", "--json")
        assert code == 0, err
        got[t] = json.loads(out)["relative_uncertainty"]
    assert got[0.002] > 2 * got[0.02]


def test_plan_on_a_real_description_opens_nothing(tmp_path, capsys):
    """The template names /dev/ttyUSB0..2, which do not exist here: a plan is still checked and
    timed, without a line of driver logging."""
    code, out, err = run_main(capsys, "plan", _plan(tmp_path, 0.02), "--bench", BENCHES / "real-template.toml")
    assert code == 0, err
    assert err == "" and "all 3 points reachable" in out and "exposure" in out
    # a calibration step the bench cannot take is the one refusal line, still without opening
    code, out, err = run_main(capsys, "plan", IN_PLANE, "--bench", BENCHES / "real-template.toml")
    assert code == 2 and "declares no switchable light" in _one_line(err)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_scan_names_a_dead_or_stale_port_in_one_line(tmp_path, capsys):
    plan = _plan(tmp_path, 0.02)
    real = read_toml(BENCHES / "real-template.toml", "bench config")
    code, out, err = run_main(capsys, "scan", plan, "--bench", BENCHES / "real-template.toml",
                              "--store", tmp_path / "runs.sqlite")
    line = _one_line(err)
    assert code == 2 and "[arm] port '/dev/ttyUSB0'" in line and "no such device" in line
    stale = {**real, "arm": {**real["arm"], "port": "/dev/null"},
             "turntable": {**real["turntable"], "port": f"tcp://127.0.0.1:{_closed_port()}"}}
    lab = tmp_path / "stale.toml"
    lab.write_text(tomli_w.dumps(stale))
    code, out, err = run_main(capsys, "scan", plan, "--bench", lab, "--store", tmp_path / "runs.sqlite")
    line = _one_line(err)
    assert code == 2 and "[turntable] port 'tcp://127.0.0.1:" in line and "nothing answers" in line
    assert not (tmp_path / "runs.sqlite").exists()


def test_a_run_with_saturated_readings_says_so(tmp_path, capsys, monkeypatch):
    """A specimen brighter than its description (here: the prediction switched off) saturates on
    the virtual body with a declared detector: the run completes, masked, and says so."""
    import bench.runner as runner

    monkeypatch.setattr(runner, "check_exposure", lambda *a, **k: None)
    d = read_toml(BENCHES / "virtual.toml", "bench config")
    d["detector"] = {"saturation_counts": 37000}  # the white (34400 counts) below it, the specimen at 0 deg above
    lab = tmp_path / "bright.toml"
    lab.write_text(tomli_w.dumps(d))
    from bench.config import load_bench
    from bench.runner import run_scan
    from bench.store import RunStore

    plan = load_plan(_plan(tmp_path, 0.05, white="once", dark="once"))  # the declared dark level taken out
    with load_bench(lab) as bench, RunStore(tmp_path / "runs.sqlite") as store:
        result = run_scan(bench, plan, store, seed=1)
    assert result.status == "completed" and result.masked > 0 and result.saturated > 0
    assert result.reason == f"{result.masked} of 9 readings masked ({result.saturated} saturated)"
    code, out, err = run_main(capsys, "show", result.run_id, "--store", tmp_path / "runs.sqlite")
    assert code == 0 and f"completed - {result.reason}" in out.splitlines()[0]
    code, out, err = run_main(capsys, "runs", "--store", tmp_path / "runs.sqlite")
    assert code == 0 and f"({result.reason})" in out
    # an unsaturated run stays plainly completed
    with load_bench(BENCHES / "virtual.toml") as bench, RunStore(tmp_path / "runs.sqlite") as store:
        plain = run_scan(bench, load_plan(_plan(tmp_path, 0.02, white="once")), store, seed=1)
    assert plain.reason is None and plain.masked == 0


def test_resume_on_stale_ports_names_the_port_before_opening(tmp_path, capsys):
    """An interrupted run of a real description whose ports are gone: `bench resume` refuses in
    one line naming the port, and the run stays as it was."""
    from bench.store import RunStore

    real = read_toml(BENCHES / "real-template.toml", "bench config")
    plan = load_plan(_plan(tmp_path, 0.02))
    store = tmp_path / "runs.sqlite"
    with RunStore(store) as s:
        rid = s.create_run(kind="scan", plan=plan.as_dict(), bench=real, meta={"bench_kind": "real"},
                           n_planned=len(plan.points))
        s.set_status(rid, "interrupted", "a device fault")
    code, out, err = run_main(capsys, "resume", rid, "--store", store)
    line = _one_line(err)
    assert code == 2 and "[arm] port '/dev/ttyUSB0'" in line and "no such device" in line
    with RunStore(store) as s:
        assert s.run(rid)["status"] == "interrupted"


def test_auto_integration_takes_the_longest_unsaturated(tmp_path, capsys):
    """integration_s = "auto": the bench chooses the longest integration whose brightest scan
    keeps its margin (two digits, rounded down), records it, and the run reads unsaturated; a
    description without full scale refuses it in one line."""
    doc = {"name": "auto", "kind": "in-plane", "integration_s": "auto", "averages": 2, "dark": "none",
           "white": "none", "in_plane": {"theta_i": [30], "theta_r": [0, 30, 60], "phi_i": 0}}
    plan = tmp_path / "auto.toml"
    plan.write_text(tomli_w.dumps(doc))
    code, out, err = run_main(capsys, "plan", plan, "--bench", BENCHES / "virtual.toml", "--json")
    assert code == 0, err
    got = json.loads(out)
    t = got["integration_s"]
    fixed = predict_exposure(dataclasses.replace(load_plan(plan), integration_s=t, integration_auto=False),
                             read_toml(BENCHES / "virtual.toml", "bench config"))
    assert not fixed.saturates and fixed.saturates_at(t * 1.02) and got["exposure"]["fraction_of_full_scale"] > 0.9
    code, out, err = run_main(capsys, "scan", plan, "--bench", BENCHES / "virtual.toml", "--store",
                              tmp_path / "runs.sqlite", "--json", "-q")
    assert code == 0 and json.loads(out)["masked"] == 0, err
    from bench.store import RunStore

    with RunStore(tmp_path / "runs.sqlite") as s:
        assert s.run(json.loads(out)["run_id"])["plan"]["integration_s"] == t  # recorded: a resume keeps it
    plain = tmp_path / "plain.toml"
    plain.write_text(tomli_w.dumps({"name": "v", "kind": "virtual", "specimen": {"spec": "lambert:albedo=0.8"}}))
    code, out, err = run_main(capsys, "plan", plan, "--bench", plain)
    assert code == 2 and "no detector with a full scale" in _one_line(err)
