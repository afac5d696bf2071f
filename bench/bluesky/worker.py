"""The one worker thread of a bench: every blocking driver call runs here, never on the loop.

A serial port (and the SDKs on top of it) is not thread-safe, and the RunEngine's event loop
must not block. Each connected bench therefore owns one :class:`BenchWorker`: a single-thread
executor through which *all* its driver calls pass, in the order they were submitted. A status
awaiting a call can be cancelled or timed out on the loop; the call itself (a move waiting for
its axes to settle) finishes in the worker, bounded by the driver's own timeouts, and the next
call (``stop``) runs after it.
"""

from __future__ import annotations

import asyncio
import functools
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, TypeVar

from bench.core.errors import DeviceError

__all__ = ["BenchWorker"]

T = TypeVar("T")


class BenchWorker:
    """A single-thread executor for one bench's blocking calls.

    Parameters
    ----------
    name : str
        The bench's name (the thread is called ``goniobench-<name>``).
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"goniobench-{name}")
        self._thread: threading.Thread | None = None
        self._closed = False

    async def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run ``fn(*args, **kwargs)`` on the worker thread and await its result."""
        if self._closed:
            raise DeviceError(f"bench {self.name!r} is disconnected")
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, functools.partial(self._call, fn, *args, **kwargs))

    def call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run ``fn`` on the worker thread from ordinary (non-async) code and wait for it."""
        if self._closed:
            raise DeviceError(f"bench {self.name!r} is disconnected")
        return self._executor.submit(self._call, fn, *args, **kwargs).result()

    def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        self._thread = threading.current_thread()
        return fn(*args, **kwargs)

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def thread(self) -> threading.Thread | None:
        """The worker thread (``None`` before the first call)."""
        return self._thread

    def close(self) -> None:
        """Wait for the queued calls, then stop the thread. Idempotent."""
        if not self._closed:
            self._closed = True
            self._executor.shutdown(wait=True)
