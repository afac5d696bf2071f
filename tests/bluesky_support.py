"""Shared helpers of the Bluesky tests (test_bluesky.py, test_bluesky_emulated.py)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.plans as bp
from bluesky import RunEngine, protocols
from event_model import DocumentNames, schema_validators

from bench.bluesky import StoreWriter
from bench.bluesky.goniometer import AXES

ROOT = Path(__file__).parent.parent
BENCHES = ROOT / "fixtures" / "benches"
IN_PLANE = ROOT / "fixtures" / "plans" / "in-plane.toml"

PROTOCOLS = {
    "goniometer": (protocols.HasName, protocols.Readable, protocols.Movable, protocols.Locatable,
                   protocols.Stoppable),
    "axis": (protocols.HasName, protocols.Readable, protocols.Movable, protocols.Locatable, protocols.Stoppable,
             protocols.Checkable),
    "spectrometer": (protocols.HasName, protocols.Readable, protocols.Triggerable, protocols.Configurable),
    "reflectance": (protocols.HasName, protocols.Readable, protocols.Triggerable, protocols.Configurable,
                    protocols.Stageable),
    "light": (protocols.HasName, protocols.Readable, protocols.Movable),
}


class Docs:
    """A RunEngine subscriber keeping every document, each validated against event-model's schema."""

    def __init__(self) -> None:
        self.docs: list[tuple[str, dict[str, Any]]] = []

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        schema_validators[DocumentNames[name]].validate(doc)
        self.docs.append((name, doc))

    def of(self, name: str) -> list[dict[str, Any]]:
        return [d for n, d in self.docs if n == name]

    def clear(self) -> None:
        self.docs.clear()


def run(RE: RunEngine, devs: Any, plan: Any, store: Path | None = None) -> tuple[Docs, StoreWriter | None]:
    """Run ``plan`` with a validating collector (and a StoreWriter); ``RE.md`` names ``devs``' bench."""
    RE.md["goniobench"] = devs.metadata
    docs = Docs()
    writer = StoreWriter(store) if store is not None else None
    tokens = [RE.subscribe(docs)] + ([RE.subscribe(writer)] if writer is not None else [])
    try:
        RE(plan)
    finally:
        for t in tokens:
            RE.unsubscribe(t)
    return docs, writer


def reset_reflectance(RE: RunEngine, devs: Any, integration_s: float = 0.02, averages: int = 1,
                      dark: str = "once", white: str = "once") -> None:
    r = devs.reflectance
    RE(bps.mv(r.integration_s, integration_s, r.averages, averages, r.dark_mode, dark, r.white_mode, white))


class Calls(list):
    """The calls a :func:`spy` saw: ``(args, thread)``; ``restore()`` removes the spy."""

    def __init__(self, obj: Any, method: str) -> None:
        super().__init__()
        self.obj, self.method = obj, method

    def restore(self) -> None:
        delattr(self.obj, self.method)


def spy(obj: Any, method: str) -> Calls:
    """Record (args, thread) of every call of ``obj.method`` (an instance attribute wrapper)."""
    calls = Calls(obj, method)
    original = getattr(obj, method)

    def wrapper(*args: Any) -> Any:
        calls.append((args, threading.current_thread()))
        return original(*args)

    setattr(obj, method, wrapper)
    return calls


def check_protocols(devs: Any) -> None:
    targets = {"goniometer": [devs.goniometer], "axis": list(devs.goniometer.axes.values()),
               "spectrometer": [devs.spectrometer], "reflectance": [devs.reflectance], "light": [devs.light]}
    for kind, devices in targets.items():
        for dev in devices:
            for proto in PROTOCOLS[kind]:
                assert isinstance(dev, proto), f"{dev.name} is not {proto.__name__}"
    assert [a.name for a in devs.goniometer.axes.values()] == [f"goniometer-{a}" for a in AXES]
    assert not isinstance(devs.spectrometer, protocols.Movable)  # the checks can fail


#: standard plans: builder(devices) -> (plan, events, goniometer moves)
STANDARD = {
    "count": lambda d: (bp.count([d.reflectance], num=2), 2, 0),
    "scan": lambda d: (bp.scan([d.reflectance], d.goniometer.theta_r, -20, 60, 5), 5, 5),
    "rel_scan": lambda d: (bp.rel_scan([d.spectrometer], d.goniometer.theta_r, -10, 10, 3), 3, 4),
    "list_scan": lambda d: (bp.list_scan([d.reflectance, d.spectrometer], d.goniometer.theta_i, [20, 40],
                                         d.goniometer.theta_r, [30, 50]), 2, 2),
    "grid_scan": lambda d: (bp.grid_scan([d.reflectance], d.goniometer.theta_i, 20, 40, 2,
                                         d.goniometer.theta_r, 10, 50, 3), 6, 6),
}

