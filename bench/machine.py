"""The machine figures come from: :func:`cpu_info` (CPU model, widest vector ISA, FMA, LLVM's CPU
name), stated in the benchmarks' tables and in ``bench tradeoff --design``'s output."""

from __future__ import annotations

import platform
from typing import Any

__all__ = ["cpu_info"]


def cpu_info() -> dict[str, Any]:
    """The CPU the figures come from: model name, vendor (``GenuineIntel``, ``AuthenticAMD``), the
    widest vector ISA it has (``avx512``,
    ``avx2``, ``avx``, ``sse4.2``, ``sse2``), whether it has FMA, and the CPU name LLVM compiles
    numba's kernels for."""
    flags: set[str] = set()
    model = platform.processor() or platform.machine()
    vendor = "unknown"
    try:
        for line in open("/proc/cpuinfo", encoding="utf-8", errors="replace"):
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                model = value.strip()
            elif key.strip() == "vendor_id":
                vendor = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
                break
    except OSError:
        pass
    isa = next((name for name, flag in (("avx512", "avx512f"), ("avx2", "avx2"), ("avx", "avx"),
                                        ("sse4.2", "sse4_2")) if flag in flags), "sse2")
    try:
        from llvmlite import binding

        llvm_cpu = binding.get_host_cpu_name()
    except Exception:  # informative only
        llvm_cpu = "unknown"
    return {"model": model, "vendor": vendor, "vector_isa": isa, "fma": "fma" in flags, "llvm_cpu": llvm_cpu}
