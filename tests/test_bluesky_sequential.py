"""``bench.bluesky.plans.sequential_fit``: the sequential design (``bench scan --sequential``) as a
Bluesky plan, on the virtual body of the emulated bench description with a plastic specimen.

The bench file is seeded at its top level (``seed = 5``), so the virtual body draws the same
readings on every path: the plan and :func:`sequential_scan` (the CLI's loop) must then make the
same designs and find the same estimates. Everything here is deterministic (fixed seed): no
statistical false alarm. Cost of the fast tests: one shared 1-s session of the plan (~5 CPU-s),
its rerun (~2 CPU-s: the fits again) and a 1-step session for the target (~1 CPU-s).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from bluesky import RunEngine

from bench.bluesky import connect
from bench.bluesky.plans import SEQUENTIAL_KEY, FIT_STREAM, sequential_fit
from bench.core.errors import InputError
from bench.store import RunStore
from bluesky_support import BENCHES, Docs

MODEL = "plastic:alpha=?,kd=?"
#: small and coarse: a 1-s budget on the 15-deg in-plane grid, one integration time
OPTIONS = {"seconds": 1.0, "step": 15.0, "integration_s": "0.01"}


def _bench_file(folder: Path) -> Path:
    text = (BENCHES / "emulated.toml").read_text().replace("lambert:albedo=0.8", "plastic:alpha=0.15,kd=0.5")
    p = folder / "plastic.toml"
    p.write_text("seed = 5\n" + text)
    return p


def _run(RE_with_result: RunEngine, plan) -> tuple[Docs, object]:
    docs = Docs()
    token = RE_with_result.subscribe(docs)
    try:
        result = RE_with_result(plan)
    finally:
        RE_with_result.unsubscribe(token)
    return docs, result.plan_result


@pytest.fixture(scope="module")
def devs(RE_with_result, tmp_path_factory):
    folder = tmp_path_factory.mktemp("sequential")
    d = connect(_bench_file(folder), run_engine=RE_with_result, body="virtual")
    d.folder = folder  # type: ignore[attr-defined]
    yield d
    d.close()


@pytest.fixture(scope="module")
def session(RE_with_result, devs):
    """One whole session of the plan into a fresh store: (documents, result, store)."""
    store = devs.folder / "bluesky.sqlite"
    docs, result = _run(RE_with_result, sequential_fit(MODEL, devs, store=store, **OPTIONS))
    return docs, result, store


def _fit_events(docs: Docs) -> list[dict]:
    fit_desc = {d["uid"] for d in docs.of("descriptor") if d["name"] == FIT_STREAM}
    return [e["data"] for e in docs.of("event") if e["descriptor"] in fit_desc]


@pytest.mark.slow  # the module's session: 3 designs, scans and fits (9-62 s under load)
def test_one_run_per_step_with_its_design_and_fit_stopping_at_the_budget(session):
    docs, result, store = session
    starts, stops, fits = docs.of("start"), docs.of("stop"), _fit_events(docs)
    assert len(result.steps) >= 2 and len(starts) == len(stops) == len(fits) == len(result.steps)
    assert all(s["exit_status"] == "success" for s in stops)
    assert result.stopped == "budget" and result.seconds <= OPTIONS["seconds"]
    prior = {"alpha": 0.1, "kd": 0.5}  # the family's declared defaults
    for k, (start, fit, step) in enumerate(zip(starts, fits, result.steps)):
        md = start[SEQUENTIAL_KEY]
        assert md["step"] == k and md["model"] == MODEL and md["criterion"] == "D"
        # designed at the prior, then at the previous step's estimate (kept inside the bounds)
        expected = prior if k == 0 else {n: fits[k - 1][f"fit-{n}"] for n in prior}
        assert md["designed_at"] == pytest.approx(expected, rel=1e-12)
        assert start["num_points"] == step.points
        assert fit["fit-model"] == MODEL and fit["fit-step"] == k
        for n in prior:
            assert fit[f"fit-{n}"] == step.estimates[n]
            assert fit[f"fit-{n}_lo"] < fit[f"fit-{n}"] < fit[f"fit-{n}_hi"]
            assert fit[f"fit-{n}_width"] == pytest.approx(step.widths[n], rel=1e-12)
        assert fit["fit-dof"] > 0 and fit["fit-chi2"] > 0 and 0 <= fit["fit-p_value"] <= 1
        assert json.loads(fit["fit-json"])["parameters"]["alpha"]["value"] == fit["fit-alpha"]
        assert fit["fit-stopped"] == ("" if k < len(fits) - 1 else "budget")
    with RunStore(store) as st:
        runs = [st.run(r["run_id"]) for r in st.runs()]
    assert [r["run_id"] for r in runs] == result.runs and all(r["status"] == "completed" for r in runs)
    assert [r["plan"]["name"] for r in runs] == [f"sequential-{starts[0][SEQUENTIAL_KEY]['session']}-{k}"
                                                 for k in range(len(runs))]


@pytest.mark.slow  # ~5-10 CPU-s: a whole CLI session (3 designs, 3 fits) besides the plan's
def test_the_plan_finds_what_bench_scan_sequential_finds(session, devs, tmp_path):
    """Same bench file (seeded), model, budget and options: the CLI's loop makes the same designs
    on the same readings, so the estimates agree to the optimizer's last digits."""
    from bench.config import load_bench
    from bench.identify.design_io import design_inputs
    from bench.identify.design_sequential import sequential_scan, session_candidates

    _, result, _ = session
    spec, point, settings = design_inputs(MODEL, None, None, OPTIONS["integration_s"])
    with load_bench(devs.folder / "plastic.toml", body="virtual") as bench, RunStore(tmp_path / "cli.sqlite") as st:
        assert bench.goniometer.seed == devs.seed == 5
        cli = sequential_scan(bench, st, spec, point, OPTIONS["seconds"], settings,
                            session_candidates(bench, OPTIONS["step"], settings), seed=bench.goniometer.seed)
    assert [s.points for s in cli.steps] == [s.points for s in result.steps]
    assert cli.seconds == pytest.approx(result.seconds, rel=1e-12)
    for n, v in cli.estimates.items():
        assert result.estimates[n] == pytest.approx(v, rel=1e-8)
        assert result.widths[n] == pytest.approx(cli.widths[n], rel=1e-6)


