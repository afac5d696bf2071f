"""Kernel compilation, shown while it happens and done ahead of time.

numba compiles a kernel the first time it is called with a new signature and caches the machine
code on disk (:mod:`virtual.kernels`); a cold cache costs 2-16 s per kernel family. Two
things keep that from looking like a hang or landing on a user's first command:

* :class:`CompileProgress` (a numba event listener, installed for the length of a CLI command by
  :func:`compile_progress`): on a terminal, one line per kernel family updated with elapsed seconds
  against an estimate (the family's last compile time on this machine, else a stated default);
  elsewhere, one plain line per kernel family as it starts. Nothing is printed when nothing compiles.
* :func:`warm_up` (``python -m bench.compilation``, run by ``make install``): calls every kernel
  family once through the public API on tiny inputs, in two processes, so the cache holds every
  kernel before the first command.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import importlib.util
import json
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterator, TextIO

__all__ = ["KERNEL_FAMILIES", "CompileProgress", "compile_progress", "WARM_UP", "warm_up", "main"]

#: Kernels called from Python, by name: (what the user reads, seconds a cold compile takes on a
#: 2-core machine, the estimate before this machine has compiled it once).
KERNEL_FAMILIES: dict[str, tuple[str, float]] = {
    "gonio_block_chunk": ("float64 block kernel", 10.0),
    "gonio_block32_chunk": ("float32 block kernel", 14.0),
    "gonio_coat_chunk": ("float64 block kernel of roughplastic and the leaf", 10.0),
    "gonio_coat32_chunk": ("float32 block kernel of roughplastic and the leaf", 16.0),
    "lambert_spectral_chunk": ("float64 spectral Lambertian batch", 3.0),
    "ggx_spectral_chunk": ("float64 spectral GGX batch", 4.0),
    "lambert_spectral32_chunk": ("float32 spectral Lambertian batch", 5.0),
    "ggx_spectral32_chunk": ("float32 spectral GGX batch", 5.0),
    "fresnel_bounds": ("Fresnel bound tables", 2.0),
    "spectro_fx_chunk": ("spectrophotometer kernel (ray by ray, scene effects by flag)", 9.0),
    "gonio_fx_chunk": ("goniophotometer kernel (ray by ray, scene effects by flag)", 8.0),
    "spectro_points_chunk": ("spectrophotometer kernel on given points", 2.0),
    "index_many": ("collector patch lookup", 1.0),
    "_warp_polar_array": ("disk sampler", 1.0),
    "_warp_triangle_array": ("triangle sampler", 1.0),
}

_HISTORY = "compile-seconds.json"


def _history_file(dispatcher: Any) -> Path | None:
    """Where this machine's compile times are kept: beside the dispatcher's cache, if any."""
    path = getattr(getattr(dispatcher, "_cache", None), "_cache_path", None)
    return Path(path) / _HISTORY if path else None


def _read_history(path: Path | None) -> dict[str, float]:
    try:
        data = json.loads(path.read_text()) if path else {}
        return {str(k): float(v) for k, v in data.items()} if isinstance(data, dict) else {}
    except (OSError, ValueError, TypeError):
        return {}


class CompileProgress:
    """numba ``numba:compile`` listener: a line per compiled kernel family (see the module docstring).

    Only the outermost compile of a known family is shown (its callees compile inside it).
    """

    def __init__(self, stream: TextIO | None = None, interactive: bool | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        if interactive is None:
            try:
                interactive = self.stream.isatty()
            except (AttributeError, ValueError):
                interactive = False
        self.interactive = interactive
        self._depth = 0
        self._current: tuple[str, str, float, float, Path | None] | None = None
        self._ticker: threading.Thread | None = None
        self._stop = threading.Event()
        self._header_said = False
        self.listener: Any = None

    def listen(self, event: Any) -> Any:
        """This progress as a listener of numba's event module ``event`` (``numba.core.event``)."""
        outer = self

        class _Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                outer._start(ev.data.get("dispatcher") if isinstance(ev.data, dict) else None)

            def on_end(self, ev: Any) -> None:
                outer._end()

        self.listener = _Listener()
        return self.listener

    def _say(self, text: str, end: str = "\n") -> None:
        try:
            print(text, end=end, file=self.stream, flush=True)
        except (OSError, ValueError):  # a closed or broken stderr must not fail the compile
            pass

    def _start(self, dispatcher: Any) -> None:
        self._depth += 1
        if self._depth != 1 or dispatcher is None:
            return
        name = getattr(getattr(dispatcher, "py_func", None), "__name__", "")
        if name not in KERNEL_FAMILIES:
            return
        label, default = KERNEL_FAMILIES[name]
        history = _history_file(dispatcher)
        estimate = _read_history(history).get(name, default)
        if not self._header_said:
            self._header_said = True
            self._say("compiling kernels (first run only)...")
        self._current = (name, label, estimate, time.perf_counter(), history)
        if not self.interactive:
            self._say(f"  compiling the {label} (about {estimate:.0f} s)")
            return
        self._stop.clear()
        self._ticker = threading.Thread(target=self._tick, daemon=True)
        self._ticker.start()

    def _tick(self) -> None:
        while not self._stop.wait(0.5):
            cur = self._current
            if cur is None:
                return
            _, label, estimate, t0, _ = cur
            elapsed = time.perf_counter() - t0
            left = max(estimate - elapsed, 0.0)
            self._say(f"\r  compiling the {label}: {elapsed:4.0f} s, about {left:.0f} s left   ", end="")

    def _end(self) -> None:
        self._depth = max(self._depth - 1, 0)
        if self._depth or self._current is None:
            return
        name, label, _, t0, history = self._current
        self._current = None
        seconds = time.perf_counter() - t0
        if self._ticker is not None:
            self._stop.set()
            self._ticker.join()
            self._ticker = None
            self._say(f"\r  compiled the {label} in {seconds:.0f} s" + " " * 24)
        if history is not None:
            with contextlib.suppress(OSError):
                data = _read_history(history)
                data[name] = round(seconds, 1)
                history.write_text(json.dumps(data, sort_keys=True))


