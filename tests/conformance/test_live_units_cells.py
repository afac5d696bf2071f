"""Conformance cells of the Bluesky devices' data keys as a live ``TiledWriter`` stores them:
every number a bench's devices read carries its unit.

Cell: virtual body (seed 1) x ``count`` of the goniometer, spectrometer and reflectance devices at a
measuring geometry, 0.02 s (white and dark at stage) x the primary descriptor and its configuration.

Invariant: every numeric data key (``number``, ``integer``, an ``array`` of numbers; flags and text
have no unit; in the configuration, the measured quantities, not a count of scans) has ``units`` -- a reflectance factor is ``"1"``, as a stored spectrophotometer's value
and its served copy say, a pixel count ``"pixels"`` -- so a run written live and the same run served
from the store read with the same units. Deterministic. Power: the devices once declared the
hinted ``reflectance-rf_mean`` / ``-rf_mean_std`` and the reflectance factor arrays without one.
"""

from __future__ import annotations

from pathlib import Path

import bluesky.plan_stubs as bps
import bluesky.plans as bp
from bluesky import RunEngine

from bench.bluesky import connect

BENCH = Path(__file__).resolve().parents[2] / "fixtures" / "benches" / "virtual.toml"


def _unitless(data_keys: dict, kinds: str = "fiu") -> list[str]:
    return sorted(k for k, v in data_keys.items()
                  if v["dtype"] in ("number", "integer", "array") and "units" not in v
                  and str(v.get("dtype_numpy", "<f8"))[1:2] in kinds)


def test_every_number_a_live_run_reads_has_a_unit():
    RE = RunEngine({})
    docs: list[tuple[str, dict]] = []
    with connect(BENCH, run_engine=RE, seed=1) as devs:
        RE(bps.mv(devs.reflectance.integration_s, 0.02, devs.goniometer.theta_i, 30, devs.goniometer.theta_r, 20))
        RE(bp.count([devs.goniometer, devs.spectrometer, devs.reflectance]), lambda n, d: docs.append((n, d)))
    (desc,) = [d for n, d in docs if n == "descriptor"]
    assert "reflectance-rf_mean" in desc["data_keys"] and "spectrometer-n_saturated" in desc["data_keys"]
    assert _unitless(desc["data_keys"]) == []
    assert desc["data_keys"]["reflectance-rf_mean"]["units"] == "1"
    assert desc["data_keys"]["reflectance-reflectance_factor"]["units"] == "1"
    for device, conf in desc["configuration"].items():
        assert _unitless(conf["data_keys"], "f") == [], device  # a setting's count (averages) is a number
