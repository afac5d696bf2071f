"""Sweeps: spec and keys, in-process vs Dask (bitwise equal), a killed worker, interrupt and resume."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.cli import main
from bench.core.errors import ConfigError, RunInterrupted, StoreError
from bench.store import RunStore
from store_probe import kill_once_committed
from bench.sweep import (TASK_COLUMNS, TaskResult, load_sweep, resume_sweep, run_sweep, run_task, series_seed,
                         sweep_from_dict, sweep_readings, task_key)
from bench.sweep.executor import _Sink

ROOT = Path(__file__).parent.parent
SWEEPS = ROOT / "fixtures" / "sweeps"

# 2 specimens x 2 incidences x 2 wavelengths = 8 tasks of ~0.1-0.3 s each (rays counted)
SMALL = {"sweep": {"name": "small", "seed": 99, "instrument": "gonio",
                   "specimens": ["lambert:albedo=0.5", "lambert:reflectance=0.4,transmittance=0.3"],
                   "incidences": [10, [50, 90]], "collectors": ["equal-psa:3x8"], "wavelengths": [500, 600],
                   "rays": 2_000_000, "method": "rays", "wavelengths_per_task": 1}}


def _science(store, run_id):
    """The stored results without what legitimately differs between executions (who, when)."""
    return store.readings(run_id).drop(columns=["t_start", "t_end"]).reset_index(drop=True)


def _assert_once(store, run_id, n_tasks, rows_per_task):
    pts = store.points(run_id)
    assert sorted(pts["idx"]) == list(range(n_tasks))  # every task, each exactly once
    assert (pts["n_readings"] == rows_per_task).all()
    assert len(store.readings(run_id)) == n_tasks * rows_per_task
    assert store.run(run_id)["status"] == "completed"


# --- spec ------------------------------------------------------------------------------------


def test_fixtures_load_into_the_documented_task_counts():
    assert len(load_sweep(SWEEPS / "gonio-product.toml")) == 2 * 3 * 1 * 3  # specimens x incidences x wl
    assert len(load_sweep(SWEEPS / "spectro-colorchecker.toml")) == 4 * 3  # whole spectra per task
    tasks = load_sweep(SWEEPS / "gonio-tasks.toml").tasks
    assert len(tasks) == 1 + 1 + 1  # a whole spectrum per task by default
    assert tasks[1].collector == "equal-solid-angle:6x24" and (tasks[1].theta_i, tasks[1].phi_i) == (45.0, 90.0)
    assert tasks[2].rays == 500_000 and tasks[0].rays == 1_000_000  # [[task]] overrides [sweep]
    assert tasks[2].wavelengths == (450.0, 550.0, 650.0)


@pytest.mark.parametrize("change,needle", [
    ({"colour": 1}, "colour"),
    ({"instrument": "camera"}, "instrument"),
    ({"incidences": [95]}, "theta_i"),
    ({"specimens": ["colorchecker:dark skin"], "wavelengths": "300:400:50"}, "300"),
    ({"specimens": ["lambert:albedo=0.5", "lambert: albedo = 0.5"]}, "same measurement"),
    ({"rays": 0}, "rays"),
    ({"method": "quick"}, "method"),
    ({"geometries": ["8/d"]}, "geometries"),
])
def test_bad_sweeps_are_refused_naming_the_problem(change, needle):
    d = {"sweep": {**SMALL["sweep"], **change}}
    with pytest.raises(ConfigError, match=needle):
        sweep_from_dict(d)


def test_seeds_come_from_the_series_parameters_not_the_order_or_index():
    a = sweep_from_dict(SMALL)
    rev = {"sweep": {**SMALL["sweep"], "specimens": SMALL["sweep"]["specimens"][::-1],
                     "incidences": SMALL["sweep"]["incidences"][::-1]}}
    b = sweep_from_dict(rev)
    by_params = {(t.specimen, t.theta_i, t.wavelengths): t.seed for t in a.tasks}
    assert {(t.specimen, t.theta_i, t.wavelengths): t.seed for t in b.tasks} == by_params
    assert [t.idx for t in a.tasks] == list(range(8))
    assert len({t.seed for t in a.tasks}) == 4  # one per series; wavelengths are keyed by the instrument
    t = a.tasks[0]
    params = {"instrument": "gonio", "specimen": t.specimen, "beam": "collimated", "incidence": [10.0, 0.0],
              "collector": "equal-psa:3x8", "method": "rays", "rays": 2_000_000}
    assert t.key == task_key(params) and t.seed == series_seed(99, t.key)
    other_seed = sweep_from_dict({"sweep": {**SMALL["sweep"], "seed": 100}})
    assert other_seed.tasks[0].seed != t.seed


def test_results_do_not_depend_on_grouping_or_numba_threads(tmp_path):
    cheap = {"sweep": {**SMALL["sweep"], "rays": 200_000, "specimens": SMALL["sweep"]["specimens"][:1]}}
    one = sweep_from_dict(cheap)  # one wavelength per task
    grouped = sweep_from_dict({"sweep": {**cheap["sweep"], "wavelengths_per_task": 0}})
    assert len(one) == 4 and len(grouped) == 2
    with RunStore(tmp_path / "s.sqlite") as store:
        a = run_sweep(one, store).run_id
        b = run_sweep(grouped, store).run_id
        cols = ["theta_i", "phi_i", "wavelength_nm", "theta_r", "phi_r", "count", "N", "value"]
        ra = _science(store, a).sort_values(cols[:5]).reset_index(drop=True)[cols]
        rb = _science(store, b).sort_values(cols[:5]).reset_index(drop=True)[cols]
        pd.testing.assert_frame_equal(ra, rb, check_exact=True)
    t = one.tasks[1]
    r1, r2 = run_task(t, numba_threads=1), run_task(t, numba_threads=2)
    pd.testing.assert_frame_equal(r1.rows, r2.rows, check_exact=True)
    # the stored seed reproduces the series with the plain instrument
    from virtual.goniophotometer import VirtualGoniophotometer

    g = VirtualGoniophotometer(t.specimen, collector=t.collector, rays=t.rays, seed=t.seed, method="rays")
    rec = g.measure_bsdf(t.theta_i, t.phi_i, list(t.wavelengths))
    assert rec.table["count"].tolist() == r1.rows["count"].tolist()


def test_spectro_sweep_stores_reflectance_and_transmittance_with_intervals(tmp_path):
    d = {"sweep": {"seed": 5, "instrument": "spectro", "specimens": ["lambert:reflectance=0.4,transmittance=0.3"],
                   "geometries": ["8/d", "45/0"], "wavelengths": "450:650:100", "rays": 40_000}}
    spec = sweep_from_dict(d)
    with RunStore(tmp_path / "s.sqlite") as store:
        rid = run_sweep(spec, store).run_id
        df = sweep_readings(store, rid)
    assert len(df) == 2 * 3 * 2
    assert set(df["quantity"]) == {"reflectance", "reflectance factor", "transmittance"}
    assert df["worker"].str.startswith("in-process").all() and (df["compute_s"] > 0).all()
    assert set(df["geometry"]) == {"8/d", "45/0"} and set(df["hemisphere"]) == {"R", "T"}
    assert ((df["ci_lo"] <= df["value"]) & (df["value"] <= df["ci_hi"])).all()
    hemi = df[(df["geometry"] == "8/d")]
    r, t = hemi[hemi.hemisphere == "R"], hemi[hemi.hemisphere == "T"]
    # binomial standard errors of 40,000 rays: 0.4 and 0.3 within 5 sigma
    assert np.all(np.abs(r["value"] - 0.4) < 5 * np.sqrt(0.4 * 0.6 / 40_000))
    assert np.all(np.abs(t["value"] - 0.3) < 5 * np.sqrt(0.3 * 0.7 / 40_000))
    assert np.allclose(r["std"], np.sqrt(r["value"] * (1 - r["value"]) / r["N"]))


# --- store semantics ---------------------------------------------------------------------------


def test_a_result_already_stored_is_skipped_never_stored_twice(tmp_path):
    spec = sweep_from_dict({"sweep": {**SMALL["sweep"], "rays": 10_000}})
    res = run_task(spec.tasks[0])
    with RunStore(tmp_path / "s.sqlite") as store:
        rid = store.create_run(kind="sweep", plan=spec.source, seed=spec.seed, n_planned=len(spec))

        class Bar:
            def update(self, n):
                pass

        sink = _Sink(store, rid, set(), Bar(), None)
        sink.put(res)
        sink.put(res)  # a retried task's second answer
        assert sink.run == 1 and sink.duplicates == 1
        other = _Sink(store, rid, set(), Bar(), None)  # e.g. a second client on the same store
        other.put(TaskResult(res.idx, res.geometry, res.rows, res.t_start, res.t_end, "x", 0.0))
        assert other.duplicates == 1 and other.run == 0
        assert store.points(rid)["idx"].tolist() == [0]


def test_an_interrupted_sweep_resumes_to_the_results_of_an_uninterrupted_one(tmp_path):
    spec = sweep_from_dict({"sweep": {**SMALL["sweep"], "rays": 100_000}})
    with RunStore(tmp_path / "s.sqlite") as store:
        full = run_sweep(spec, store).run_id

        def ctrl_c(k, idx):
            if k == 3:
                raise KeyboardInterrupt

        with pytest.raises(RunInterrupted, match="--resume"):
            run_sweep(spec, store, on_task=ctrl_c)
        rid = store.runs()[-1]["run_id"]
        assert store.run(rid)["status"] == "interrupted" and store.done_indices(rid) == {0, 1, 2}
        res = resume_sweep(store, rid)
        assert (res.tasks_run, res.tasks_done, res.status) == (5, 8, "completed")
        _assert_once(store, rid, 8, 2 * 3 * 8)
        pd.testing.assert_frame_equal(_science(store, rid), _science(store, full), check_exact=True)
        with pytest.raises(StoreError, match="completed"):
            resume_sweep(store, rid)


@pytest.mark.slow  # a sweep killed and resumed in subprocesses (6-36 s under load)
def test_a_sigkilled_sweep_process_resumes_to_the_uninterrupted_results(tmp_path, reference):
    toml = tmp_path / "small.toml"
    sw = SMALL["sweep"]
    toml.write_text("[sweep]\n" + "\n".join(f"{k} = {json.dumps(v)}" for k, v in sw.items()) + "\n")
    db = tmp_path / "crash.sqlite"
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sweep", str(toml), "--store", str(db), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    kill_once_committed(proc, db, 2)
    proc.wait(10)
    with RunStore(db) as store:
        rid = store.runs()[0]["run_id"]
        done = store.done_indices(rid)
        assert store.run(rid)["status"] == "running"  # killed: nobody recorded an end
        assert (store.readings(rid).groupby("idx").size() == 2 * 3 * 8).all()  # committed tasks are whole
        assert 2 <= len(done) < 8, "the kill did not land mid-sweep: the test did not test a crash"
        res = resume_sweep(store, rid)
        assert res.tasks_run == 8 - len(done)
        _assert_once(store, rid, 8, 2 * 3 * 8)
        pd.testing.assert_frame_equal(_science(store, rid), reference, check_exact=True)


def test_cli_runs_a_sweep_and_resumes_by_run_id(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    code = main(["sweep", str(SWEEPS / "gonio-tasks.toml"), "--store", str(store), "--json", "-q"])
    out = capsys.readouterr().out
    assert code == 0
    d = json.loads(out)
    assert d["status"] == "completed" and d["tasks_done"] == d["tasks_planned"] == 3 and d["executor"] == "in-process"
    # resuming a completed run is a mistake the user can fix: exit 2 (the exit-status policy)
    assert main(["sweep", "--resume", d["run_id"], "--store", str(store)]) == 2
    assert main(["sweep", str(SWEEPS / "missing.toml"), "--store", str(store)]) == 2
    assert main(["sweep", "--store", str(store)]) == 2
    capsys.readouterr()


# --- Dask -------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """SMALL run in-process (numba on all threads): what every executor must store."""
    with RunStore(tmp_path_factory.mktemp("ref") / "s.sqlite") as store:
        return _science(store, run_sweep(sweep_from_dict(SMALL), store).run_id)


@pytest.fixture(scope="module")
def cluster_client():
    import distributed  # noqa: F401 - the [scale] extra, installed by make test: a hard requirement
    from bench.sweep import dask_client

    with dask_client(workers=2, dashboard_address="127.0.0.1:0") as client:
        yield client


@pytest.mark.slow  # starts a two-process Dask cluster (~7 CPU-s)
def test_in_process_and_a_two_process_local_cluster_store_identical_results(tmp_path, reference, cluster_client):
    spec = sweep_from_dict(SMALL)
    with RunStore(tmp_path / "s.sqlite") as store:
        dist = run_sweep(spec, store, client=cluster_client)
        assert dist.executor == "dask" and dist.tasks_done == 8
        _assert_once(store, dist.run_id, 8, 2 * 3 * 8)
        pd.testing.assert_frame_equal(_science(store, dist.run_id), reference, check_exact=True)
        tidy = sweep_readings(store, dist.run_id)
        assert tidy["worker"].str.startswith("tcp://").all() and tidy["specimen"].notna().all()
        assert set(TASK_COLUMNS) - {"geometry", "quantity"} <= set(tidy.columns)
        assert store.run(dist.run_id)["meta"]["executions"][0]["workers"] == 2


@pytest.mark.slow  # a Dask scheduler started for one CLI run (12 s under load)
def test_cli_points_a_sweep_at_an_existing_scheduler_and_prints_the_dashboard(tmp_path, capsys, cluster_client):
    address = cluster_client.scheduler_info()["address"]
    store = tmp_path / "s.sqlite"
    code = main(["sweep", str(SWEEPS / "gonio-tasks.toml"), "--scheduler", address, "--store", str(store), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    d = json.loads(out)
    assert d["executor"] == "dask" and d["tasks_done"] == 3
    assert f"Dask scheduler {address} with 2 workers; dashboard: http" in err
    with RunStore(store) as s:
        assert s.run(d["run_id"])["meta"]["executions"][0]["scheduler"] == address


def test_a_worker_killed_mid_sweep_loses_and_duplicates_nothing(tmp_path, reference, cluster_client):
    spec = sweep_from_dict(SMALL)
    killed: dict = {}

    def kill_a_busy_worker(k, idx):
        if k != 1:
            return
        busy = {w: keys for w, keys in cluster_client.processing().items() if keys}
        assert busy, "no task running when the first result arrived"
        addr = sorted(busy)[0]
        pid = cluster_client.run(os.getpid, workers=[addr])[addr]
        killed.update(addr=addr, keys=set(busy[addr]))
        os.kill(pid, signal.SIGKILL)

    with RunStore(tmp_path / "s.sqlite") as store:
        res = run_sweep(spec, store, client=cluster_client, on_task=kill_a_busy_worker)
        assert killed and res.status == "completed"
        _assert_once(store, res.run_id, 8, 2 * 3 * 8)
        got = sweep_readings(store, res.run_id)
        rerun = {int(k.rsplit("-", 1)[1]) for k in killed["keys"]}
        # the tasks the dead worker held were recomputed elsewhere, and equal bit for bit
        assert any(killed["addr"] not in set(got.loc[got["idx"] == i, "worker"]) for i in rerun)
        pd.testing.assert_frame_equal(_science(store, res.run_id), reference, check_exact=True)


def test_common_random_numbers_share_one_stream_across_specimens():
    """By default each specimen of a sweep draws its own rays; with ``common_random_numbers``
    two specimens of otherwise equal series share seed and streams, so counts of nearly equal
    models move together (their difference has a far smaller spread). Checked on the counts:
    lambert 0.50 vs 0.51 over 20 wavelengths, 20,000 rays each."""
    import numpy as np

    from bench.sweep.spec import sweep_from_dict
    from bench.sweep.task import run_task

    def counts(crn):
        spec = sweep_from_dict({"sweep": {"name": "crn", "seed": 11, "instrument": "spectro",
                                          "specimens": ["lambert:reflectance=0.5", "lambert:reflectance=0.51"],
                                          "geometries": ["8/d"], "wavelengths": "400:590:10", "rays": 20_000,
                                          "common_random_numbers": crn}})
        a, b = spec.tasks
        assert (a.seed == b.seed) is crn and a.common_random_numbers is crn
        ra, rb = (run_task(t).rows for t in (a, b))
        return (ra[ra.hemisphere == "R"]["count"].to_numpy(float), rb[rb.hemisphere == "R"]["count"].to_numpy(float))

    a, b = counts(True)
    shared = np.std(b - a)
    a, b = counts(False)
    apart = np.std(b - a)
    # independent: sd(diff) ~ sqrt(2 N p (1-p)) ~ 100 counts; common: ~ sqrt(N 0.01) ~ 14
    assert shared < 40 < apart


def test_a_two_specimen_sweep_exports_one_file_per_specimen_reflection_only_in_astm(tmp_path, capsys):
    """Each file holds one specimen, named in its rows (CSV) and its SAMPLE_NAME (ASTM); the ASTM
    BRDF holds the reflection side only (the transmission rows are there with --hemisphere T)."""
    two = {"sweep": {**SMALL["sweep"], "rays": 200_000, "incidences": [10], "wavelengths": [500]}}
    with RunStore(tmp_path / "s.sqlite") as store:
        rid = run_sweep(sweep_from_dict(two), store).run_id
    specs = two["sweep"]["specimens"]
    assert main(["export", rid, "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "w.csv")]) == 0
    paths = capsys.readouterr().out.split()
    assert len(paths) == 2
    for path, spec in zip(paths, specs):
        assert set(pd.read_csv(path).specimen) == {spec}
    assert main(["export", rid, "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "w.astm.csv")]) == 0
    for path, spec in zip(capsys.readouterr().out.split(), specs):
        text = Path(path).read_text()
        assert spec in text.split("\n")[1] and "SCATTER_TYPE BRDF" in text
        rows = [ln for ln in text.splitlines() if ln[:1].isdigit() or ln[:1] == "-"]
        assert rows and all(float(ln.split(",")[2]) <= np.pi / 2 + 1e-9 for ln in rows)  # theta_s: reflection
    assert main(["export", rid, "--store", str(tmp_path / "s.sqlite"), "--out", str(tmp_path / "t.astm.csv"),
                 "--hemisphere", "T"]) == 0
    t_paths = capsys.readouterr().out.split()
    assert "SCATTER_TYPE BTDF" in Path(t_paths[1]).read_text()