class _AfterImport(importlib.abc.MetaPathFinder):
    """Calls ``action(module)`` right after module ``name`` is first imported (then leaves
    ``sys.meta_path``): a listener reaches numba's event bus without importing numba itself."""

    def __init__(self, name: str, action: Callable[[Any], None]) -> None:
        self.name, self.action = name, action

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != self.name:
            return None
        self.remove()
        spec = importlib.util.find_spec(fullname)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        run = loader.exec_module

        def exec_then_act(module: Any) -> None:
            run(module)
            self.action(module)

        loader.exec_module = exec_then_act
        return spec

    def remove(self) -> None:
        with contextlib.suppress(ValueError):
            sys.meta_path.remove(self)


@contextlib.contextmanager
def compile_progress(stream: TextIO | None = None, interactive: bool | None = None) -> Iterator[CompileProgress]:
    """Show kernel compiles (:class:`CompileProgress`) while the block runs. Loads nothing: when
    numba is not imported yet (a command on the certified fast path may never import it), the
    listener joins numba's event bus when it is."""
    progress = CompileProgress(stream, interactive)
    registered: list[Any] = []

    def register(event: Any) -> None:
        event.register("numba:compile", progress.listen(event))
        registered.append(event)

    hook = None
    if "numba.core.event" in sys.modules:
        register(sys.modules["numba.core.event"])
    else:
        hook = _AfterImport("numba.core.event", register)
        sys.meta_path.insert(0, hook)
    try:
        yield progress
    finally:
        if hook is not None:
            hook.remove()
        for event in registered:
            event.unregister("numba:compile", progress.listener)


# --- the warm-up ---------------------------------------------------------------------------------

def _gonio(kernel: str, spec: str = "ggx:alpha=0.2") -> None:
    from virtual.beam import Beam
    from virtual.collector import Collector
    from virtual.engine import gonio_counts, measurement_seed
    from virtual.specimens import parse_specimen

    sp, beam, col = parse_specimen(spec), Beam("conical"), Collector("equal-psa", 3, 6)
    gonio_counts(sp.model, sp.params(550.0), beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0), col.kernel_args(),
                 100, measurement_seed(1), kernel=kernel)


def _block64() -> None:
    _gonio("block")


def _block32() -> None:
    _gonio("block32")


def _coat64() -> None:
    _gonio("block", "leaf:healthy")  # gonio_coat_chunk (roughplastic's too)


def _coat32() -> None:
    _gonio("block32", "leaf:healthy")  # gonio_coat32_chunk (roughplastic's too)


def _spectral_batches() -> None:
    import numpy as np

    from virtual.beam import Beam
    from virtual.collector import Collector
    from virtual.engine import gonio_counts_spectral, measurement_seed
    from virtual.model_ids import MODEL_GGX, MODEL_LAMBERT
    from virtual.specimens import parse_specimen

    beam, col = Beam("conical"), Collector("equal-psa", 3, 6)
    lam, ggx = parse_specimen("lambert:albedo=0.5").params(550.0), parse_specimen("ggx:alpha=0.2").params(550.0)
    narrow = np.array([0.005, 0.005, *ggx[2:]])  # below float32's smallest roughness: the float64 batch
    for model, rows in ((MODEL_LAMBERT, [lam, 0.5 * lam]), (MODEL_GGX, [ggx, ggx]), (MODEL_GGX, [narrow, narrow])):
        gonio_counts_spectral(model, rows, beam.code, beam.disk_code, beam.kernel_args(30.0, 0.0), col.kernel_args(),
                              100, measurement_seed(1))


