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
import io
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd
import tomli_w

from bench.core.parsing import read_toml
from invariant import (ALPHA_CELL, ALPHA_MATRIX, MAX_CELLS, check_invariant, check_refusal,  # noqa: F401 -- the API
                       check_repeat_scatter, covariance, plainly_completed, relative_bias, sidak_k)
from truth import SPECIMENS, TRUE_PARAMETERS

ROOT = Path(__file__).resolve().parents[2]
BENCHES = ROOT / "fixtures" / "benches"

BODIES = ("virtual", "emulated", "real")
CALIBRATIONS = ("once", "file", "repeated", "run", "foreign-file")
DARKS = ("none", "once", "per-incidence")
INTERFACES = ("scan", "resume", "count", "list_scan", "grid_scan", "adaptive", "sweep")
EXPOSURES = ("nominal", "near", "over")
#: the in-plane plan every scan-like cell measures (10 points, 3 bands)
PLAN_GRID = {"theta_i": [30, 50], "theta_r": {"start": -10, "stop": 70, "step": 20}}
NOMINAL = (0.02, 2)  # integration s, averages
#: the declared detector of the exposure cells (the emulated unit's data sheet, written out so
#: every body reads through the same full scale)
DETECTOR = {"saturation_counts": 65535, "counts_per_ms": 1500.0, "dark_counts": 1000.0}
RESPONSE_GAIN = 2.0  # counts per (BRDF x cos theta_r) per counts_per_ms (bench.builders.detector)


@dataclass(frozen=True)
class Cell:
    """One combination of the matrix (``perturb``: a deliberately wrong cell, for power)."""

    specimen: str = "lambert"
    body: str = "virtual"
    calibration: str = "once"
    darks: str = "once"
    interface: str = "scan"
    exposure: str = "nominal"
    seed: int = 1
    perturb: str | None = None  # "certificate": the description's certificate 3 % off the standard's
    fit: bool = False

    def __post_init__(self) -> None:
        for value, allowed in ((self.specimen, SPECIMENS), (self.body, BODIES), (self.calibration, CALIBRATIONS),
                               (self.darks, DARKS), (self.interface, INTERFACES), (self.exposure, EXPOSURES)):
            assert value in allowed, f"{value!r} not one of {tuple(allowed)}"

    @property
    def id(self) -> str:
        tail = f"-{self.perturb}" if self.perturb else ""
        return (f"{self.specimen}-{self.body}-{self.calibration}-dark_{self.darks}-{self.interface}-"
                f"{self.exposure}-s{self.seed}{tail}")


@dataclass
class Outcome:
    """What a cell did: refused (``refusal`` the one line) or ``readings`` (one row per reading:
    the store's columns, ``masked``, ``run_id``)."""

    cell: Cell
    store: Path
    exit_code: int | None = None
    refusal: str | None = None
    stderr: str = ""
    moves: int = 0
    statuses: list[str] = field(default_factory=list)
    reported: dict[str, Any] | None = None
    run_ids: list[str] = field(default_factory=list)
    readings: pd.DataFrame | None = None
    aperture_deg: float = 1.0

    @property
    def refused(self) -> bool:
        return self.refusal is not None


# --------------------------------------------------------------------------- running a command

class MotionSpy:
    """Counts ``move_to`` of every goniometer the benches built during ``with spy:`` (in this
    process): ``load_bench`` is wrapped where the entry points look it up."""

    def __init__(self) -> None:
        self.moves = 0
        self._patches: list[tuple[Any, str, Any]] = []

    def _wrap(self, load):
        def load_bench(*args: Any, **kwargs: Any) -> Any:
            bench = load(*args, **kwargs)
            g = bench.goniometer
            move = g.move_to

            def move_to(geometry: Any) -> Any:
                self.moves += 1
                return move(geometry)

            g.move_to = move_to
            return bench
        return load_bench

    def __enter__(self) -> "MotionSpy":
        import bench.config

        modules = [bench.config] + [m for m in (sys.modules.get("bench.bluesky.connect"),) if m is not None]
        for mod in modules:
            original = mod.load_bench
            self._patches.append((mod, "load_bench", original))
            mod.load_bench = self._wrap(original)
        return self

    def __exit__(self, *exc: Any) -> None:
        for mod, name, original in reversed(self._patches):
            setattr(mod, name, original)
        self._patches.clear()


