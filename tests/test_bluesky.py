"""Every bench as Bluesky / ophyd-async devices, on the virtual bench: protocols,
standard plans, our plans, documents into our store, equivalence with ``bench scan``, refusals
and faults. The emulated bench's tests are in test_bluesky_emulated.py.
"""

from __future__ import annotations

import asyncio
import json
import math
import threading

import bluesky.plan_stubs as bps
import bluesky.plans as bp
import numpy as np
import pytest
from bluesky.utils import FailedStatus

from bench.bluesky import connect, plan_from_toml
from bench.bluesky.goniometer import AXES
from bench.cli import main as bench_cli
from bench.core.errors import DeviceTimeoutError, GeometryError, PlanError
from bench.core.geometry import Geometry
from bench.plans import load_plan, order_for_travel
from bench.runner import run_scan
from bench.store import RunStore
from bluesky_support import BENCHES, IN_PLANE, STANDARD, check_protocols, reset_reflectance, run, spy


def test_every_virtual_device_satisfies_the_bluesky_protocols(virtual):
    check_protocols(virtual)
    assert virtual.light is not None


def test_spectrometer_describes_one_array_with_its_wavelength_axis(RE, virtual):
    wl = virtual.bench.spectrometer.wavelengths
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180), virtual.spectrometer.integration_s, 0.1))
    docs, _ = run(RE, virtual, bp.count([virtual.spectrometer]))
    desc = docs.of("descriptor")[0]
    key = desc["data_keys"]["spectrometer-spectrum"]
    assert key["dtype"] == "array" and key["shape"] == [wl.size] and key["units"] == "counts"
    assert key["dims"] == ["wavelength_nm"]
    assert desc["data_keys"]["spectrometer-saturated"]["shape"] == [wl.size]
    assert desc["data_keys"]["spectrometer-dark"]["dtype"] == "boolean"
    conf = desc["configuration"]["spectrometer"]
    assert np.array_equal(conf["data"]["spectrometer-wavelength_nm"], wl)
    assert conf["data_keys"]["spectrometer-wavelength_nm"]["units"] == "nm"
    assert conf["data"]["spectrometer-integration_s"] == 0.1 and conf["data"]["spectrometer-averages"] == 1
    # the configured integration time is the one acquired with: the virtual signal is linear in it
    # (two fresh benches of one seed: repeated triggers at one geometry draw counts of their own)
    spectra = []
    for t in (0.1, 0.2):
        with connect(BENCHES / "virtual.toml", run_engine=RE, seed=3) as fresh:
            RE(bps.mv(fresh.goniometer, Geometry(30, 0, 20, 180), fresh.spectrometer.integration_s, t))
            docs, _ = run(RE, fresh, bp.count([fresh.spectrometer]))
            spectra.append(np.asarray(docs.of("event")[0]["data"]["spectrometer-spectrum"]))
    first, second = spectra
    assert np.allclose(second, 2 * first) and np.all(first > 0)
    RE(bps.mv(virtual.light, "off"))
    docs, _ = run(RE, virtual, bp.count([virtual.spectrometer]))
    RE(bps.mv(virtual.light, "on"))
    ev = docs.of("event")[0]["data"]
    assert ev["spectrometer-dark"] is True and not np.any(ev["spectrometer-spectrum"])


@pytest.mark.parametrize("name", list(STANDARD))
def test_standard_plans_succeed_on_the_virtual_bench_and_land_in_the_store(RE, virtual, tmp_path, name):
    reset_reflectance(RE, virtual)
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    plan, n_events, n_moves = STANDARD[name](virtual)
    moves0 = virtual.goniometer.mover.moves
    docs, writer = run(RE, virtual, plan, tmp_path / "s.sqlite")
    stop = docs.of("stop")[0]
    assert stop["exit_status"] == "success" and stop["num_events"]["primary"] == n_events
    assert len(docs.of("event")) == n_events
    # axes set together move once per point (coalesced); rel_scan also returns to the start
    assert virtual.goniometer.mover.moves - moves0 == n_moves
    with RunStore(tmp_path / "s.sqlite") as store:
        (info,) = store.runs()
        assert info["kind"] == "bluesky" and info["status"] == "completed" and info["points_done"] == n_events
        run_info = store.run(info["run_id"])
        assert run_info["meta"]["bluesky_start"]["plan_name"] == name
        assert run_info["meta"]["bluesky_start"]["uid"] == docs.of("start")[0]["uid"]
        assert run_info["bench"]["kind"] == "virtual" and run_info["seed"] == 3
        df = store.readings(info["run_id"])
        assert len(df) == n_events * virtual.bench.spectrometer.wavelengths.size
        if name != "rel_scan":  # calibrated: a Lambertian of albedo 0.8 within 5 std of 0.8/pi
            z = (df["value"] - 0.8 / math.pi) / df["std"]
            assert np.all(np.abs(z) < 5)
        else:  # the spectrometer alone: signals, values masked with the reason
            assert df["value"].isna().all()
            assert (df["extra"].map(lambda e: e["mask"]) == "no white reference").all()


