"""The cells of the conformance matrix and what running one takes: :class:`Cell`, :class:`Outcome`,
the plan and bench description a cell measures with, ``bench`` in this process
(:func:`bench_cli`) and a spy on the goniometers' motion (:class:`MotionSpy`). The harness
(:mod:`harness`) runs cells with them.

Exposure is set from the truth and the declared detector's response (the emulated unit's data
sheet, the same for every body): the brightest expected scan of the plan, white standard
included, at 40 % (nominal), 85 % (near) or 200 % (over) of full scale above the dark.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd
import tomli_w

from bench.core.parsing import read_toml
from truth import SPECIMENS, truth_of

ROOT = Path(__file__).resolve().parents[2]
BENCHES = ROOT / "fixtures" / "benches"

BODIES = ("virtual", "emulated", "real")
CALIBRATIONS = ("once", "file", "repeated", "run", "foreign-file")
DARKS = ("none", "once", "per-incidence")
INTERFACES = ("scan", "resume", "count", "list_scan", "grid_scan", "sequential", "sweep")
EXPOSURES = ("nominal", "near", "over")
#: the in-plane plan every scan-like cell measures (10 points, 3 bands)
PLAN_GRID = {"theta_i": [30, 50], "theta_r": {"start": -10, "stop": 70, "step": 20}}
NOMINAL_AVERAGES = 2
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
    faults: list[str] = field(default_factory=list)  # device faults a run was resumed after

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

#: the brightest expected scan of each exposure, as a fraction of the detector's room above its dark
EXPOSURE_FRACTION = {"nominal": 0.4, "near": 0.85, "over": 2.0}


def plan_settings(cell: Cell) -> tuple[float, int]:
    """Integration time (whole ms) and averages (2) of the cell's exposure: the brightest expected scan of
    the plan (the white at 0/45 included) at 40 % of the declared detector's room above its dark
    (nominal), at 85 % (near full scale) or at twice full scale (over), from the detector's
    declared response and the truth."""
    brightest = max(_brightest_reflected(cell.specimen), 0.99 / np.pi * np.cos(np.radians(45)))
    per_s = RESPONSE_GAIN * DETECTOR["counts_per_ms"] * 1000.0 * brightest
    room = DETECTOR["saturation_counts"] - DETECTOR["dark_counts"]
    # whole milliseconds: the spectrometer's driver integrates in ms (and records what it did)
    return round(float(EXPOSURE_FRACTION[cell.exposure] * room / per_s), 3), NOMINAL_AVERAGES


@functools.lru_cache(maxsize=None)
def _brightest_reflected(name: str) -> float:
    """max over the plan of BRDF x cos(theta_r), the truth at the detector cone."""
    rows = pd.DataFrame(plan_rows(PLAN_GRID))
    return float(np.max(truth_of(name, rows, 1.0) * np.cos(np.radians(rows["theta_r"]))))


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
