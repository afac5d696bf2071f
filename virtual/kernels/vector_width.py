"""The vector width each kernel family is compiled for, chosen here rather than by the CPU's tuning.

LLVM decides how wide a loop's vectors are from the target's *tuning*, not only its features:
for Intel server cores (Skylake-SP through Emerald Rapids) it prefers 256-bit vectors even where
AVX-512 exists (the ``prefer-256-bit`` tuning flag), for AMD Zen 4/5 it uses 512 bits. The same
kernel then ran at two speeds on two AVX-512 machines for a reason that was neither's hardware.
Each block kernel instead carries LLVM's function attribute ``"prefer-vector-width"``, which
overrides the tuning for that function (LLVM's X86 subtarget reads it per function), from the
declared table :data:`FAMILY_WIDTH` (a kernel names its family; the other functions of a block
kernel's module take the module's, :data:`MODULE_FAMILY`):

* AVX-512 hosts compile every family for 512-bit vectors: on an Intel Xeon (Emerald Rapids) the
  512-bit build ran GGX 2.39x, Lambertian 3.33x, plastic 1.14x, leaf 1.10x, dielectric 1.47x,
  roughplastic 0.91x of Mitsuba's rows against 1.78x, 2.17x, 0.81x, 0.86x, -, 0.77x with the
  tuning's 256 bits (one run of ``python -m benchmarks gonio``); AMD Zen 5's own tuning is 512.
* A host without AVX-512 ignores the attribute (LLVM never uses registers the target lacks).

The width is a choice of speed only: every kernel is IEEE-rounded lane by lane (no
reassociation, no estimates: :data:`virtual.kernels.FASTMATH`), so the counts are the same bits
at any width -- checked by ``tests/test_same_bits.py`` for every LLVM target the host can run,
at the table's width and at 256 bits.

``GONIOBENCH_VECTOR_WIDTH=256`` (or ``512``) overrides the table for a process (tests and
benchmarks); the width in force is part of every kernel's cache stamp, so a cached kernel of
another width is never loaded.

numba has no per-function attribute option: :func:`install` wraps numba's
``BaseContext.declare_function`` (once, idempotently) to add the attribute to the functions
:func:`register` was told about, and to nothing else.
"""

from __future__ import annotations

import os
import pickle
import re
import shutil
import subprocess
import tempfile
from typing import Any

from numba.core import base

__all__ = ["FAMILY_WIDTH", "MODULE_FAMILY", "ENV", "register", "width_of", "stamp", "install", "compiled_width", "target"]

#: Preferred vector width in bits, per kernel family (the module docstring says why).
FAMILY_WIDTH: dict[str, int] = {
    "block32": 512,     # float32 block kernel: Lambertian, GGX, Phong, Oren-Nayar, dielectric, plastic
    "coat32": 512,      # float32 coated block kernel: rough plastic, leaf
    "spectral32": 512,  # float32 spectral batches (Lambertian, GGX)
    "block64": 512,     # float64 block kernels (plain and coated) and spectral batches
    "xoshiro": 512,     # the 64-lane xoshiro fills every block kernel draws its uniforms from
}
#: The family of every other function compiled in a block kernel's module (the helpers a kernel
#: calls rather than inlines: finishing a block, reading tables): their loops vectorize at the
#: family's width too, not at the tuning's.
MODULE_FAMILY: dict[str, str] = {
    "virtual.kernels.block32": "block32",
    "virtual.kernels.f32": "block32",
    "virtual.kernels.branchfree32": "block32",
    "virtual.kernels.block32_coat": "coat32",
    "virtual.kernels.spectral32": "spectral32",
    "virtual.kernels.block64": "block64",
    "virtual.kernels.block_coat": "block64",
    "virtual.kernels.coat": "block64",
    "virtual.kernels.xoshiro": "xoshiro",
}
#: Environment variable overriding the table for the whole process: ``256`` or ``512``.
ENV = "GONIOBENCH_VECTOR_WIDTH"
_WIDTHS = (256, 512)
_ATTRIBUTE = "prefer-vector-width"

#: (module, qualified name) of each registered kernel -> its family.
_REGISTERED: dict[tuple[str, str], str] = {}


