"""Measure the goniophotometer study with code for a narrower vector ISA than the CPU has.

``python -m benchmarks gonio --isa avx2`` on an AVX-512 machine compiles *both* sides of the
comparison for the generic AVX2 target ``x86-64-v3`` (AVX2, FMA, BMI2; LLVM's own features and
tuning for it) -- numba's kernels (``NUMBA_CPU_NAME`` / ``NUMBA_CPU_FEATURES``) and Mitsuba's
Dr.Jit LLVM back end (``jit_llvm_set_target`` of drjit-core, 8 float32 lanes) -- so that the
ratios an AVX2 machine would see can be measured beside the native ones on one machine. The run
is the same core executing 256-bit code, not another CPU: its JSON says both
(``cpu.vector_isa`` the CPU's, ``cpu.compiled_isa`` the code's).

Why not the host's CPU name with its AVX-512 features turned off: LLVM then still tunes for
the wide core, and on a Zen 5 that made numba's GGX kernel 1.6x
slower than the same code for ``x86-64-v3`` -- not what an AVX2 machine runs.

numba reads its target once, when it is imported, so :func:`reexec` starts the study again in a
fresh interpreter with the environment set; :data:`ENV` tells that process what it was asked.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path
from typing import Any

__all__ = ["ISAS", "ENV", "TARGETS", "requested", "reexec", "restrict_drjit", "compiled_isa", "numba_code", "drjit_code"]

#: The ISAs a study can be compiled for: ``native`` (numba's and Dr.Jit's own choice) or ``avx2``.
ISAS = ("native", "avx2")
#: Set in the re-executed process: the ISA it compiles for.
ENV = "GONIOBENCH_BENCH_ISA"

_AVX2_LANES_F32 = 8
#: drjit-core's ``jit_llvm_set_target(const char *, const char *, uint32_t)`` (C++ linkage).
_SET_TARGET = "_Z19jit_llvm_set_targetPKcS0_j"
_VECTOR_WIDTH = "_Z21jit_llvm_vector_widthv"
#: The LLVM CPU each narrowed ISA compiles for (its default features: no per-host list, which
#: Dr.Jit's own, older LLVM might not know).
TARGETS = {"avx2": "x86-64-v3"}


def requested() -> str:
    """The ISA this process compiles for (``native`` unless :func:`reexec` set :data:`ENV`)."""
    return os.environ.get(ENV, "native")


def reexec(isa: str, argv: list[str]) -> None:
    """Run ``python -m benchmarks ARGV`` again with numba targeting ``isa`` (does not return)."""
    if isa not in ISAS:
        raise ValueError(f"--isa must be one of {', '.join(ISAS)}, got {isa!r}")
    env = dict(os.environ, **{ENV: isa})
    if isa in TARGETS:  # the target's own features: an empty list, not the host's
        env.update(NUMBA_CPU_NAME=TARGETS[isa], NUMBA_CPU_FEATURES="")
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
    set_target.argtypes, set_target.restype = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32], None
    set_target(TARGETS[requested()].encode(), None, _AVX2_LANES_F32)
    width.restype = ctypes.c_uint32
    got = int(width())
    return "" if got == _AVX2_LANES_F32 else f"Dr.Jit kept {got} lanes after asking for {_AVX2_LANES_F32}"


def compiled_isa(cpu: dict[str, Any]) -> str:
    """The ISA the study's code is compiled for: the CPU's own unless narrowed."""
    return cpu.get("vector_isa", "unknown") if requested() == "native" else requested()


def _chunk_kernel(model: int, shape: str) -> Any:
    """The numba dispatcher ``gonio_counts`` (or the spectral batch) ran for ``model`` as ``shape``."""
    from virtual import chunked
    from virtual.kernel_codes import COAT_MODELS
    from virtual.model_ids import MODEL_LAMBERT

    coat = int(model) in COAT_MODELS
    lambert = int(model) == MODEL_LAMBERT
    return {"block32": chunked.gonio_coat32_chunk if coat else chunked.gonio_block32_chunk,
            "block": chunked.gonio_coat_chunk if coat else chunked.gonio_block_chunk,
            "ray": chunked.gonio_fx_chunk,
            "spectral-float32": chunked.lambert_spectral32_chunk if lambert else chunked.ggx_spectral32_chunk,
            "spectral-float64": chunked.lambert_spectral_chunk if lambert else chunked.ggx_spectral_chunk}[shape]


def numba_code(model: int, shape: str) -> dict[str, Any]:
    """What our row's kernel was compiled for: LLVM target and features (numba's), and the widest
    vector register in its machine code (bits; read from the code, not assumed)."""
    from virtual.kernels import vector_width

    return {**vector_width.target(), "vector_bits": vector_width.compiled_width(_chunk_kernel(model, shape))}


def drjit_code() -> dict[str, Any]:
    """What Mitsuba's anchor rows were compiled for: Dr.Jit's LLVM target and its lane count."""
    try:
        core = _drjit_core()
        width = core[_VECTOR_WIDTH]
    except (OSError, AttributeError, ImportError) as exc:
        return {"cpu": "unknown", "features": "", "vector_bits": None, "note": f"{type(exc).__name__}: {exc}"}
    width.restype = ctypes.c_uint32
    lanes = int(width())
    cpu = TARGETS.get(requested(), "host")
    return {"cpu": cpu, "features": "", "vector_bits": 32 * lanes}