@pytest.mark.slow  # a sequential session to a target width (3-16 s under load)
def test_a_target_width_stops_early(session, RE_with_result, devs, tmp_path):
    _, full, _ = session
    # the untargeted session's first fit is narrower than this: the target stops it after step 0
    # (power: without the target, the same session ran further, asserted by the first test)
    assert full.steps[0].widths["alpha"] < 0.01 and len(full.steps) >= 2
    # a fresh bench of the same file: repeated triggers at one geometry draw counts of their own,
    # so the module's bench (which measured the session's points already) would read other counts
    with connect(_bench_file(tmp_path), run_engine=RE_with_result, body="virtual") as fresh:
        docs, result = _run(RE_with_result, sequential_fit(MODEL, fresh, store=tmp_path / "t.sqlite", target={"alpha": 0.01},
                                             **OPTIONS))
    assert result.stopped == "target" and len(result.steps) == 1 and len(docs.of("start")) == 1
    assert result.estimates == pytest.approx(full.steps[0].estimates, rel=1e-8)  # the same first step
    assert _fit_events(docs)[-1]["fit-stopped"] == "target"


@pytest.mark.slow  # reads the module's session (made by the test above)
def test_a_rerun_reuses_the_stored_steps_without_measuring(session, RE_with_result, devs):
    docs, result, store = session
    again_docs, again = _run(RE_with_result, sequential_fit(MODEL, devs, store=store, **OPTIONS))
    assert again_docs.of("start") == [] and again.runs == result.runs
    assert again.estimates == pytest.approx(result.estimates, rel=1e-8)


