"""The conformance harness: run one cell of the matrix through the project's real entry points and
judge it by one invariant.

A :class:`Cell` is specimen x body x calibration x darks x interface x exposure x seed.
:func:`run_cell` runs it -- ``bench scan`` / ``bench resume`` / ``bench white`` / ``bench sweep``
through ``bench.cli.main`` in this process (a SIGKILLed scan as a child process), Bluesky plans
through a RunEngine and :func:`bench.bluesky.connect` -- and returns an :class:`Outcome`: either
refused before motion (exit 2, exactly one line on stderr, no ``move_to`` and no stored point) or
the readings the run(s) stored, with each reading's GUM budget.

The invariant (:func:`check_invariant`, which returns the violations, empty when the cell holds):

* refused: one line, exit 2, no motion, nothing stored -- or
* every unmasked reading within ``k`` of its combined standard uncertainty of the truth
  (:mod:`truth`), ``k`` by Sidak over the cell's readings;
* the relative bias of the whole cell (generalized least squares over the readings' full
  covariance from their budgets: the white certificate one error common to all) within ``k_bias``;
  this is the test that sees a 3 % scale error a single reading's ``k`` can miss;
* repeated triggers at one geometry (Bluesky ``count``) scatter as the budgets' unshared Type A
  part says (chi-square, two-sided);
* a run with masked readings is never reported as a plain ``completed``;
* (optional) ``bench fit`` recovers the true parameters inside its 0.95 interval.

:func:`check_repeat_scatter` compares the scatter over seeds of one cell with the budgets' Type A
part (chi-square on the deviations from the seeds' mean, with the Type A covariance).

False-alarm rates: :mod:`invariant` (1 % family-wise over the matrix).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterator

import pandas as pd

from bench.core.parsing import read_toml
from cells import (BENCHES, BODIES, CALIBRATIONS, DARKS, DETECTOR, EXPOSURES, INTERFACES, PLAN_GRID,  # noqa: F401
                   ROOT, Cell, MotionSpy, Outcome, _json, base_description, bench_cli, plan_dict, plan_settings,
                   write_toml)
from invariant import (ALPHA_CELL, ALPHA_MATRIX, MAX_CELLS, check_invariant, check_refusal,  # noqa: F401 -- the API
                       check_repeat_scatter, covariance, plainly_completed, relative_bias, sidak_k)
from truth import SPECIMENS, TRUE_PARAMETERS


@contextlib.contextmanager
def body_of(cell: Cell, workdir: Path) -> Iterator[tuple[Path, Any]]:
    """The cell's bench description written to ``workdir`` and, for the real body, the emulators
    it points at (started here from the emulated bench with the cell's specimen and seed, as
    ``bench emulate`` does, stopped on exit)."""
    emulators = None
    if cell.body == "real":
        from bench.builders.emulated import Emulators

        emu_config = read_toml(BENCHES / "emulated.toml")
        emu_config["specimen"] = {"spec": SPECIMENS[cell.specimen]["spec"]}
        if cell.exposure != "nominal":
            emu_config["detector"] = dict(DETECTOR)
        emulators = Emulators(emu_config, seed=cell.seed)
    try:
        yield write_toml(workdir / "bench.toml", base_description(cell, emulators)), emulators
    finally:
        if emulators is not None:
            emulators.close()


def _body_args(cell: Cell) -> list[str]:
    return ["--body", cell.body]


class PrepRefused(Exception):
    """A step that prepares the cell's calibration (``bench white``, the run a white is taken
    from) exited non-zero: the cell's outcome is that refusal."""

    def __init__(self, code: int, err: str) -> None:
        super().__init__(err)
        self.code, self.err = code, err


def _checked(*argv: object) -> str:
    """``bench ARGV`` for a preparation step: its stdout, or :class:`PrepRefused`. A step that
    failed on its own (exit 1: a device fault the drivers did not absorb, seen under heavy load
    on the emulators) is taken once more, as an operator would."""
    code, out, err = bench_cli(*argv)
    if code == 1:
        code, out, err = bench_cli(*argv)
    if code != 0:
        raise PrepRefused(code, err)
    return out


def _with_white_file(bench_toml: Path, white: Path, name: str) -> Path:
    d = read_toml(bench_toml)
    d["white"] = {**dict(d.get("white") or {}), "reference_file": str(white)}
    return write_toml(bench_toml.parent / name, d)


def _measure_white(cell: Cell, source: Path, body: str, emulators: Any, white: Path) -> None:
    """``bench white --yes`` on ``body`` (on the real body over emulators the harness, as the
    operator, mounts the standard first and the specimen after)."""
    t, n = plan_settings(cell)
    mount = emulators is not None and body == "real"
    if mount:
        emulators.mount_white(True)
    try:
        _checked("white", "--bench", source, "--body", body, "--out", white, "--yes", "--integration-s", t,
                 "--averages", n, "--dark", "none" if cell.darks == "none" else "once")
    finally:
        if mount:
            emulators.mount_white(False)