def test_the_signed_theta_r_axis_views_across_the_normal(RE, virtual):
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    RE(bps.mv(virtual.goniometer.theta_r, -20))
    assert virtual.goniometer.mover.reached == Geometry(30, 0, 20, 0)
    # locate() is a coroutine: run it in the RunEngine's loop
    where = asyncio.run_coroutine_threadsafe(virtual.goniometer.theta_r.locate(), RE.loop).result(5)
    assert where == {"setpoint": -20.0, "readback": -20.0}


def test_a_refused_target_fails_the_status_naming_the_rule_before_any_motion(RE, virtual):
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    moves = spy(virtual.bench.goniometer, "move_to")
    try:
        with pytest.raises(FailedStatus) as ei:
            RE(bps.mv(virtual.goniometer.theta_i, 95))
        assert isinstance(ei.value.__cause__, GeometryError)
        assert str(ei.value.__cause__).startswith("source_hemisphere: ")  # the arm's rule
        with pytest.raises(FailedStatus):
            RE(bps.mv(virtual.goniometer, [95, 0, 20, 180]))
    finally:
        moves.restore()
    assert moves == []
    assert virtual.goniometer.mover.target["theta_i"] == 30.0  # the last accepted request stays


def test_every_driver_call_runs_on_the_benchs_one_worker_thread(RE, virtual):
    reset_reflectance(RE, virtual, dark="per-point")
    moves = spy(virtual.bench.goniometer, "move_to")
    acquisitions = spy(virtual.bench.spectrometer, "acquire")
    try:
        run(RE, virtual, bp.scan([virtual.reflectance, virtual.spectrometer], virtual.goniometer.theta_r, 10, 30, 3))
    finally:
        moves.restore()
        acquisitions.restore()
    threads = {t for _, t in moves + acquisitions}
    assert len(moves) == 3 and len(acquisitions) >= 9  # dark + signal per point, and the spectrometer
    assert threads == {virtual.worker.thread}
    assert virtual.worker.thread.name.startswith("goniobench-") and virtual.worker.thread is not threading.main_thread()


def test_list_scan_of_the_in_plane_plan_equals_bench_scan_and_compares_as_identical(RE, tmp_path, capsys):
    """Same seed, same points, same settings: the Bluesky path stores the very values of ``bench scan``
    (on a freshly connected bench: repeated triggers at one geometry draw counts of their own, so the
    module's bench, which earlier tests triggered, would read other counts)."""
    plan = load_plan(IN_PLANE)
    db = tmp_path / "s.sqlite"
    from bench.config import load_bench

    with load_bench(BENCHES / "virtual.toml", seed=3) as bench, RunStore(db) as store:
        scan_id = run_scan(bench, plan, store, seed=3).run_id
    with connect(BENCHES / "virtual.toml", run_engine=RE, seed=3) as virtual:  # fresh: first triggers
        _list_scan_equals(RE, virtual, plan, db, scan_id, tmp_path, capsys)


def _list_scan_equals(RE, virtual, plan, db, scan_id, tmp_path, capsys):
    reset_reflectance(RE, virtual, plan.integration_s, plan.averages, plan.dark, plan.white)
    cols = {a: [getattr(g, a) for g in plan.points] for a in AXES}
    axes = virtual.goniometer.axes
    moves0 = virtual.goniometer.mover.moves
    docs, writer = run(RE, virtual, bp.list_scan([virtual.reflectance], *[x for a in AXES for x in (axes[a], cols[a])]),
                       db)
    assert docs.of("stop")[0]["exit_status"] == "success" and len(docs.of("event")) == len(plan)
    assert virtual.goniometer.mover.moves - moves0 == len(plan)  # four axes set per point, one move each
    (bs_id,) = writer.run_ids
    with RunStore(db) as store:
        key = ["theta_i", "phi_i", "theta_r", "phi_r", "wavelength_nm"]
        a = store.readings(scan_id).sort_values(key).reset_index(drop=True)
        b = store.readings(bs_id).sort_values(key).reset_index(drop=True)
    assert len(a) == len(b) == len(plan) * 3
    for c in key + ["signal", "dark", "white", "value", "std", "ci_lo", "ci_hi", "saturated"]:
        assert np.array_equal(a[c].to_numpy(), b[c].to_numpy(), equal_nan=True), c
    assert a["extra"].tolist() == b["extra"].tolist()  # reflectance factor, mask, integration, averages
    code = bench_cli(["compare", scan_id, bs_id, "--store", str(db), "--out", str(tmp_path / "rep"), "--json",
                      "--no-figures"])
    summary = json.loads(capsys.readouterr().out)
    assert code == 0
    s = summary["candidates"][next(iter(summary["candidates"]))]
    assert s["n_points"] == len(a) and s["rmse"] == 0.0 and s["max_abs"] == 0.0
    assert s["fraction_within_uncertainty"] == 1.0


