"""Every numba kernel of :mod:`virtual`, and the one cache policy they are compiled under.

Modules (each owns one kind of kernel; none holds Python-side objects):

``rng``         xoshiro256+ streams advanced in place (scalar and 64 lanes side by side), and
                64 xoshiro128+ lanes of float32 uniforms
``sampling``    scalar warps of uniforms into points of disks, triangles, the hemisphere
``beam``        emitting one incident ray (collimated or conical beam)
``collector``   the exact and the vectorizable patch lookup of the collector sphere
``microfacet``  Fresnel factors, GGX visible normals, masking ratios, frames
``scatter``     the specimen model ids and the ``scatter`` dispatch, one branch per model
``engine``      the bare counting kernels (ray by ray, and the vectorized float64 block kernel)
``f32``         float32 twins of the scalar helpers (warps, beam, bin guess, microfacet terms)
``given32``     float32 forms of the specimens (Lambertian, GGX, Phong, Oren-Nayar)
``given32_rough`` float32 forms of the rough dielectric and the rough plastic
``block32``     the float32 block kernel (16 lanes per AVX-512 vector), the default fast path
``effects``     the counting kernels with a scene's per-ray effects, float32 lookup, given points

The cache policy: decorate with :func:`jit` (never ``numba.njit(cache=True)``). numba's own
on-disk cache checks only the source file of the decorated function, so after an edit of a
kernel it *calls* (inlined or linked from another file) it would load machine code of the old
source. :func:`jit` marks the function, and :class:`KernelSourceLocator` -- registered first
among numba's cache locators -- gives every marked function a source stamp that is the hash of
*all* the modules of this package plus the function's own file (so kernels in ``tests/`` and
``benchmarks/`` decorated with :func:`jit` are covered too). Any edit of any kernel source makes
every cached index stale, and numba then recompiles and overwrites it: no file is ever deleted,
nothing happens at import time beyond registering the locator. Where the cache lives is numba's
usual choice (``NUMBA_CACHE_DIR`` if set, else ``__pycache__`` beside the source, else the
user-wide cache directory).
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Any, Callable

import numba
from numba.core import caching

__all__ = ["jit", "KernelSourceLocator", "kernel_sources_digest"]

#: Attribute set on the Python function of every kernel compiled by :func:`jit`.
MARK = "__goniobench_kernel__"
KERNELS_DIR = Path(__file__).resolve().parent

_CacheImpl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl")


#: Sources outside this package whose values the kernels compile in as constants.
KERNEL_CONSTANT_SOURCES = (KERNELS_DIR.parent / "model_ids.py",)


@functools.lru_cache(maxsize=1)
def kernel_sources_digest() -> str:
    """SHA-256 of every module of this package and of :data:`KERNEL_CONSTANT_SOURCES` (names and
    contents), read once per process."""
    h = hashlib.sha256()
    for src in [*sorted(KERNELS_DIR.glob("*.py")), *KERNEL_CONSTANT_SOURCES]:
        h.update(src.name.encode())
        h.update(b"\0")
        h.update(src.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _file_digest(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:  # no readable source (frozen, interactive): the package hash still applies
        return ""


class KernelSourceLocator(caching._CacheLocator):
    """numba cache locator for :func:`jit` kernels: numba's usual place, our source stamp.

    It wraps the locator numba would have chosen (so ``NUMBA_CACHE_DIR`` and the fallbacks keep
    working) and replaces only :meth:`get_source_stamp`.
    """

    def __init__(self, inner: Any, py_file: str) -> None:
        self._inner = inner
        self._py_file = py_file

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return self._inner.get_cache_path()

    def get_disambiguator(self) -> str:
        return self._inner.get_disambiguator()

    def get_source_stamp(self) -> str:
        """The hash of all kernel sources and of the decorated function's own file."""
        return f"{kernel_sources_digest()}:{_file_digest(str(self._py_file))}"

    @classmethod
    def from_function(cls, py_func: Callable, py_file: str) -> "KernelSourceLocator | None":
        if not getattr(py_func, MARK, False):
            return None  # not ours: numba's locators decide as usual
        for other in _CacheImpl._locator_classes:
            if other is cls:
                continue
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, py_file)
        return None


if KernelSourceLocator not in _CacheImpl._locator_classes:
    _CacheImpl._locator_classes.insert(0, KernelSourceLocator)


def jit(fn: Callable | None = None, /, **options: Any) -> Any:
    """``numba.njit`` with the package's on-disk cache policy (see the module docstring).

    Use as ``@jit`` or ``@jit(inline="always")``, ``@jit(parallel=True, fastmath=True)``...;
    ``cache`` is not an option: every kernel is cached under the policy.
    """
    if "cache" in options:
        raise TypeError("jit() sets the cache itself; do not pass cache=")

    def compile_(f: Callable) -> Any:
        setattr(f, MARK, True)
        return numba.njit(cache=True, **options)(f)

    return compile_ if fn is None else compile_(fn)