def prepare_calibration(cell: Cell, bench_toml: Path, emulators: Any, workdir: Path, store: Path) -> Path:
    """The description the cell runs on: the body's own for a white measured in the run, else
    the same with ``[white] reference_file`` naming a white file made now: ``bench white`` on this
    body (the operator mounts the standard: ``--yes``), or ``bench white --from-run`` of a
    completed scan of the same plan (on the real body that scan is itself calibrated from a file:
    no operator can mount the standard during a scan), or, for ``foreign-file``, a white measured
    on another body (the emulated one; for the emulated body, its virtual twin) handed to this
    one. Raises :class:`PrepRefused`."""
    if cell.calibration in ("once", "repeated"):
        return bench_toml
    white = workdir / "white.csv"
    if cell.calibration == "run":
        source = bench_toml
        if cell.body == "real":
            _measure_white(cell, bench_toml, "real", emulators, workdir / "white-first.csv")
            source = _with_white_file(bench_toml, workdir / "white-first.csv", "bench-first.toml")
        plan = write_toml(workdir / "white-plan.toml", {**plan_dict(cell), "white": "once"})
        out = _checked("scan", plan, "--bench", source, *_body_args(cell), "--store", store,
                       "--seed", cell.seed + 1000, "--json", "-q")
        _checked("white", "--from-run", _json(out)["run_id"], "--store", store, "--out", white)
    elif cell.calibration == "foreign-file":
        body = "virtual" if cell.body == "emulated" else "emulated"
        foreign = write_toml(workdir / "foreign.toml", base_description(replace(cell, body=body)))
        _measure_white(cell, foreign, body, None, white)
    else:
        _measure_white(cell, bench_toml, cell.body, emulators, white)
    return _with_white_file(bench_toml, white, "bench-white.toml")


def perturbed(cell: Cell, bench_toml: Path, workdir: Path) -> Path:
    """A perturbed cell's description: the certificate declares 0.96 where the standard (the one
    the white file was measured with, or the simulated one) is 0.99 -- every value 3 % low."""
    if cell.perturb != "certificate":
        return bench_toml
    d = read_toml(bench_toml)
    d["white"] = {**dict(d.get("white") or {}), "reflectance_factor": 0.96}
    return write_toml(workdir / "bench-perturbed.toml", d)


def _store_points(store: Path) -> tuple[list[str], int]:
    if not store.exists():
        return [], 0
    from bench.store import RunStore

    with RunStore(store) as s:
        runs = [r["run_id"] for r in s.runs()]
        return runs, sum(len(s.done_indices(r)) for r in runs)


def run_cell(cell: Cell, workdir: Path) -> Outcome:
    """Run ``cell`` in ``workdir`` (a fresh directory) and collect what it did."""
    workdir.mkdir(parents=True, exist_ok=True)
    store = workdir / "runs.sqlite"
    outcome = Outcome(cell, store)
    with body_of(cell, workdir) as (bench_toml, emulators):
        try:
            bench_toml = prepare_calibration(cell, bench_toml, emulators, workdir, workdir / "prep.sqlite")
        except PrepRefused as exc:  # refused while preparing the calibration: before the cell's own motion
            _cli_outcome(outcome, exc.code, "", exc.err)
            return outcome
        bench_toml = perturbed(cell, bench_toml, workdir)
        outcome.aperture_deg = _aperture(bench_toml)
        if cell.interface in ("count", "list_scan", "grid_scan"):
            import bench.bluesky.connect  # noqa: F401 -- imported before the spy wraps its load_bench
        with MotionSpy() as spy:
            if cell.interface in ("scan", "sequential"):
                _run_scan(cell, bench_toml, workdir, outcome)
            elif cell.interface == "resume":
                _run_resume(cell, bench_toml, workdir, outcome)
            elif cell.interface == "sweep":
                _run_sweep(cell, workdir, outcome)
            else:
                _run_bluesky(cell, bench_toml, outcome, spy)
        if cell.interface not in ("count", "list_scan", "grid_scan"):
            outcome.moves = spy.moves
    _collect(outcome)
    return outcome


def _aperture(bench_toml: Path) -> float:
    from bench.builders.instrument import declared_aperture

    return declared_aperture(read_toml(bench_toml))


def _cli_outcome(outcome: Outcome, code: int, out: str, err: str) -> None:
    outcome.exit_code, outcome.stderr = code, err
    outcome.reported = _json(out)
    outcome.refusal = None
    if code != 0:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        outcome.refusal = lines[0] if lines else ""


