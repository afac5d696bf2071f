"""The fault-injection soak (benchmarks/soak.py), two minutes: scans on the emulated bench under
~1 % injected transient faults on all three protocols, with SIGKILL + resume and stage alarms,
end with no device-fault exit from a transient fault, no lost or duplicated point and nothing
left behind. Slow: CI runs it in ``make test-slow``; the in-process fault
tests of tests/test_faults.py are its cheap twins in ``make test``."""

from __future__ import annotations

import pytest

from benchmarks.soak import run_soak


@pytest.mark.slow
def test_two_minute_soak_rides_through_transient_faults(tmp_path):
    out = run_soak(2.0, seed=11, rate=0.01, points=60, workdir=tmp_path)
    assert out["runs"] >= 2 and out["runs_completed"] == out["runs"], out
    assert out["device_fault_exits"] == 0, out["device_fault_exit_lines"]
    assert out["refusals"] == [], out["refusals"]
    assert out["lost_points"] == 0 and out["duplicated_points"] == 0
    assert out["leftover_running_runs"] == 0 and out["leftover_processes"] == 0
    injected = sum(n for dev in out["faults_injected"].values() for n in dev.values())
    assert injected > 0 and out["recovered"] > 0 and out["failed_transactions"] == 0, out


def test_the_rss_slope_tells_a_leak_from_a_warm_up_that_levels_off():
    """A leak of 2 MB per 10,000 points reads the same early and late; a warm-up that levels off
    (3 MB over the first 2,500 points, as measured in a faulted 6,000-point run) reads steep over
    the run after its first fifth and nearly flat over its second half."""
    from benchmarks.soak import _slope_mb_per_10k

    points = list(range(0, 6001, 25))
    leak = [(p, 250_000 + int(2.0 * 1024 * p / 10_000)) for p in points]
    warm = [(p, 250_000 + int(3 * 1024 * min(p, 2500) / 2500)) for p in points]
    assert _slope_mb_per_10k(leak) == pytest.approx(2.0, rel=0.01)
    assert _slope_mb_per_10k(leak, 0.5) == pytest.approx(2.0, rel=0.01)
    assert _slope_mb_per_10k(warm) > 1.0 and abs(_slope_mb_per_10k(warm, 0.5)) < 0.01
    assert _slope_mb_per_10k(leak[:5]) is None  # too few points to say