def _spectro_kernels() -> None:
    """The spectrophotometer's ray-by-ray kernels: its instrument, its scene effects, given points."""
    import numpy as np

    from virtual.beam import Beam
    from virtual.effects import spectro_effect_counts, spectro_point_counts
    from virtual.engine import NO_CONE, measurement_seed
    from virtual.spectrophotometer import VirtualSpectrophotometer
    from virtual.specimens import parse_specimen

    VirtualSpectrophotometer("lambert:reflectance=0.5", rays=100, beam="conical", seed=1).measure("8/d", [550.0])
    VirtualSpectrophotometer("lambert:reflectance=0.5", seed=1, uncertainty=0.2).measure("8/d", [550.0])
    sp, beam = parse_specimen("lambert:albedo=0.5"), Beam("conical")
    p, b = sp.params(550.0), beam.kernel_args(30.0, 0.0)
    spectro_effect_counts(sp.model, p[None, :], None, beam.code, beam.disk_code, b, NO_CONE, 0, None, 100,
                          measurement_seed(1))  # the instrument's kernel: loaded, not compiled again
    spectro_point_counts(sp.model, p, b, np.zeros((4, 4)), measurement_seed(1))


def _gonio_kernels() -> None:
    """The goniophotometer's ray-by-ray kernel (instrument and scene effects), its fast path and
    the samplers."""
    from virtual.beam import Beam
    from virtual.collector import Collector
    from virtual.effects import gonio_effect_counts
    from virtual.engine import measurement_seed
    from virtual.goniophotometer import VirtualGoniophotometer
    from virtual.specimens import parse_specimen

    VirtualGoniophotometer("lambert:albedo=0.5", rays=1000, method="fast", seed=1).simulate(30.0, 0.0, 550.0)
    _gonio("ray")
    sp, beam, col = parse_specimen("lambert:albedo=0.5"), Beam("conical"), Collector("equal-psa", 3, 6)
    gonio_effect_counts(sp.model, sp.params(550.0)[None, :], None, beam.code, beam.disk_code,
                        beam.kernel_args(30.0, 0.0), col.kernel_args(), 0, None, None, 100, measurement_seed(1))
    _samplers()


def _samplers() -> None:
    import numpy as np

    from virtual.collector import Collector
    from virtual.sampling import sample_disk, sample_triangle

    Collector("equal-psa", 3, 6).index(np.array([[0.0, 0.0, 1.0]]))
    sample_disk(4, 1.0, "polar", 1)
    sample_triangle(4, (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), "random", 1)


#: The warm-up's tasks, costliest first (seconds of a cold compile, each alone into an empty
#: cache, on a 2-core AMD EPYC Zen 5: the coated families' float32 block 18, the spectral batches
#: 15, float32 block 15, the coated families' float64 block 12, the spectrophotometer's 10, float64
#: block 10, the goniophotometer's ray kernel 9; together 21-30 s on two processes, less than the
#: sum because the per-ray helpers they share are compiled once per process at most and cached:
#: see :mod:`virtual.kernels`). No two tasks share a kernel, so no kernel is compiled twice (a
#: shared helper may be, once in each process, when both need it before either has cached it); two
#: workers take them in this order as each frees up (longest first: the two processes end within
#: one task's time of each other).
WARM_UP: tuple[Callable[[], None], ...] = (_coat32, _spectral_batches, _block32, _coat64, _spectro_kernels,
                                           _block64, _gonio_kernels)


_HEADER_SAID = [False]  # per worker process: its tasks say "compiling kernels" once between them


def _run_task(task: Callable[[], None]) -> None:
    with compile_progress(interactive=False) as progress:
        progress._header_said = _HEADER_SAID[0]
        try:
            task()
        finally:
            _HEADER_SAID[0] = progress._header_said


def warm_up(processes: int = 2) -> float:
    """Compile every kernel family into the on-disk cache (nothing is compiled when it is
    current); returns the seconds taken."""
    t0 = time.perf_counter()
    if processes <= 1:
        for task in WARM_UP:
            _run_task(task)
    else:
        with ProcessPoolExecutor(max_workers=min(processes, len(WARM_UP))) as pool:
            for f in [pool.submit(_run_task, t) for t in WARM_UP]:
                f.result()
    return time.perf_counter() - t0


def main() -> int:
    seconds = warm_up()
    print(f"kernels ready ({seconds:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
