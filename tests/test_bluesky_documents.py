"""What the Bluesky devices put in the documents: one sign convention per key (the goniometer's
axes and the reflectance detector's geometry agree in one event, and the store gets the geometry
they mean).
"""

from __future__ import annotations

import bluesky.plan_stubs as bps
import bluesky.plans as bp

from bench.bluesky.goniometer import AXES
from bench.core.geometry import Geometry
from bench.store import RunStore
from bluesky_support import reset_reflectance, run


def test_one_event_says_one_geometry_in_one_sign_convention(RE, virtual, tmp_path):
    """At list_scan(theta_r, [-20]) the goniometer read -20 and the reflectance detector +20 with
    phi_r flipped: both now say -20 in the plane phi_r = 180, and the store keeps (30, 0, 20, 0)."""
    reset_reflectance(RE, virtual)
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    docs, writer = run(RE, virtual, bp.list_scan([virtual.reflectance], virtual.goniometer.theta_r, [-20, 20]),
                       tmp_path / "s.sqlite")
    events = docs.of("event")
    assert len(events) == 2
    for event, want in zip(events, (-20.0, 20.0)):
        data = event["data"]
        for axis in AXES:
            if f"goniometer-{axis}" in data:
                assert data[f"goniometer-{axis}"] == data[f"reflectance-{axis}"], (axis, data)
        assert data["reflectance-theta_r"] == want and data["reflectance-phi_r"] == 180.0
    with RunStore(tmp_path / "s.sqlite") as store:
        df = store.readings(writer.run_ids[0])
    got = sorted({(r.theta_i, r.phi_i, r.theta_r, r.phi_r) for r in df.itertuples()})
    assert got == [(30.0, 0.0, 20.0, 0.0), (30.0, 0.0, 20.0, 180.0)]


def test_every_data_key_names_the_hardware_not_a_soft_signal(RE, virtual):
    """Data keys said `soft://NAME`; they name the bench's instrument (body, bench, role, model)."""
    RE(bps.mv(virtual.goniometer, Geometry(30, 0, 20, 180)))
    docs, _ = run(RE, virtual, bp.count([virtual.goniometer, virtual.reflectance, virtual.spectrometer,
                                         virtual.light]))
    (desc,) = docs.of("descriptor")
    keys = dict(desc["data_keys"])
    for conf in desc["configuration"].values():
        keys.update(conf["data_keys"])
    assert keys and not [k for k, v in keys.items() if v["source"].startswith("soft://")]
    for name, key in keys.items():
        role = {"goniometer": "goniometer", "light": "light"}.get(name.split("-")[0], "spectrometer")
        assert key["source"].startswith(f"virtual://virtual/{role}/") and key["source"].endswith(f"#{name}"), key
