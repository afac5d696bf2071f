"""``connect(BENCH_TOML, run_engine=RE)``: a bench's roles as named, connected ophyd-async devices.

The bench is built exactly as ``bench scan`` builds it (:func:`bench.config.load_bench`: a
virtual bench, an emulated one with its emulator processes, or real ports), then wrapped:

=================  ===========================================  ==================================
device             our role                                     Bluesky protocols
=================  ===========================================  ==================================
``goniometer``     Goniometer (``check``, ``move_to``, ...)     Movable (a whole Geometry),
                                                                Readable, Locatable, Stoppable
``goniometer.X``   one angle of the Goniometer                  Movable, Readable, Locatable,
                   (``theta_i``, ``phi_i``, ``theta_r``,        Stoppable, Checkable,
                   ``phi_r``)                                   Subscribable
``spectrometer``   Spectrometer (``acquire``)                   Triggerable, Readable,
                                                                Configurable
``reflectance``    Spectrometer + white standard + Calibration  Triggerable, Readable,
                                                                Configurable, Stageable
``light``          LightSource (``on``, ``off``)                Movable, Readable
=================  ===========================================  ==================================

All devices share the bench's single worker thread (:class:`~bench.bluesky.worker.BenchWorker`)
and the spectrometer and reflectance devices share one set of reading settings
(:class:`~bench.bluesky.detectors.ReadingSettings`: ``integration_s`` and ``averages`` set on
either are the other's; the defaults follow the bench's stored white, if any), and are connected in the RunEngine's event loop. Close with :meth:`Devices.close` (or use
``with``): it stops the goniometer, ends the worker, and closes the bench (stopping emulators).
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ophyd_async.core import Device

from bench.bluesky.detectors import LightDevice, ReadingSettings, ReflectanceDevice, SpectrometerDevice
from bench.bluesky.goniometer import GoniometerDevice
from bench.bluesky.signals import hardware_source
from bench.bluesky.worker import BenchWorker
from bench.config import Bench, load_bench
from bench.core.errors import BenchError, DeviceError
from bench.core.records import json_default
from bench.core.roles import Closing

__all__ = ["connect", "Devices", "METADATA_KEY", "PLAN_KEY", "jsonable"]

#: the start-document key (set in ``RE.md`` by :func:`connect`) holding the bench's metadata
METADATA_KEY = "goniobench"
#: the start-document key describing our plan (its table, the order, points planned), set by
#: :func:`bench.bluesky.plans.plan_from_toml` and read by :class:`bench.bluesky.StoreWriter`
PLAN_KEY = "goniobench_plan"


@dataclass
class Devices(Closing):
    """The connected devices of one bench (``light`` is ``None`` when it has no light)."""

    bench: Bench
    worker: BenchWorker
    goniometer: GoniometerDevice
    spectrometer: SpectrometerDevice
    reflectance: ReflectanceDevice
    light: LightDevice | None = None
    seed: int | None = None
    loop: asyncio.AbstractEventLoop | None = field(default=None, repr=False)

    def all(self) -> list[Device]:
        """Every device (the goniometer's axes are its children)."""
        out: list[Device] = [self.goniometer, self.spectrometer, self.reflectance]
        return out + ([self.light] if self.light is not None else [])

    @property
    def metadata(self) -> dict[str, Any]:
        """What a run's start document should say about the bench (``RE.md["goniobench"]``):
        its config, kind, description, seed and specimen, as ``bench scan`` records them (as JSON
        values: a start document must be JSON)."""
        return jsonable({"bench": self.bench.config, "bench_name": self.bench.name, "bench_kind": self.bench.kind,
                "bench_description": self.bench.describe(), "seed": self.seed,
                "specimen": (self.bench.config.get("specimen") or {}).get("spec"),
                "source": "virtual" if self.bench.kind == "virtual" else "measured"})

    def close(self) -> None:
        """Stop the goniometer, end the worker thread, close the bench. Idempotent."""
        try:
            if not self.worker.closed:
                try:
                    self.worker.call(self.bench.goniometer.stop)
                except (BenchError, OSError):
                    pass
                self.worker.close()
        finally:
            self.bench.close()


def jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON values (numpy converted, mapping keys as strings)."""
    return json.loads(json.dumps(obj, default=json_default))


def _loop_of(run_engine: Any) -> asyncio.AbstractEventLoop:
    if run_engine is not None:
        return run_engine.loop
    from bluesky.run_engine import get_bluesky_event_loop

    loop = get_bluesky_event_loop()
    if loop is None:
        raise BenchError("connect() needs a RunEngine (connect(..., run_engine=RE)): create one first")
    return loop


def _in_loop(loop: asyncio.AbstractEventLoop, coro: Any, timeout: float) -> Any:
    return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout)


def connect(config: str | Path | Mapping[str, Any], run_engine: Any = None, *, seed: int | None = None,
            timeout: float = 10.0, body: str | None = None) -> Devices:
    """Build the bench ``config`` names and return its devices, connected in the RunEngine's loop.

    Parameters
    ----------
    config : path or mapping
        A bench TOML (``fixtures/benches/virtual.toml``, ``emulated.toml``, a real one) or its dict.
    run_engine : bluesky.RunEngine, optional
        The RunEngine the devices will serve; its ``md["goniobench"]`` is set to
        :attr:`Devices.metadata` so :class:`~bench.bluesky.StoreWriter` can record the bench.
        Without it, the loop of the RunEngine created last is used.
    seed : int, optional
        Root seed of a virtual bench (as ``bench scan --seed``).
    body : str, optional
        ``virtual``, ``emulated`` or ``real``: what executes the description (as ``--body``;
        default: its ``kind``).
    timeout : float
        Seconds to wait for the devices to connect.

    Returns
    -------
    Devices
        ``goniometer`` (axes ``theta_i``, ``phi_i``, ``theta_r``, ``phi_r``), ``spectrometer``,
        ``reflectance`` and ``light`` (or ``None``).
    """
    loop = _loop_of(run_engine)
    bench = load_bench(config, seed=seed, body=body)
    worker = BenchWorker(bench.name)
    try:
        start = worker.call(bench.goniometer.position)
        gonio = GoniometerDevice(bench.goniometer, worker, start, name="goniometer",
                                 hardware=hardware_source(bench, "goniometer"))
        settings = ReadingSettings.for_bench(bench)  # one detector: one integration time for both
        spectrometer = SpectrometerDevice(bench, worker, name="spectrometer", settings=settings, mover=gonio.mover)
        reflectance = ReflectanceDevice(bench, worker, gonio.mover, name="reflectance", settings=settings)
        light = LightDevice(bench, worker, name="light") if bench.light is not None else None
        actual_seed = getattr(bench.goniometer, "seed", seed)
        devs = Devices(bench, worker, gonio, spectrometer, reflectance, light,
                       seed=None if actual_seed is None else int(actual_seed), loop=loop)

        async def connect_all() -> None:
            await asyncio.gather(*(d.connect(timeout=timeout) for d in devs.all()))

        _in_loop(loop, connect_all(), timeout + 5.0)
    except BaseException as exc:
        worker.close()
        bench.close()
        if isinstance(exc, (BenchError, KeyboardInterrupt)):
            raise
        raise DeviceError(f"bench {bench.name!r}: the devices did not connect: {exc}") from exc
    if run_engine is not None:
        run_engine.md[METADATA_KEY] = devs.metadata
    return devs