@pytest.mark.slow  # ~4-8 CPU-s: a whole session again, failed in its second step, then finished
def test_a_session_failed_in_a_step_is_finished_by_a_rerun_as_if_uninterrupted(session, RE_with_result, devs, tmp_path):
    from bluesky.utils import FailedStatus

    from bench.core.errors import DeviceTimeoutError

    _, full, _ = session
    store = tmp_path / "killed.sqlite"
    gonio = devs.bench.goniometer
    original = gonio.move_to
    state = {"armed": False, "moves": 0}

    def arm(name, doc):
        if name == "start" and doc[SEQUENTIAL_KEY]["step"] == 1:
            state["armed"] = True

    def faulty(g):
        if state["armed"]:
            state["moves"] += 1
            if state["moves"] == 3:
                raise DeviceTimeoutError("arm: move_to did not settle within 10 s")
        return original(g)

    gonio.move_to = faulty
    token = RE_with_result.subscribe(arm)
    try:
        with pytest.raises(FailedStatus):
            RE_with_result(sequential_fit(MODEL, devs, store=store, **OPTIONS))
    finally:
        RE_with_result.unsubscribe(token)
        del gonio.move_to
    with RunStore(store) as st:
        assert [r["status"] for r in st.runs()] == ["completed", "failed"]
    docs, result = _run(RE_with_result, sequential_fit(MODEL, devs, store=store, **OPTIONS))
    starts = docs.of("start")  # step 0 reused; step 1 measured again from its stored plan; step 2 designed
    assert [s[SEQUENTIAL_KEY]["step"] for s in starts] == list(range(1, len(full.steps)))
    assert [s[SEQUENTIAL_KEY]["replanned"] for s in starts] == [True] + [False] * (len(starts) - 1)
    assert [s.points for s in result.steps] == [s.points for s in full.steps]
    assert result.estimates == pytest.approx(full.estimates, rel=1e-8)
    with RunStore(store) as st:
        statuses = {r["run_id"]: r["status"] for r in st.runs()}
    assert len(statuses) == len(full.steps) + 1 and all(statuses[r] == "completed" for r in result.runs)


@pytest.mark.parametrize("kwargs, words", [
    ({"seconds": 0.0}, "seconds must be > 0"),
    ({"seconds": 1.0, "criterion": "Q"}, "criterion must be one of"),
    ({"seconds": 1.0, "target": {"eta": 0.1}}, "eta is not a free parameter"),
    ({"seconds": 1.0, "target": "alpha=0"}, "--target"),
    ({"seconds": 1.0, "prior": {"alpha": 7.0}}, "outside the model's bounds"),
    ({"seconds": 0.01}, "buys no design"),
])
def test_bad_arguments_are_refused_before_the_run_engine_sees_anything(devs, tmp_path, kwargs, words):
    with pytest.raises(InputError, match=words):
        sequential_fit(MODEL, devs, store=tmp_path / "x.sqlite", step=15.0, integration_s="0.01", **kwargs)


_SESSION = """
import json, sys
from bluesky import RunEngine
from bench.bluesky import connect
from bench.bluesky.plans import sequential_fit
RE = RunEngine(call_returns_result=True)
with connect({bench!r}, run_engine=RE, seed=1) as devs:
    r = RE(sequential_fit("lambert:reflectance=?", devs, seconds=3, store={store!r},
                        target={{"reflectance": 0.003}})).plan_result
print(json.dumps([r.stopped, r.estimates, r.widths, [[s.points, s.estimates] for s in r.steps]]))
"""


@pytest.mark.slow  # four fresh interpreters, each a 3-step session (~10 CPU-s each)
def test_a_seeded_sequential_session_is_the_same_in_every_process(tmp_path):
    """The sequential_fit session of docs/bluesky.md (seed 1) and `bench scan --sequential --seed 1` give the
    same designs and the very same estimates in processes with different hash seeds (set and
    dict orders of strings differ between them); each was reported to vary between runs."""
    import os
    import subprocess
    import sys

    from bluesky_support import ROOT

    def session(tag: str, hash_seed: str) -> str:
        code = _SESSION.format(bench=str(BENCHES / "virtual.toml"), store=str(tmp_path / f"{tag}.sqlite"))
        r = subprocess.run([sys.executable, "-"], input=code, capture_output=True, text=True, timeout=900,
                           cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONHASHSEED": hash_seed})
        assert r.returncode == 0, r.stderr[-3000:]
        return r.stdout.splitlines()[-1]

    def cli(tag: str, hash_seed: str) -> dict:
        r = subprocess.run([sys.executable, "-m", "bench.cli", "scan", "--sequential", "lambert:reflectance=?",
                            "--bench", str(BENCHES / "virtual.toml"), "--budget-seconds", "3", "--seed", "1", "--json",
                            "--quiet", "--store", str(tmp_path / f"{tag}.sqlite")], capture_output=True, text=True,
                           timeout=900, cwd=tmp_path,
                           env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONHASHSEED": hash_seed})
        assert r.returncode == 0, r.stderr[-3000:]
        out = json.loads(r.stdout)
        out.pop("runs", None)  # run ids are fresh per store
        for step in out.get("steps", []):
            if isinstance(step, dict):
                step.pop("run_id", None)
        return out

    first, second = session("a", "1"), session("b", "2")
    assert first == second
    assert cli("c", "3") == cli("d", "4")