def test_plan_from_toml_validates_orders_like_the_runner_and_stores_bench_scans_values(RE, tmp_path):
    plan = load_plan(IN_PLANE)
    db = tmp_path / "s.sqlite"
    from bench.config import load_bench

    with load_bench(BENCHES / "virtual.toml", seed=3) as bench, RunStore(db) as store:
        scan_id = run_scan(bench, plan, store, seed=3).run_id
    with connect(BENCHES / "virtual.toml", run_engine=RE, seed=3) as virtual:  # fresh: first triggers
        moves = spy(virtual.bench.goniometer, "move_to")
        try:
            docs, writer = run(RE, virtual, plan_from_toml(IN_PLANE, virtual), db)
        finally:
            moves.restore()
    order = order_for_travel(plan.points)
    assert [args[0] for args, _ in moves] == [plan.points[i] for i in order]  # one move per point, travel order
    events = docs.of("event")
    assert len(events) == len(plan) and docs.of("stop")[0]["exit_status"] == "success"
    start = docs.of("start")[0]
    assert start["goniobench_plan"]["order"] == order and start["num_points"] == len(plan)
    conf = docs.of("descriptor")[0]["configuration"]["reflectance"]["data"]
    assert conf["reflectance-dark_mode"] == "per-incidence" and conf["reflectance-averages"] == 2
    with RunStore(db) as store:
        a = store.readings(scan_id)
        b = store.readings(writer.run_ids[0])
        for c in ("idx", "theta_i", "theta_r", "phi_r", "wavelength_nm", "signal", "value", "std"):
            assert np.array_equal(a[c].to_numpy(), b[c].to_numpy(), equal_nan=True), c
        assert store.done_indices(writer.run_ids[0]) == set(range(len(plan)))
        cals = [store.run(r)["calibration"] for r in (scan_id, writer.run_ids[0])]
    for cal in cals:  # the same white and dark readings, taken at different times
        for reading in ("white", "white_dark"):
            cal[reading].pop("timestamp")
    assert cals[0] == cals[1]


def test_plan_from_toml_refuses_a_plan_whole_before_the_run_engine_sees_it(RE, virtual):
    moves = spy(virtual.bench.goniometer, "move_to")
    try:
        with pytest.raises(PlanError, match=r"1 of 3 points.*point 1 .*theta_i=95"):
            plan_from_toml({"kind": "list", "points": [[10, 0, 20, 180], [95, 0, 20, 180], [30, 0, 40, 180]]},
                           virtual)
    finally:
        moves.restore()
    assert moves == []


