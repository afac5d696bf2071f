"""Measure the goniophotometer study with code for a narrower vector ISA than the CPU has.

``python -m benchmarks gonio --isa avx2`` on an AVX-512 machine compiles *both* sides of the
comparison for AVX2 -- numba's kernels (``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES``: the host's
CPU name and features with every AVX-512 feature turned off) and Mitsuba's Dr.Jit LLVM back end
(``jit_llvm_set_target`` of drjit-core: the same features, 8 float32 lanes) -- so that the ratios
an AVX2 machine would see can be measured beside the native ones on one machine. The run is the
same core executing 256-bit code, not another CPU: its JSON says both (``cpu.vector_isa`` the
CPU's, ``cpu.compiled_isa`` the code's).

numba reads its target once, when it is imported, so :func:`reexec` starts the study again in a
fresh interpreter with the environment set; :data:`ENV` tells that process what it was asked.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path
from typing import Any

__all__ = ["ISAS", "ENV", "requested", "narrowed_features", "reexec", "restrict_drjit", "compiled_isa"]

#: The ISAs a study can be compiled for: ``native`` (numba's and Dr.Jit's own choice) or ``avx2``.
ISAS = ("native", "avx2")
#: Set in the re-executed process: the ISA it compiles for.
ENV = "GONIOBENCH_BENCH_ISA"

_AVX2_LANES_F32 = 8
#: Feature prefixes that imply 512-bit vectors (AVX-512, its EVEX encodings, AVX10, AMX tiles).
_WIDE = ("avx512", "evex512", "avx10", "amx")
#: drjit-core's ``jit_llvm_set_target(const char *, const char *, uint32_t)`` (C++ linkage).
_SET_TARGET = "_Z19jit_llvm_set_targetPKcS0_j"
_VECTOR_WIDTH = "_Z21jit_llvm_vector_widthv"
#: What Dr.Jit is told on top of the host CPU: no AVX-512 (LLVM turns off every feature that needs
#: it; the full host list would name features its own, older LLVM may not know).
_DRJIT_NARROW = "-avx512f"


def requested() -> str:
    """The ISA this process compiles for (``native`` unless :func:`reexec` set :data:`ENV`)."""
    return os.environ.get(ENV, "native")


def narrowed_features(features: str) -> str:
    """LLVM's comma-separated ``+feat``/``-feat`` list with every 512-bit feature turned off."""
    out = []
    for f in filter(None, features.split(",")):
        name = f[1:] if f[0] in "+-" else f
        out.append(f"-{name}" if name.startswith(_WIDE) else f)
    return ",".join(out)


def _host() -> tuple[str, str]:
    from llvmlite import binding

    binding.initialize_native_target()
    return binding.get_host_cpu_name(), binding.get_host_cpu_features().flatten()


def reexec(isa: str, argv: list[str]) -> None:
    """Run ``python -m benchmarks ARGV`` again with numba targeting ``isa`` (does not return)."""
    if isa not in ISAS:
        raise ValueError(f"--isa must be one of {', '.join(ISAS)}, got {isa!r}")
    env = dict(os.environ, **{ENV: isa})
    if isa == "avx2":
        cpu, features = _host()
        env.update(NUMBA_CPU_NAME=cpu, NUMBA_CPU_FEATURES=narrowed_features(features))
    sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, "-m", "benchmarks", *argv], env)


def _drjit_core() -> ctypes.CDLL:
    import drjit

    return ctypes.CDLL(str(Path(drjit.__file__).with_name("libdrjit-core.so")))


def restrict_drjit() -> str:
    """After Dr.Jit's LLVM back end is up: compile its kernels for :func:`requested` (a no-op for
    ``native``). Returns "" or why it could not (the anchor then says it is not available)."""
    if requested() == "native":
        return ""
    try:
        core = _drjit_core()
        set_target, width = core[_SET_TARGET], core[_VECTOR_WIDTH]
    except (OSError, AttributeError, ImportError) as exc:
        return f"cannot narrow Dr.Jit to {requested()} ({type(exc).__name__}: {exc})"
    cpu = os.environ.get("NUMBA_CPU_NAME", "")
    set_target.argtypes, set_target.restype = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32], None
    set_target(cpu.encode(), _DRJIT_NARROW.encode(), _AVX2_LANES_F32)
    width.restype = ctypes.c_uint32
    got = int(width())
    return "" if got == _AVX2_LANES_F32 else f"Dr.Jit kept {got} lanes after asking for {_AVX2_LANES_F32}"


def compiled_isa(cpu: dict[str, Any]) -> str:
    """The ISA the study's code is compiled for: the CPU's own unless narrowed."""
    return cpu.get("vector_isa", "unknown") if requested() == "native" else requested()