def _override() -> int | None:
    raw = os.environ.get(ENV, "").strip()
    if not raw:
        return None
    if raw not in {str(w) for w in _WIDTHS}:
        raise ValueError(f"{ENV} must be one of {', '.join(map(str, _WIDTHS))}, got {raw!r}")
    return int(raw)


def width_of(family: str) -> int:
    """The vector width (bits) family ``family`` is compiled for in this process."""
    if family not in FAMILY_WIDTH:
        raise ValueError(f"unknown kernel family {family!r}; known: {', '.join(sorted(FAMILY_WIDTH))}")
    return _override() or FAMILY_WIDTH[family]


def stamp() -> str:
    """The widths in force, as text: part of every kernel's cache stamp."""
    return ",".join(f"{f}={width_of(f)}" for f in sorted(FAMILY_WIDTH))


def register(module: str, qualname: str, family: str) -> None:
    """Compile the function ``module.qualname`` for ``family``'s vector width."""
    width_of(family)  # an unknown family fails at decoration, not at the first call
    _REGISTERED[(module, qualname)] = family
    install()


def install() -> None:
    """Wrap numba's ``declare_function`` once so registered functions get the width attribute."""
    if getattr(base.BaseContext.declare_function, "_goniobench_width", False):
        return
    declare = base.BaseContext.declare_function

    def declare_function(self: Any, module: Any, fndesc: Any) -> Any:
        fn = declare(self, module, fndesc)
        family = _REGISTERED.get((fndesc.modname, fndesc.qualname))
        if family is not None:
            # llvmlite's AttributeSet accepts only enum attributes by name; a string attribute is
            # written into the IR as it stands, so it is added past that check.
            set.add(fn.attributes, f'"{_ATTRIBUTE}"="{width_of(family)}"')
        return fn

    declare_function._goniobench_width = True  # type: ignore[attr-defined]
    base.BaseContext.declare_function = declare_function  # type: ignore[method-assign]


def target() -> dict[str, str]:
    """The LLVM target numba compiles for in this process: CPU name and feature string."""
    from numba.core.registry import cpu_target

    codegen = cpu_target.target_context.codegen()
    return {"cpu": codegen._get_host_cpu_name(), "features": codegen._tm_features}


_REGISTER = re.compile(r"%([xyz])mm\d+")
_BITS = {"x": 128, "y": 256, "z": 512}


def _object_code(dispatcher: Any, sig: Any) -> bytes | None:
    """The machine code (an ELF object) numba keeps for ``dispatcher``'s overload ``sig``: from
    its on-disk cache, where a cached kernel's code lives once the JIT has taken it."""
    cache = getattr(dispatcher, "_cache", None)
    if cache is None or not hasattr(cache, "_cache_file"):
        return None
    from numba.core.registry import cpu_target

    try:
        key = cache._index_key(sig, cpu_target.target_context.codegen())
        data = cache._cache_file.load(key)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError):
        return None
    found: list[bytes] = []

    def walk(x: Any) -> None:
        if isinstance(x, (bytes, bytearray)) and bytes(x[:4]) == b"\x7fELF":
            found.append(bytes(x))
        elif isinstance(x, (tuple, list)):
            for y in x:
                walk(y)

    walk(data)
    return found[0] if found else None


def compiled_width(dispatcher: Any) -> int | None:
    """The widest vector register (bits) in ``dispatcher``'s compiled code, read from the code
    itself (numba's assembly for a kernel compiled in this process, else its cached object code
    disassembled by binutils' ``objdump``); None when neither can be read."""
    widest = None
    for sig in dispatcher.signatures:
        library = dispatcher.overloads[sig].library
        if not getattr(library, "_disable_inspection", False):
            text = dispatcher.inspect_asm(sig)
        else:
            obj = _object_code(dispatcher, sig)
            objdump = shutil.which("objdump")
            if obj is None or objdump is None:
                continue
            with tempfile.NamedTemporaryFile(suffix=".o") as f:
                f.write(obj)
                f.flush()
                text = subprocess.run([objdump, "-d", "--no-show-raw-insn", f.name], capture_output=True,
                                      text=True, check=False).stdout
        bits = [_BITS[m] for m in _REGISTER.findall(text)]
        if bits:
            widest = max(widest or 0, max(bits))
    return widest