def test_bluesky_runs_are_listed_shown_and_exported_by_the_cli(RE, virtual, tmp_path, capsys):
    db = tmp_path / "s.sqlite"
    reset_reflectance(RE, virtual)
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    _, writer = run(RE, virtual, bp.scan([virtual.reflectance], virtual.goniometer.theta_r, 10, 50, 3), db)
    (rid,) = writer.run_ids
    assert bench_cli(["runs", "--store", str(db), "--json"]) == 0
    (listed,) = json.loads(capsys.readouterr().out)
    assert listed["run_id"] == rid and listed["kind"] == "bluesky" and listed["points_done"] == 3
    assert bench_cli(["show", rid, "--store", str(db), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["status"] == "completed" and shown["geometry"]["theta_r"] == [10.0, 50.0]
    out = tmp_path / "r.csv"
    assert bench_cli(["export", rid, "--store", str(db), "--format", "csv", "--out", str(out)]) == 0
    capsys.readouterr()
    assert len([line for line in out.read_text().splitlines() if line and not line.startswith("#")]) == 1 + 3 * 3


def test_a_faulting_goniometer_fails_the_run_with_its_message_and_is_stopped(RE, virtual, tmp_path):
    reset_reflectance(RE, virtual)
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    gonio = virtual.bench.goniometer
    original = gonio.move_to
    calls = {"n": 0}

    def faulty(g):
        calls["n"] += 1
        if calls["n"] == 3:
            raise DeviceTimeoutError("arm: move_to did not settle within 10 s")
        return original(g)

    gonio.move_to = faulty
    stops = spy(gonio, "stop")
    try:
        with pytest.raises(FailedStatus) as ei:
            run(RE, virtual, bp.scan([virtual.reflectance], virtual.goniometer.theta_r, 10, 50, 5), tmp_path / "s.db")
        assert isinstance(ei.value.__cause__, DeviceTimeoutError)  # the status failed with our typed error
    finally:
        stops.restore()
        del gonio.move_to
    assert len(stops) >= 1  # the RunEngine stopped the axis it had moved: nothing left moving
    with RunStore(tmp_path / "s.db") as store:
        (info,) = store.runs()
        assert info["status"] == "failed" and info["points_done"] == 2
        # worded as bench scan words a fault (the stop document's reason is the status's repr)
        assert info["reason"] == ("DeviceTimeoutError: arm: move_to did not settle within 10 s "
                                  "(device goniometer-theta_r)")
        stop = store.run(info["run_id"])["meta"]["bluesky_stop"]
    assert stop["exit_status"] == "fail" and "did not settle within 10 s" in stop["reason"]




def test_a_slow_driver_never_blocks_the_run_engines_loop(RE, virtual):
    """A move that takes 0.3 s runs in the worker: the loop keeps answering within 0.1 s."""
    import time

    gonio = virtual.bench.goniometer
    original = gonio.move_to
    gonio.move_to = lambda g: (time.sleep(0.3), original(g))[1]
    lags: list[float] = []
    done = threading.Event()

    async def probe() -> None:
        while not done.is_set():
            t0 = time.perf_counter()
            await asyncio.sleep(0.005)
            lags.append(time.perf_counter() - t0 - 0.005)

    task = asyncio.run_coroutine_threadsafe(probe(), RE.loop)
    try:
        t0 = time.perf_counter()
        RE(bp.list_scan([virtual.spectrometer], virtual.goniometer.theta_r, [10, 20, 30]))
        elapsed = time.perf_counter() - t0
    finally:
        done.set()
        task.result(5)
        del gonio.move_to
    assert elapsed > 0.9 and len(lags) > 50  # the moves did take their time, the probe kept running
    assert max(lags) < 0.1


def test_best_effort_callback_and_live_table_show_the_hinted_reflectance(RE, virtual, capsys):
    """Fast twin of the live-view block of docs/bluesky.md (test_readme.py runs it, slow): the hints name
    scalar value and uncertainty fields, BestEffortCallback plots them against the scanned axis,
    and LiveTable prints them by string field name."""
    import matplotlib

    matplotlib.use("Agg")
    from bluesky.callbacks import LiveTable
    from bluesky.callbacks.best_effort import BestEffortCallback

    assert sorted(virtual.reflectance.hints["fields"]) == ["reflectance-rf_mean", "reflectance-rf_mean_std"]
    assert sorted(virtual.spectrometer.hints["fields"]) == ["spectrometer-mean_counts", "spectrometer-peak_counts"]
    reset_reflectance(RE, virtual)
    bec = BestEffortCallback()
    fields = ["goniometer-theta_r", "reflectance-rf_mean", "reflectance-rf_mean_std"]
    tokens = [RE.subscribe(bec), RE.subscribe(LiveTable(fields))]
    capsys.readouterr()
    try:
        docs, _ = run(RE, virtual, bp.scan([virtual.reflectance], virtual.goniometer.theta_r, 10, 30, 2))
    finally:
        for token in tokens:
            RE.unsubscribe(token)
    (plots,) = bec._live_plots.values()
    assert set(plots) == {"reflectance-rf_mean", "reflectance-rf_mean_std"}
    events = docs.of("event")
    for ev in events:  # the scalar is the band mean of the calibrated reflectance factor
        rf, masked = np.asarray(ev["data"]["reflectance-reflectance_factor"]), ev["data"]["reflectance-masked"]
        assert ev["data"]["reflectance-rf_mean"] == pytest.approx(rf[~np.asarray(masked)].mean(), rel=1e-12)
        assert 0 < ev["data"]["reflectance-rf_mean_std"] < 0.1
    out = capsys.readouterr().out.splitlines()  # LiveTable's header has exactly our three fields
    assert any([c.strip() for c in line.split("|")[3:6]] == fields for line in out if line.count("|") == 6), out