#: the bench-time budget of a sequential session (docs/design.md's example spends 4.33 s)
SEQUENTIAL_SECONDS = 4.5


def _run_scan(cell: Cell, bench_toml: Path, workdir: Path, outcome: Outcome) -> None:
    plan = write_toml(workdir / "plan.toml", plan_dict(cell))
    if cell.interface == "sequential":  # designed steps read every point as the cell's plan does
        argv = ["scan", "--sequential", SPECIMENS[cell.specimen]["model"], "--bench", bench_toml, *_body_args(cell),
                "--budget-seconds", SEQUENTIAL_SECONDS, "--integration-s", plan_settings(cell)[0], "--like", plan,
                "--store", outcome.store, "--seed", cell.seed, "--json", "-q"]
    else:
        argv = ["scan", plan, "--bench", bench_toml, *_body_args(cell), "--store", outcome.store,
                "--seed", cell.seed, "--json", "-q"]
    _cli_outcome(outcome, *bench_cli(*argv, cwd=workdir))
    if outcome.exit_code == 1 and cell.interface == "scan":
        _after_a_device_fault(outcome, argv, workdir)


def _after_a_device_fault(outcome: Outcome, argv: list[Any], workdir: Path) -> None:
    """A scan that failed on its own (exit 1: a device fault the drivers' bounded retries did not
    absorb -- seen under heavy load on the emulators) is finished as its message says: ``bench
    resume`` of the interrupted run, or, when it stopped before creating one, the scan once more.
    The fault stays on record in ``outcome.faults``."""
    outcome.faults.append(outcome.stderr.strip())
    runs, _ = _store_points(outcome.store)
    from bench.store import RunStore

    if runs:
        with RunStore(outcome.store) as s:
            status = s.run(runs[-1])["status"]
        if status == "interrupted":
            _cli_outcome(outcome, *bench_cli("resume", runs[-1], "--store", outcome.store, "--json", "-q",
                                             cwd=workdir))
        return
    _cli_outcome(outcome, *bench_cli(*argv, cwd=workdir))


def _run_resume(cell: Cell, bench_toml: Path, workdir: Path, outcome: Outcome) -> None:
    """``bench scan`` in a child process, SIGKILLed once 3 points are committed, then ``bench
    resume`` here. (Under load the scan may finish first; the cell then is a plain scan.)"""
    sys.path.insert(0, str(ROOT / "tests"))
    from store_probe import committed_points

    plan = write_toml(workdir / "plan.toml", plan_dict(cell))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "scan", str(plan), "--bench", str(bench_toml),
                             "--body", cell.body, "--store", str(outcome.store), "--seed", str(cell.seed), "-q",
                             "--json"], cwd=workdir, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while committed_points(outcome.store) < 3 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    out, err = proc.communicate(timeout=60)
    if proc.returncode not in (0, -signal.SIGKILL):
        _cli_outcome(outcome, proc.returncode, out, err)
        return
    runs, _ = _store_points(outcome.store)
    from bench.store import RunStore

    with RunStore(outcome.store) as s:
        status = s.run(runs[-1])["status"]
    if status == "completed":  # the scan won the race
        _cli_outcome(outcome, 0, out, err)
        return
    _cli_outcome(outcome, *bench_cli("resume", runs[-1], "--store", outcome.store, "--json", "-q", cwd=workdir))


def _run_sweep(cell: Cell, workdir: Path, outcome: Outcome) -> None:
    """``bench sweep`` of the specimen (virtual by nature: it has no body, calibration or darks)."""
    sweep = {"sweep": {"name": f"cell-{cell.specimen}", "seed": cell.seed, "instrument": "gonio",
                       "specimens": [SPECIMENS[cell.specimen]["spec"]], "incidences": PLAN_GRID["theta_i"],
                       "collectors": ["equal-psa:18x36"], "wavelengths": [550], "rays": 2_000_000,
                       "method": "auto", "delta": 0.01}}
    path = write_toml(workdir / "sweep.toml", sweep)
    _cli_outcome(outcome, *bench_cli("sweep", path, "--store", outcome.store, "--json", cwd=workdir))


#: the Bluesky plans of the matrix: builder(devices) -> plan
def _bluesky_plan(name: str, devs: Any) -> Any:
    import bluesky.plans as bp

    g = devs.goniometer
    if name == "count":
        return bp.count([devs.reflectance, g], num=3)
    if name == "list_scan":
        return bp.list_scan([devs.reflectance, g], g.theta_i, [30, 30, 50, 50], g.theta_r, [10, 50, 50, 70])
    return bp.grid_scan([devs.reflectance, g], g.theta_i, 30, 50, 2, g.theta_r, 10, 50, 3)


