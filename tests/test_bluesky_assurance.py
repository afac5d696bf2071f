"""``check_standards``: ``bench check`` through the RunEngine. Same seed, same day, same
standard: the Bluesky check run stores the very readings and score of ``bench check``, as a run
of kind ``check`` that ``bench chart`` and the scan gate read like the CLI's; refusals come before
the RunEngine sees anything.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.assurance import check_history
from bench.bluesky import connect
from bench.bluesky.assurance import check_standards
from bench.core.errors import InputError
from bench.store import RunStore
from tests.helpers.cli import run_main
from tests.test_assurance import CHECK, _bench

DRIFT = '[drift]\nstart = "2026-12-01"\nwhite_per_day = -0.01\n'


def test_a_bluesky_check_stores_bench_checks_readings_and_score_and_is_charted(RE_with_result, capsys, tmp_path):
    bench, store = _bench(tmp_path, assurance="refuse", drift=DRIFT), tmp_path / "s.sqlite"
    code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--seed", 4, "--date", "2026-12-04",
                              "--json")
    assert code == 0, err
    cli = json.loads(out)["checks"][0]
    (bs,) = RE_with_result(check_standards(bench, store=store, seed=4, date="2026-12-04", run_engine=RE_with_result)).plan_result
    assert bs["check"] == "grey tile" and bs["date"] == "2026-12-04" and bs["run"] != cli["run"]
    with RunStore(store) as s:
        info = s.run(bs["run"])
        a, b = s.readings(cli["run"]), s.readings(bs["run"])
    assert info["kind"] == "check" and info["status"] == "completed"
    assert info["meta"]["check"]["value"] == pytest.approx(bs["value"]) and info["meta"]["check"]["date"] == "2026-12-04"
    assert len(a) == len(b) == 6
    for c in ("idx", "theta_i", "theta_r", "wavelength_nm", "signal", "value", "std"):
        assert np.array_equal(a[c].to_numpy(), b[c].to_numpy(), equal_nan=True), c
    assert bs["value"] == cli["value"] and bs["readings"] == cli["readings"]
    # the white soiled 3 % by that day: the standard reads 1 / 0.97 of its model (noise ~0.3 %)
    assert bs["value"] == pytest.approx(1 / 0.97, rel=0.01) and not bs["agree"]
    with RunStore(store, create=False) as s:
        assert [h["run"] for h in check_history(s, "virtual", "grey tile")] == [cli["run"], bs["run"]]
    code, out, err = run_main(capsys, "show", bs["run"], "--store", store, "--json")
    shown = json.loads(out)
    assert code == 0 and shown["kind"] == "check" and shown["check"]["max_abs_E_n"] == pytest.approx(bs["max_abs_E_n"])
    # the same seed and day twice: a baseline without spread is refused in one line (it was a traceback)
    code, _, err = run_main(capsys, "chart", "--bench", bench, "--store", store)
    assert code == 2 and "first 2 check values are all" in err and len(err.strip().splitlines()) == 1
    (other,) = RE_with_result(check_standards(bench, store=store, seed=5, date="2026-12-04", run_engine=RE_with_result)).plan_result
    code, out, err = run_main(capsys, "chart", "--bench", bench, "--store", store, "--json")
    assert code == 0, err
    assert [r["run"] for r in json.loads(out)["charts"][0]["runs"]] == [cli["run"], bs["run"], other["run"]]


def test_a_scan_relies_on_a_bluesky_check_and_devices_lend_their_bench(RE_with_result, capsys, tmp_path):
    """The devices of the bench being checked: the standard is mounted on a bench of its own
    (theirs keeps its specimen), and the scan gate of that day finds the Bluesky check."""
    bench, store = _bench(tmp_path, assurance="refuse"), tmp_path / "s.sqlite"
    plan = tmp_path / "plan.toml"
    plan.write_text('name = "tiny"\nkind = "list"\nintegration_s = 0.02\npoints = [[30, 0, 20, 180]]\n')
    scan = ("scan", plan, "--bench", bench, "--store", store, "--seed", 5, "--date", "2026-12-02", "--quiet")
    code, _, err = run_main(capsys, *scan)
    assert code == 2 and "'grey tile' was never measured" in err
    with connect(bench, run_engine=RE_with_result, seed=2) as devs:
        (c,) = RE_with_result(check_standards(devs, store=store, date="2026-12-02")).plan_result
        assert devs.bench.config["specimen"]["spec"] == "lambert:albedo=0.8"  # the bench's own, untouched
    assert c["agree"] and abs(c["value"] - 1) < 0.02
    with RunStore(store, create=False) as s:
        assert s.run(c["run"])["meta"]["specimen"] == "lambert:albedo=0.5"  # the standard was measured
    code, out, err = run_main(capsys, *scan)
    assert code == 0, err
    code, out, _ = run_main(capsys, "show", out.strip().splitlines()[-1], "--store", store, "--json")
    assert json.loads(out)["assurance"]["checks"]["grey tile"]["run"] == c["run"]


def test_check_standards_refuses_before_the_run_engine_sees_anything(RE_with_result, tmp_path):
    bench, store = _bench(tmp_path), tmp_path / "s.sqlite"
    with pytest.raises(InputError, match="has no check named 'nope'; its checks: grey tile"):
        check_standards(bench, store=store, checks=["nope"], run_engine=RE_with_result)
    certified = tmp_path / "certified.toml"
    certified.write_text(bench.read_text().replace('specimen = "lambert:albedo=0.5"', "reference = 0.16"))
    with pytest.raises(InputError, match="gives only a certified reference: the virtual body simulates"):
        check_standards(certified, store=store, run_engine=RE_with_result)
    with pytest.raises(InputError, match="date must be YYYY-MM-DD"):
        check_standards(bench, store=store, date="12/04/2026", run_engine=RE_with_result)
    (tmp_path / "real").mkdir()
    real = _bench(tmp_path / "real", "emulated.toml")
    real.write_text(real.read_text() + CHECK.replace("grey tile", "white tile"))
    with pytest.raises(InputError, match=r"a real bench measures the one standard mounted on it; name it with "
                                         r"checks=\[...\] \(its checks: grey tile, white tile\)"):
        check_standards(real, store=store, body="real", run_engine=RE_with_result)
    assert not store.exists()  # nothing opened, nothing written


@pytest.mark.slow
def test_the_emulated_body_checks_through_the_run_engine_as_bench_check_does(RE_with_result, capsys, tmp_path):
    bench, store = _bench(tmp_path, "emulated.toml", drift=DRIFT), tmp_path / "e.sqlite"
    code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--seed", 4, "--date", "2026-12-06",
                              "--json")
    assert code == 0, err
    cli = json.loads(out)["checks"][0]
    (bs,) = RE_with_result(check_standards(bench, store=store, seed=4, date="2026-12-06", run_engine=RE_with_result)).plan_result
    with RunStore(store) as s:
        assert s.run(bs["run"])["kind"] == "check"
    # the emulator's noise is its own (its processes are seeded per start): the same drift, within noise
    assert bs["value"] == pytest.approx(cli["value"], rel=3e-3) and bs["value"] == pytest.approx(1 / 0.95, rel=0.01)


@pytest.mark.slow  # a real Tiled server: ~10 CPU-s of imports and start-up
def test_check_runs_are_served_by_bench_serve_and_read_with_tiled_clients_default_readers(RE_with_result, capsys, tmp_path):
    """A check run of bench check and one of check_standards, served like any run: found by kind,
    their check (value, max |E_n|, date) in the start document, their readings in ``primary``."""
    import os
    import subprocess
    import sys

    from tiled.client import from_uri
    from tiled.queries import Key

    from tests.helpers.cli import ROOT

    bench, store = _bench(tmp_path), tmp_path / "s.sqlite"
    code, out, err = run_main(capsys, "check", "--bench", bench, "--store", store, "--seed", 1, "--date", "2026-12-01",
                              "--json")
    assert code == 0, err
    (bs,) = RE_with_result(check_standards(bench, store=store, seed=2, date="2026-12-02", run_engine=RE_with_result)).plan_result
    runs = {json.loads(out)["checks"][0]["run"]: "2026-12-01", bs["run"]: "2026-12-02"}
    env = {"PYTHONPATH": str(ROOT), **{k: v for k, v in os.environ.items() if k != "PYTHONPATH"}}
    server = subprocess.Popen([sys.executable, "-m", "bench.cli", "serve", "--store", str(store), "--port", "0",
                               "--json", "--max-seconds", "300"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True, env=env)
    try:
        line = server.stdout.readline()
        assert line, server.stderr.read()[-3000:]
        client = from_uri(json.loads(line)["uri"])
        served = client.search(Key("start.kind") == "check")
        assert len(served) == 2
        with RunStore(store, create=False) as s:
            for run in served.values():
                start = run.metadata["start"]
                rid = start["run_id"]
                check = s.run(rid)["meta"]["check"]
                assert start["kind"] == "check" and start["specimen"] == "lambert:albedo=0.5"
                assert start["goniobench"]["check"]["date"] == runs[rid] == check["date"]
                assert start["goniobench"]["check"]["value"] == check["value"]
                primary = run["primary"].read()  # one event per point, arrays over wavelength_nm
                got = np.sort(np.asarray(primary["value"], float).ravel())
                assert got.size == 6 and np.array_equal(got, np.sort(s.readings(rid)["value"].to_numpy(float)))
    finally:
        server.terminate()
        server.wait(20)
