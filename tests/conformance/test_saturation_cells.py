"""Saturation on the Bluesky path and in ``bench white``, on the virtual body reading through the
declared detector (``[detector]``, the emulated unit's data sheet: every body saturates alike).

* The reflectance detector's ``stage()`` predicts the white it measures and the setpoint its
  first trigger reads at (:mod:`bench.exposure`, as ``bench scan`` predicts a plan): over full
  scale it is refused in one line before any motion, nothing stored.
* A Bluesky plan's later points are not known at stage: a reading that saturates there is masked,
  and the stored run says so in its reason (``N of M readings masked (S saturated)``), never a
  plain ``completed``.
* ``bench white`` refuses a white predicted to saturate before any motion (as ``bench scan``
  predicts a plan's white), and one found saturated in a band; nothing written.

GGX (alpha 0.3) peaks at 1.19 sr^-1 x cos at (50, 0, 50, 180); the white standard at 0/45 gives
0.22: at 36 ms x 2 the peak is predicted at twice full scale, the white at 37 %.
"""

from __future__ import annotations

from pathlib import Path

import bluesky.plan_stubs as bps
import numpy as np
import bluesky.plans as bp
import pytest
from bluesky import RunEngine

from bench.bluesky import StoreWriter, connect
from bench.core.errors import BenchError
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.store import RunStore
from cells import BENCHES, DETECTOR, bench_cli, write_toml
from truth import SPECIMENS

OVER_S = 0.036  # the GGX peak at twice full scale, the white at 37 % of it


def _description(tmp_path: Path, specimen: str = "ggx") -> Path:
    d = read_toml(BENCHES / "virtual.toml")
    d["specimen"] = {**dict(d.get("specimen") or {}), "spec": SPECIMENS[specimen]["spec"]}
    d["detector"] = dict(DETECTOR)
    return write_toml(tmp_path / "bench.toml", d)


def _list_scan(tmp_path: Path, start: Geometry) -> tuple[str | None, list[dict], int]:
    """A list_scan over the GGX peak from ``start``: (the refusal, the stored runs, the moves the plan made)."""
    RE = RunEngine({})
    devs = connect(_description(tmp_path), run_engine=RE, seed=5, body="virtual")
    store = tmp_path / "runs.sqlite"
    try:
        r, g = devs.reflectance, devs.goniometer
        RE(bps.mv(g, start))
        RE(bps.mv(r.integration_s, OVER_S, r.averages, 2, r.dark_mode, "once", r.white_mode, "once"))
        moves = []
        devs.bench.goniometer.move_to = _counting(devs.bench.goniometer.move_to, moves)
        token = RE.subscribe(StoreWriter(store))
        refusal = None
        try:
            RE(bp.list_scan([r, g], g.theta_i, [30, 50], g.theta_r, [10, 50]))
        except BenchError as exc:
            refusal = str(exc)
        finally:
            RE.unsubscribe(token)
    finally:
        devs.close()
    if not store.exists():
        return refusal, [], len(moves)
    with RunStore(store) as s:
        return refusal, [s.run(x["run_id"]) for x in s.runs()], len(moves)


def _counting(move, moves: list):
    def move_to(geometry):
        moves.append(geometry)
        return move(geometry)
    return move_to


def test_stage_refuses_a_setpoint_predicted_over_full_scale_before_any_motion(tmp_path):
    refusal, runs, moves = _list_scan(tmp_path, Geometry(50, 0, 50, 180))
    assert refusal is not None and len(refusal.strip().splitlines()) == 1, refusal
    assert "would saturate the detector" in refusal and "point 0 (50" in refusal and "integrate at most" in refusal
    assert runs == [] and moves == 0


def test_a_bluesky_run_with_saturated_readings_is_not_a_plain_completed(tmp_path):
    """Staged at a diffuse setpoint (accepted), the plan then reads the GGX peak: masked, and said."""
    refusal, runs, moves = _list_scan(tmp_path, Geometry(30, 0, 10, 180))
    assert refusal is None and moves > 0 and len(runs) == 1
    run = runs[0]
    assert run["status"] == "completed"
    reason = run["reason"] or ""
    assert "readings masked" in reason and "saturated)" in reason and not reason.startswith("0 of"), run


@pytest.mark.parametrize("integration_s, ok", [(0.05, True), (0.172, False)])
def test_bench_white_refuses_a_saturated_white_and_writes_nothing(tmp_path, integration_s, ok):
    """The white at 0/45 reads 0.22 sr^-1 x cos: at 0.172 s past full scale (at 0.05 s, 52 %)."""
    out = tmp_path / "white.csv"
    code, _, err = bench_cli("white", "--bench", _description(tmp_path, "lambert"), "--body", "virtual", "--out", out,
                             "--yes", "--integration-s", integration_s, "--averages", 2)
    if ok:
        assert code == 0 and out.exists(), err
        return
    assert code == 2 and len(err.strip().splitlines()) == 1 and not out.exists(), err
    assert "would saturate the detector" in err and "the white standard is predicted at" in err, err


def test_a_white_found_saturated_is_refused_as_a_reference():
    """The backstop after the prediction (a white read brighter than predicted, or a completed run's
    white taken by ``bench white --from-run``): any saturated band refuses it, naming the band."""
    from bench.calibration_chain import check_white_unsaturated
    from bench.core.calibration import Calibration, WhiteStandard
    from bench.core.errors import CalibrationRefused
    from bench.core.roles import Reading

    wl, s = np.array([450.0, 550.0, 650.0]), np.array([3e4, 5e4, 65535.0])

    def white(saturated):
        return Calibration(WhiteStandard(0.99), Reading(wl, s, np.array(saturated), 0.05, 2, timestamp=0.0))

    check_white_unsaturated("w", white([False, False, False]))
    with pytest.raises(CalibrationRefused, match="w is saturated in 1 of 3 bands .first at 650 nm. at integration_s = 0.05"):
        check_white_unsaturated("w", white([False, False, True]))