def bench_cli(*argv: object, cwd: Path | None = None) -> tuple[int, str, str]:
    """``bench ARGV`` in this process: exit status, stdout, stderr."""
    from bench.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), _cwd(cwd):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


@contextlib.contextmanager
def _cwd(path: Path | None) -> Iterator[None]:
    if path is None:
        yield
        return
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _json(text: str) -> dict[str, Any] | None:
    for line in reversed(text.strip().splitlines()):
        with contextlib.suppress(ValueError):
            doc = json.loads(line)
            if isinstance(doc, dict):
                return doc
    return None


# --------------------------------------------------------------------------- descriptions, plans

def plan_settings(cell: Cell) -> tuple[float, int]:
    """Integration time and averages of the cell's exposure: nominal (0.02 s x 2), near full
    scale (the brightest expected scan, white included, at ~85 % of it) or over (at 2x)."""
    t, n = NOMINAL
    if cell.exposure == "nominal":
        return t, n
    brightest = max(_brightest_reflected(cell.specimen), 0.99 / np.pi * np.cos(np.radians(45)))
    per_s = RESPONSE_GAIN * DETECTOR["counts_per_ms"] * 1000.0 * brightest
    room = DETECTOR["saturation_counts"] - DETECTOR["dark_counts"]
    fraction = 0.85 if cell.exposure == "near" else 2.0
    return round(fraction * room / per_s, 5), n


def _brightest_reflected(name: str) -> float:
    """max over the plan of BRDF x cos(theta_r), the truth at the detector cone."""
    rows = pd.DataFrame(plan_rows(PLAN_GRID))
    from truth import truth_of as _t

    return float(np.max(_t(name, rows, 1.0) * np.cos(np.radians(rows["theta_r"].abs()))))


def plan_rows(grid: dict[str, Any]) -> list[dict[str, float]]:
    tr = grid["theta_r"]
    rows = []
    for ti in grid["theta_i"]:
        for r in np.arange(tr["start"], tr["stop"] + 1e-9, tr["step"]):
            rows.append({"theta_i": ti, "phi_i": 0.0, "theta_r": abs(r), "phi_r": 180.0 if r >= 0 else 0.0,
                         "wavelength_nm": 550.0})
    return rows


def plan_dict(cell: Cell) -> dict[str, Any]:
    t, n = plan_settings(cell)
    white = "repeated" if cell.calibration == "repeated" else "once"
    plan = {"name": f"cell-{cell.id}", "kind": "in-plane", "integration_s": t, "averages": n, "dark": cell.darks,
            "white": white, "in_plane": PLAN_GRID}
    if white == "repeated":
        plan["white_repeats"] = 3
    return plan


def base_description(cell: Cell, emulators: Any = None) -> dict[str, Any]:
    """The bench description the cell's body executes (before its calibration file)."""
    if cell.body == "real":
        d = dict(emulators.real_bench_config())
    else:
        d = read_toml(BENCHES / ("virtual.toml" if cell.body == "virtual" else "emulated.toml"))
    d["specimen"] = {**dict(d.get("specimen") or {}), "spec": SPECIMENS[cell.specimen]["spec"]}
    if cell.exposure != "nominal":
        d["detector"] = dict(DETECTOR)
    return d


def write_toml(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(doc))
    return path


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


