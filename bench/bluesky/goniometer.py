"""The goniometer as ophyd-async devices: four Movable axes moved together by one mover.

Each axis (``theta_i``, ``phi_i``, ``theta_r``, ``phi_r``, degrees) is a ``StandardReadable`` +
``StandardMovable``: ``set()`` returns a status that completes when the bench's ``move_to`` has
settled; ``read()`` gives the *read-back* (the geometry the goniometer reports, not the
request); ``locate()`` gives both; ``stop()`` holds the arm.

Axes that are set together (``mv(theta_i, 30, theta_r, 40)``, ``grid_scan``, ``list_scan``)
are coalesced into ONE ``move_to`` of the combined geometry: the mover waits a few loop
iterations for sibling requests before it queues the move, so no intermediate geometry (new
``theta_i`` with the old ``theta_r``) is ever commanded or refused.

Safety: the mover composes the combined target geometry and runs the bench's pure ``check`` on
the event loop *before* anything is queued for the worker thread, so a target the kinematics
refuse fails the status(es) with the :class:`~bench.core.errors.GeometryError` that names the
rule, before any byte is sent, and the requested geometry stays the last accepted one.
``move_to`` checks again (drivers do).

``theta_r`` is signed in the detector plane set by ``phi_r``: ``theta_r = -40`` views at 40 deg
on the other side of the normal (``phi_r + 180``), so an in-plane record is one ``scan`` of
``theta_r`` from -60 to 60. With ``phi_r = phi_i + 180`` the sign is ``Geometry.in_plane``'s and
the plan files' (> 0 on the specular side) -- and that is the plane a detector at the zenith
(where ``phi_r`` is undefined) starts in, so ``scan(theta_r, -20, 80, 6)`` measures the points of
an in-plane plan with ``theta_r`` from -20 to 80 (one sign convention, README "Angles").
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable, Sequence

from bluesky.protocols import Location
from ophyd_async.core import (
    AsyncStatus,
    MovableLogic,
    StandardMovable,
    StandardReadable,
)
from ophyd_async.core import StandardReadableFormat as Format

from bench.bluesky.signals import hw_signal_r, hw_signal_rw
from bench.bluesky.worker import BenchWorker
from bench.core.errors import GeometryError
from bench.core.geometry import Geometry

__all__ = ["AXES", "Mover", "GoniometerAxis", "GoniometerDevice"]

AXES = ("theta_i", "phi_i", "theta_r", "phi_r")
#: loop iterations the mover waits for the other axes of a multi-axis move to join it
_COALESCE_ITERATIONS = 4


def _azimuth_gap(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


#: read-backs closer than this (deg, under one servo step) are the same place
_SAME_PLACE_DEG = 0.01
#: a read-back this close to the setpoint (deg: a few servo steps, the goniometers' conformance
#: tolerance) is the arm at its setpoint
_AT_SETPOINT_DEG = 0.5


def _same_place(a: Geometry, b: Geometry) -> bool:
    """Whether two read-backs are the same arm position (azimuths compared on the circle)."""
    return (abs(a.theta_i - b.theta_i) <= _SAME_PLACE_DEG and abs(a.theta_r - b.theta_r) <= _SAME_PLACE_DEG
            and _azimuth_gap(a.phi_i, b.phi_i) <= _SAME_PLACE_DEG and _azimuth_gap(a.phi_r, b.phi_r) <= _SAME_PLACE_DEG)


class Mover:
    """Owns the requested geometry of one goniometer and moves it on the bench's worker.

    ``target`` holds the axis setpoints (``theta_r`` signed in the plane of ``phi_r``);
    ``reached`` is the last geometry the goniometer reported. Listeners get the axis read-backs
    after every move.
    """

    def __init__(self, goniometer: Any, worker: BenchWorker, start: Geometry) -> None:
        self.goniometer = goniometer
        self.worker = worker
        self.reached = start
        self.target = dict(start.as_dict())
        if start.theta_r == 0.0:  # azimuth undefined at the zenith: the specular plane, as in plan files
            self.target["phi_r"] = (start.phi_i + 180.0) % 360.0
        self._pending: dict[str, float] = {}
        self._batch: asyncio.Task | None = None
        self._listeners: list[Callable[[dict[str, float]], None]] = []
        self.moves = 0  # move_to calls issued (tests count coalescing with it)

    # -- geometry <-> axes -----------------------------------------------------------------
    @staticmethod
    def geometry_of(axes: dict[str, float]) -> Geometry:
        """The geometry of axis values (``theta_r`` < 0 views across the normal)."""
        tr = float(axes["theta_r"])
        phi_r = float(axes["phi_r"]) + (180.0 if tr < 0 else 0.0)
        return Geometry(float(axes["theta_i"]), float(axes["phi_i"]), abs(tr), phi_r)

    def axes_of(self, g: Geometry) -> dict[str, float]:
        """Axis read-backs of a geometry, ``theta_r`` signed against the requested plane."""
        plane = float(self.target["phi_r"]) % 360.0
        out = {"theta_i": g.theta_i, "phi_i": g.phi_i}
        if g.theta_r == 0.0:
            out["theta_r"], out["phi_r"] = 0.0, plane
        elif _azimuth_gap(g.phi_r, plane) <= 90.0:
            out["theta_r"], out["phi_r"] = g.theta_r, g.phi_r
        else:
            out["theta_r"], out["phi_r"] = -g.theta_r, (g.phi_r + 180.0) % 360.0
        return out

    def subscribe(self, listener: Callable[[dict[str, float]], None]) -> None:
        self._listeners.append(listener)
        listener(self.axes_of(self.reached))

    def _publish(self, g: Geometry) -> None:
        self.reached = g
        axes = self.axes_of(g)
        for listener in self._listeners:
            listener(axes)

    # -- checking and moving ---------------------------------------------------------------
    def check(self, **changes: float) -> Geometry:
        """The geometry with ``changes`` applied, checked by the bench (pure: no byte sent)."""
        g = self.geometry_of({**self.target, **changes})
        self.goniometer.check(g)
        return g

    async def move(self, **changes: float) -> Geometry:
        """Request ``changes``; join (or start) the next move; return the geometry reached."""
        for k, v in changes.items():
            if k not in AXES:
                raise GeometryError(f"unknown goniometer axis {k!r}; known: {', '.join(AXES)}")
            self._pending[k] = float(v)
        if self._batch is None:
            self._batch = asyncio.get_running_loop().create_task(self._run_batch())
        return await asyncio.shield(self._batch)

    async def _run_batch(self) -> Geometry:
        try:
            for _ in range(_COALESCE_ITERATIONS):
                await asyncio.sleep(0)
        finally:
            self._batch = None  # later requests start the next batch
            changes, self._pending = self._pending, {}
        g = self.check(**changes)  # the combined target, before any byte; refused -> target kept
        self.target.update(changes)
        return await self._move(g)

    async def _move(self, g: Geometry) -> Geometry:
        """Move to ``g`` on the worker and publish the read-back (after a fault: read it back)."""
        self.moves += 1
        try:
            reached = await self.worker.run(self.goniometer.move_to, g)
        except BaseException:
            await self.refresh()
            raise
        self._publish(reached)
        return reached

    async def restore(self, before: Geometry) -> Geometry:
        """Return the arm to the setpoint if something other than a move (measuring the white
        standard) left it away from ``before``, the read-back it had; returns the geometry reached.

        A setpoint that is not a geometry the bench measures at (a parked arm: the detector in
        the beam) is not returned to: the plan moves the arm before its first trigger (a scan's
        motors move after staging), and :meth:`check_at_setpoint` refuses a trigger away from it."""
        now = await self.refresh()
        if _same_place(now, before):
            return now
        g = self.geometry_of(self.target)
        try:
            self.goniometer.check(g)
        except GeometryError:
            return now
        return await self._move(g)

    def check_at_setpoint(self) -> Geometry:
        """The geometry a trigger reads at: the read-back, refused (no reading) when it is not the
        setpoint -- a count would otherwise read where the white left the arm while ``locate()``
        reports the setpoint."""
        g, r = self.geometry_of(self.target), self.reached
        near = (abs(r.theta_i - g.theta_i) <= _AT_SETPOINT_DEG and abs(r.theta_r - g.theta_r) <= _AT_SETPOINT_DEG
                and (min(r.theta_i, g.theta_i) < 1e-6 or _azimuth_gap(r.phi_i, g.phi_i) <= _AT_SETPOINT_DEG)
                and (min(r.theta_r, g.theta_r) < 1e-6 or _azimuth_gap(r.phi_r, g.phi_r) <= _AT_SETPOINT_DEG))
        if not near:
            raise GeometryError(f"the arm is at {self.reached}, not at the goniometer's setpoint {g} (a parked "
                                f"arm is not returned to after the white): move it to a measuring geometry "
                                f"before the first trigger")
        return self.reached

    async def refresh(self) -> Geometry:
        """Read the position back (after a fault, a stop or a calibration that moved the arm)."""
        try:
            g = await self.worker.run(self.goniometer.position)
        except Exception:  # the device may be gone; keep the last known position
            return self.reached
        self._publish(g)
        return g

    async def stop(self) -> None:
        """Hold the goniometer (after any move in the worker has ended), then read back. A closed
        bench's goniometer was stopped when it closed (:meth:`Devices.close`): nothing to do (the
        RunEngine stops every device it moved when a plan ends, even one the plan closed)."""
        if self.worker.closed:
            return
        await self.worker.run(self.goniometer.stop)
        await self.refresh()


@dataclass
class _AxisLogic(MovableLogic[float]):
    mover: Mover | None = None
    axis: str = ""

    async def check_move(self, new_position: float) -> None:
        # the safety rules apply to the combined geometry of the axes set together: the mover
        # checks it on the loop before any byte (see the module docstring); here, the number
        try:
            ok = math.isfinite(float(new_position))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise GeometryError(f"{self.axis} must be a finite number of degrees, got {new_position!r}")

    async def move(self, new_position: float, timeout: Any) -> None:
        assert self.mover is not None
        seconds = timeout()  # set(value, timeout=...): the status fails with TimeoutError when late;
        try:                 # the move itself ends in the worker, bounded by the driver's settle timeout
            await asyncio.wait_for(self.mover.move(**{self.axis: new_position}), seconds)
        finally:  # the setpoint is the accepted request (a refused one leaves the last)
            await self.setpoint.set(float(self.mover.target[self.axis]))

    async def stop(self) -> None:
        assert self.mover is not None
        await self.mover.stop()


class GoniometerAxis(StandardReadable, StandardMovable[float]):
    """One goniometer axis in degrees: Movable, Readable (read-back), Locatable, Stoppable."""

    def __init__(self, mover: Mover, axis: str, name: str = "", hardware: str = "goniometer") -> None:
        if axis not in AXES:
            raise GeometryError(f"unknown goniometer axis {axis!r}; known: {', '.join(AXES)}")
        self._mover = mover
        self._axis = axis
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.readback, self._set_readback = hw_signal_r(float, 0.0, hardware, units="deg", precision=4)
        self.setpoint = hw_signal_rw(float, float(mover.target[axis]), hardware, units="deg", precision=4)
        mover.subscribe(lambda axes: self._set_readback(float(axes[axis])))
        super().__init__(name=name)

    @cached_property
    def movable_logic(self) -> _AxisLogic:
        return _AxisLogic(setpoint=self.setpoint, readback=self.readback, mover=self._mover, axis=self._axis)


class GoniometerDevice(StandardReadable):
    """The goniometer: four axis children, and ``set(geometry)`` moving all of them at once.

    ``set`` takes a :class:`~bench.core.geometry.Geometry` or ``[theta_i, phi_i, theta_r,
    phi_r]``; ``read()`` gives the four read-backs; ``locate()`` gives the requested and the
    reached geometry as 4-lists; ``stop()`` holds the arm.
    """

    def __init__(self, goniometer: Any, worker: BenchWorker, start: Geometry, name: str = "",
                 hardware: str = "goniometer") -> None:
        self.mover = Mover(goniometer, worker, start)
        with self.add_children_as_readables():
            self.theta_i = GoniometerAxis(self.mover, "theta_i", hardware=hardware)
            self.phi_i = GoniometerAxis(self.mover, "phi_i", hardware=hardware)
            self.theta_r = GoniometerAxis(self.mover, "theta_r", hardware=hardware)
            self.phi_r = GoniometerAxis(self.mover, "phi_r", hardware=hardware)
        super().__init__(name=name)

    @property
    def axes(self) -> dict[str, GoniometerAxis]:
        return {a: getattr(self, a) for a in AXES}

    @staticmethod
    def _geometry(value: Geometry | Sequence[float]) -> Geometry:
        if isinstance(value, Geometry):
            return value
        try:
            vals = [float(v) for v in value]
        except (TypeError, ValueError):
            raise GeometryError(f"a goniometer target is a Geometry or [theta_i, phi_i, theta_r, phi_r], "
                                f"got {value!r}") from None
        if len(vals) != 4:
            raise GeometryError(f"a goniometer target has 4 angles (theta_i, phi_i, theta_r, phi_r), got {value!r}")
        return Geometry(*vals)

    @AsyncStatus.wrap
    async def set(self, value: Geometry | Sequence[float], timeout: float | None = None) -> None:
        g = self._geometry(value)
        changes = g.as_dict()
        try:
            await asyncio.wait_for(self.mover.move(**changes), timeout)
        finally:
            await asyncio.gather(*(ax.setpoint.set(float(self.mover.target[a])) for a, ax in self.axes.items()))

    async def locate(self) -> Location[list[float]]:
        return Location(setpoint=[float(self.mover.target[a]) for a in AXES],
                        readback=[float(v) for v in self.mover.axes_of(self.mover.reached).values()])

    async def stop(self, success: bool = True) -> None:
        await self.mover.stop()
