"""Fake time for drivers: a clock that only ``sleep`` advances, and a transport wrapper that
waits (in that fake time) as long as a read is allowed to when the reply does not come. Tests
assert on this time -- timeouts respected, retries bounded -- never on the wall clock of a
loaded machine."""

from __future__ import annotations


class FakeClock:
    """Seconds that pass only when someone sleeps. Pass ``clock`` and ``clock.sleep`` to a
    driver; ``clock.elapsed`` is then the time its waits took."""

    def __init__(self, start: float = 1000.0) -> None:
        self.start = self.now = start
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += max(0.0, seconds)

    @property
    def elapsed(self) -> float:
        return self.now - self.start


class WaitingTransport:
    """Wraps a transport that never waits (a :class:`ScriptedTransport`, an in-process bus):
    a short read waits, in ``clock``'s time, the whole timeout it was given -- as a real port
    does when no reply comes. ``waits`` lists those timeouts; everything else is the wrapped
    transport's."""

    def __init__(self, transport, clock: FakeClock) -> None:
        self.transport = transport
        self.clock = clock
        self.waits: list[float] = []

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        data = self.transport.read(n, timeout)
        if len(data) < n:
            self.waits.append(timeout)
            self.clock.sleep(timeout)
        return data

    def __getattr__(self, name: str):
        return getattr(self.transport, name)
