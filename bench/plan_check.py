"""The refusals a plan meets before a physical body is opened, read from the bench description
alone (:mod:`bench.builders.described`): the kinematics' refusals of every point, the
calibration steps, the integration limits and the exposure (:mod:`bench.exposure`); then, for
the real body, the ports it would open. ``bench scan`` and ``bench resume`` call it before
they build the body, so a refused plan starts no emulator and opens no port, and a dead port is
one line naming it. The virtual body opens nothing: its own checks (the runner's, before any
motion) refuse alike, the exposure included."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping

from bench.builders.described import check_ports, described_bench
from bench.calibration_chain import check_dark_level
from bench.exposure import check_exposure
from bench.plans import Plan, validate
from bench.preflight import check_calibration_steps
from bench.runner import stored_white

__all__ = ["refuse_before_opening"]


def refuse_before_opening(plan: Plan, d: Mapping[str, Any], body: str, calibrated: bool = False,
                          resuming: bool = False) -> None:
    """Raise the one-line refusal (:class:`~bench.core.errors.PlanError`,
    :class:`~bench.core.errors.CalibrationRefused`, :class:`~bench.core.errors.ConfigError`)
    ``plan`` meets on description ``d`` executed by ``body``, before anything is opened.
    ``calibrated``: the run already holds its calibration: no white step is checked.
    ``resuming``: the run was started (its exposure decided then, its first points measured
    with it): finishing it is not refused for its exposure."""
    bench = None if body == "virtual" else described_bench(d, body)  # the virtual body's own checks refuse alike
    if bench is not None:
        validate(plan, bench.goniometer.check)
    if not resuming:
        check_exposure(plan, d)  # before the calibration steps: the white would saturate too
    if bench is None:
        return
    steps = replace(plan, white="none") if calibrated else plan
    check_calibration_steps(bench, steps, stored_white(bench) if steps.white != "none" else None)
    check_dark_level(bench, plan)  # the chain's own rule (a resumed run's too: its readings hold the dark)
    if body == "real":
        check_ports(d)