def prepare_calibration(cell: Cell, bench_toml: Path, emulators: Any, workdir: Path, store: Path) -> Path:
    """The description the cell runs on: the body's own for a white measured in the run, else
    the same with ``[white] reference_file`` naming a white file made now: ``bench white`` on this
    body (the operator mounts the standard: ``--yes``; on the real body over emulators the
    harness mounts it), or from a completed run (``bench white --from-run``), or, for
    ``foreign-file``, measured on the *emulated* body and handed to this one."""
    if cell.calibration in ("once", "repeated"):
        return bench_toml
    t, n = plan_settings(cell)
    white = workdir / "white.csv"
    dark = "none" if cell.darks == "none" else "once"
    if cell.calibration == "run":
        code, out, err = bench_cli("scan", write_toml(workdir / "white-plan.toml", {**plan_dict(cell), "dark": dark,
                                                                                      "white": "once"}),
                                   "--bench", bench_toml, *_body_args(cell), "--store", store,
                                   "--seed", cell.seed + 1000, "--json", "-q")
        assert code == 0, f"the run a white is taken from failed: {err.strip()}"
        code, out, err = bench_cli("white", "--from-run", _json(out)["run_id"], "--store", store, "--out", white)
    else:
        source, body = bench_toml, cell.body
        if cell.calibration == "foreign-file":
            source = write_toml(workdir / "foreign.toml", base_description(replace(cell, body="emulated")))
            body = "emulated"
        if emulators is not None and body == "real":
            emulators.mount_white(True)
        try:
            code, out, err = bench_cli("white", "--bench", source, "--body", body, "--out", white, "--yes",
                                       "--integration-s", t, "--averages", n, "--dark", dark)
        finally:
            if emulators is not None and body == "real":
                emulators.mount_white(False)
    assert code == 0, f"bench white failed: {err.strip()}"
    d = read_toml(bench_toml)
    d["white"] = {**dict(d.get("white") or {}), "reference_file": str(white)}
    return write_toml(workdir / "bench-white.toml", d)


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
        prep_store = workdir / "prep.sqlite"
        bench_toml = prepare_calibration(cell, bench_toml, emulators, workdir, prep_store)
        bench_toml = perturbed(cell, bench_toml, workdir)
        outcome.aperture_deg = _aperture(bench_toml)
        if cell.interface in ("count", "list_scan", "grid_scan"):
            import bench.bluesky.connect  # noqa: F401 -- imported before the spy wraps its load_bench
        with MotionSpy() as spy:
            if cell.interface in ("scan", "adaptive"):
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
    if code != 0:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        outcome.refusal = lines[0] if lines else ""


def _run_scan(cell: Cell, bench_toml: Path, workdir: Path, outcome: Outcome) -> None:
    if cell.interface == "adaptive":
        t, n = plan_settings(cell)
        argv = ["scan", "--adaptive", SPECIMENS[cell.specimen]["model"], "--bench", bench_toml, *_body_args(cell),
                "--seconds", 3.0, "--integration-s", t, "--like", write_toml(workdir / "plan.toml", plan_dict(cell)),
                "--store", outcome.store, "--seed", cell.seed, "--json", "-q"]
    else:
        plan = write_toml(workdir / "plan.toml", plan_dict(cell))
        argv = ["scan", plan, "--bench", bench_toml, *_body_args(cell), "--store", outcome.store,
                "--seed", cell.seed, "--json", "-q"]
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
        return bp.list_scan([devs.reflectance, g], g.theta_i, [30, 30, 50, 50], g.theta_r, [10, 50, 30, 70])
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
        RE(bps.mv(devs.goniometer, Geometry(30, 0, 30, 180)))
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


def check_fit(outcome: Outcome, workdir: Path) -> list[str]:
    """``bench fit`` of the cell's last run with the specimen's model (free parameters of
    :data:`truth.TRUE_PARAMETERS`) holds each true value in its 0.95 interval."""
    if outcome.refused or not outcome.run_ids:
        return []
    truth = TRUE_PARAMETERS[outcome.cell.specimen]
    if outcome.cell.interface == "adaptive":  # the session's own fit of every reading
        found = {n: (outcome.reported or {}).get("intervals", {}).get(n) for n in truth}
    else:
        code, out, err = bench_cli("fit", outcome.run_ids[-1], "--store", outcome.store, "--model",
                                   SPECIMENS[outcome.cell.specimen]["model"], "--interval", "hessian", "--json",
                                   cwd=workdir)
        if code != 0:
            return [f"bench fit exited {code}: {err.strip()[-300:]}"]
        params = (_json(out) or {}).get("parameters", {})
        found = {n: (params.get(n) or {}).get("ci") for n in truth}
    bad = []
    for name, value in truth.items():
        ci = found.get(name)
        if not ci or not ci[0] <= value <= ci[1]:
            bad.append(f"bench fit: {name} = {value} not in its interval {ci}")
    return bad


def verdict(cell: Cell, workdir: Path) -> tuple[Outcome, list[str]]:
    """Run ``cell`` and judge it: the outcome and every violation of the invariant (the fit's
    too when ``cell.fit``)."""
    outcome = run_cell(cell, workdir)
    bad = check_invariant(outcome)
    if cell.fit and not bad:
        bad += check_fit(outcome, workdir)
    return outcome, bad
