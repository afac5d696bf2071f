"""Which libLLVM Dr.Jit is pointed at (:func:`virtual.mitsuba_llvm.llvm_library`): runs on every
machine, LLVM or not (the file system is faked)."""

from __future__ import annotations

import os


def test_a_libllvm_that_aborts_on_bsdf_sampling_is_never_picked(monkeypatch):
    """LLVM 15 (Debian 12's default) passes Dr.Jit's start-up but aborts the process on the first
    BSDF sample (x86 cannot select fmaximum): found alone, it is not used, and the status says
    what to install; named by DRJIT_LIBLLVM_PATH it is the user's choice."""
    import virtual.mitsuba_llvm as ml

    only = {"/usr/lib/x86_64-linux-gnu/libLLVM-15.so", "/usr/lib/x86_64-linux-gnu/libLLVM-14.so",
            "/usr/lib/x86_64-linux-gnu/libLLVM.so"}
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(ml, "Path", lambda p: type("P", (), {"exists": lambda self: str(p) in only})())
    assert ml.llvm_library() is None and "DRJIT_LIBLLVM_PATH" not in os.environ
    only.add("/usr/lib/x86_64-linux-gnu/libLLVM-19.so")  # power: a usable one is found
    assert ml.llvm_library() == "/usr/lib/x86_64-linux-gnu/libLLVM-19.so"
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")
    assert ml.llvm_library() == "/usr/lib/x86_64-linux-gnu/libLLVM-15.so"
