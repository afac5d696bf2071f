"""The emulated spectrometer prepares its specimen before it announces its port.

A spectral specimen builds tables on first use (a leaf's PROSPECT-D body and cuticle albedo take
seconds on a loaded core). Built inside the first acquisition, that overran the driver's deadline
for command 'S' on all five attempts, and the late frames then answered the next commands
("command 'J': expected ACK/NAK, got 0x02"). The emulator now asks its response once without a
geometry before the port is announced, and the response builds the specimen then.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import numpy as np
import pytest

from bench.builders import emulated
from bench.builders.emulated import emulated_response
from bench.config import load_bench
from bench.core.errors import DeviceError
from bench.core.geometry import Geometry
from bench.core.parsing import read_toml
from bench.plans import plan_from_dict
from bench.runner import run_scan
from bench.store import RunStore
from virtual.specimens import parse_specimen
from virtual.wire.ocean_model import SpectrometerConfig, SpectrometerModel
from virtual.wire.ocean_spectrometer import SpectrometerEmulator

BENCHES = Path(__file__).resolve().parents[1] / "fixtures" / "benches"
WL = np.linspace(400.0, 700.0, 16)


class _Counting:
    """A spectral specimen that counts its evaluations (a stand-in for one building tables)."""

    def __init__(self, inner):
        self.inner, self.calls = inner, 0

    def wavelength_range(self):
        return self.inner.wavelength_range()

    def bsdf(self, wi, wo, wl):
        self.calls += 1
        return self.inner.bsdf(wi, wo, wl)


def _response(monkeypatch, spec: str):
    made = []

    def parse(text):
        made.append(_Counting(parse_specimen(text)))
        return made[-1]

    monkeypatch.setattr(emulated, "parse_specimen", parse)
    monkeypatch.delitem(emulated._PROCESS_CACHE, "specimen", raising=False)
    return made, functools.partial(emulated_response, specimen=spec, white_rf=0.99, mount_file="/nonexistent/m.json",
                                   aperture_deg=1.0)


def test_a_response_asked_without_geometry_builds_and_evaluates_the_specimen_and_sees_no_light(monkeypatch):
    made, response = _response(monkeypatch, "plastic:alpha=0.15,kd=0.5")
    assert np.all(response(None, WL) == 0.0)
    assert len(made) == 1 and made[0].calls > 0  # parsed and evaluated: its tables are built now
    before = made[0].calls
    assert np.all(response(None, WL) == 0.0) and made[0].calls == before and len(made) == 1  # once only
    g = Geometry(30.0, 0.0, 20.0, 180.0)
    prepared = response(g, WL)
    assert len(made) == 1  # the acquisition uses the prepared specimen
    monkeypatch.delitem(emulated._PROCESS_CACHE, "specimen")
    assert np.array_equal(prepared, response(g, WL))  # and reads what an unprepared one reads
    assert prepared.max() > 0


def test_the_model_asks_its_response_once_without_geometry_when_prepared():
    asked = []
    model = SpectrometerModel(SpectrometerConfig(), response=lambda g, wl: asked.append((g, len(wl))) or np.zeros(len(wl)))
    assert asked == []
    model.prepare()
    assert asked == [(None, SpectrometerConfig().pixels)]


def test_the_emulator_prepares_before_it_announces_its_port():
    """A response that fails to prepare (an unknown specimen) stops the emulator's start, so it ran
    before the port was announced (unprepared, the start succeeded and the first 'S' failed)."""
    bad = functools.partial(emulated_response, specimen="nosuchfamily:x=1", white_rf=0.99,
                            mount_file="/nonexistent/m.json", aperture_deg=1.0)
    with pytest.raises(DeviceError, match="failed to start: .*nosuchfamily"):
        SpectrometerEmulator.start(response=bad, start_timeout=60.0)


@pytest.mark.slow  # ~30 s loaded: a leaf's tables built in the emulator, 4 emulated readings
def test_a_leaf_on_the_emulated_bench_is_read_without_a_retry(tmp_path, caplog):
    d = read_toml(BENCHES / "emulated.toml")
    d["specimen"]["spec"] = "leaf:healthy,roughness=0.2,eta=1.45"
    plan = plan_from_dict({"name": "leaf", "kind": "in-plane", "integration_s": 0.02, "averages": 1, "dark": "once",
                           "white": "once", "in_plane": {"theta_i": [30], "theta_r": [-10, 10, 40, 60]}})
    caplog.set_level(logging.WARNING, logger="drivers.ocean._link")
    with load_bench(d) as bench, RunStore(tmp_path / "s.sqlite") as store:
        run = run_scan(bench, plan, store)
        readings = store.readings(run.run_id)
    assert len(readings) == 4 * 3 and np.isfinite(readings.value).all()
    failed = [r.getMessage() for r in caplog.records if "failed (attempt" in r.getMessage()]
    assert failed == []