def _run_bluesky(cell: Cell, bench_toml: Path, outcome: Outcome, spy: MotionSpy) -> None:
    """A Bluesky plan on the cell's body: RunEngine, the devices of :func:`bench.bluesky.connect`,
    the reflectance detector set to the cell's exposure/darks/white, runs into the store by
    :class:`bench.bluesky.StoreWriter`. A refusal is an exception before the plan moved anything
    (``outcome.moves`` counts the moves of the plan itself, after the arm was put at its start)."""
    import bluesky.plan_stubs as bps
    from bluesky import RunEngine

    from bench.bluesky import StoreWriter, connect
    from bench.core.geometry import Geometry

    RE = RunEngine({})
    t, n = plan_settings(cell)
    white = "repeated" if cell.calibration == "repeated" else "once"
    devs = connect(bench_toml, run_engine=RE, seed=cell.seed, body=cell.body)
    try:
        r = devs.reflectance
        RE(bps.mv(devs.goniometer, Geometry(50, 0, 50, 180)))  # count reads here: the GGX peak of the plan
        before = spy.moves
        token = RE.subscribe(StoreWriter(outcome.store))
        try:
            RE(bps.mv(r.integration_s, t, r.averages, n, r.dark_mode, cell.darks, r.white_mode, white))
            RE(_bluesky_plan(cell.interface, devs))
            outcome.exit_code = 0
        except Exception as exc:  # the RunEngine wraps the bench's error: judged as a refusal
            text = str(exc).strip()
            outcome.exit_code, outcome.stderr = 2, text
            outcome.refusal = text.splitlines()[0] if text else type(exc).__name__
        finally:
            RE.unsubscribe(token)
        outcome.moves = spy.moves - before
    finally:
        devs.close()


# --------------------------------------------------------------------------- collecting the record

def _collect(outcome: Outcome) -> None:
    from bench.store import RunStore

    if not outcome.store.exists():
        return
    frames = []
    with RunStore(outcome.store) as s:
        for info in s.runs():
            rid = info["run_id"]
            if info.get("kind") == "fit":
                continue
            outcome.run_ids.append(rid)
            outcome.statuses.append(str(s.run(rid)["status"]))
            df = s.readings(rid)
            if len(df):
                frames.append(df.assign(run_id=rid))
    if frames:
        df = pd.concat(frames, ignore_index=True)
        df["masked"] = df["value"].isna()
        if "hemisphere" in df:  # a sweep's record: the reflected hemisphere is the BRDF
            df = df[(df["hemisphere"].isna()) | (df["hemisphere"] == "R")].reset_index(drop=True)
        outcome.readings = df


#: the confidence of the intervals ``bench fit`` must hold the truth in: each miss a 1.25e-5 event
#: (a quarter of a cell's rate), so the fits of the whole matrix keep its family-wise rate
FIT_CONFIDENCE = 1.0 - ALPHA_CELL / 4


def check_fit(outcome: Outcome, workdir: Path) -> list[str]:
    """``bench fit`` of the cell's last run with the specimen's model (free parameters of
    :data:`truth.TRUE_PARAMETERS`) holds each true value in its interval at ``FIT_CONFIDENCE``
    (Hessian intervals; for a sequential session, its last step's run)."""
    if outcome.refused or not outcome.run_ids:
        return []
    truth = TRUE_PARAMETERS[outcome.cell.specimen]
    code, out, err = bench_cli("fit", outcome.run_ids[-1], "--store", outcome.store, "--model",
                               SPECIMENS[outcome.cell.specimen]["model"], "--interval", "hessian",
                               "--confidence", FIT_CONFIDENCE, "--json", cwd=workdir)
    if code != 0:
        return [f"bench fit exited {code}: {err.strip()[-300:]}"]
    params = (_json(out) or {}).get("parameters", {})
    bad = []
    for name, value in truth.items():
        ci = (params.get(name) or {}).get("ci")
        if not ci or not ci[0] <= value <= ci[1]:
            bad.append(f"bench fit: {name} = {value} not in its {FIT_CONFIDENCE:.6g} interval {ci} "
                       f"(estimate {(params.get(name) or {}).get('value')})")
    return bad


def verdict(cell: Cell, workdir: Path) -> tuple[Outcome, list[str]]:
    """Run ``cell`` and judge it: the outcome and every violation of the invariant (the fit's
    too when ``cell.fit``)."""
    outcome = run_cell(cell, workdir)
    bad = check_invariant(outcome)
    if cell.fit and not bad:
        bad += check_fit(outcome, workdir)
    return outcome, bad
