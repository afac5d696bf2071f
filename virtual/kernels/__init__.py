"""Every numba kernel of :mod:`virtual`, and the one policy they are compiled under.

Modules (each owns one kind of kernel; none holds Python-side objects):

``xoshiro``     xoshiro256+ streams advanced in place (scalar and 64 lanes side by side), and
                64 xoshiro128+ lanes of float32 uniforms
``warps``       scalar warps of uniforms into points of disks, triangles, the hemisphere
``emit``        emitting one incident ray (collimated or conical beam); the beam vector's indices
``patch_lookup`` the exact and the vectorizable patch lookup of the collector sphere
``microfacet``  frames, unit-disk points, the laws' shared sampler steps (float64)
``ggx``         GGX's visible normals, masking ratios and reflection, the Fresnel factors, the rough
                dielectric's and plastic's steps from the normal on, written once: the float64 source of
``ggx32``       (generated, not checked in) its float32 twin, the same text on ``precision32``
``laws``        the scattering laws written once (a package: one module per law, its float64 source;
                its contract in ``laws/__init__.py``); ``lawcode`` writes the rest from them:
``laws32``      (generated, not checked in) each law's float32 twin: its source on ``precision32``
``law_dispatch`` (generated, not checked in) each law's branch of every kernel path: ray by ray,
                float64 block, float32 block, the float32 kernel's float64 second look
``lawcode``     the writer of ``laws32``, ``law_dispatch``, ``ggx32`` and :mod:`virtual.law_table`:
                all but the table when missing or stale as this package is imported (build
                products, like a compiled file), all by ``make install`` and ``make kernels``
``generate``    its command (``python -m virtual.kernels.generate``, ``make kernels``; ``--check``)
``precision64``, ``precision32`` the constants and helpers a law computes with, per precision
``scatter``     the ``scatter`` dispatch, one branch per model (the laws' through ``law_dispatch``),
                and the hand-written float64 forms of the models that are not laws yet
``coat``        Mitsuba's roughplastic: its tables and its ray-by-ray branch
``branchfree``  branch-free float64 forms of the hand-written specimens that need four or more
                uniforms per ray
``block64``     the vectorized float64 block kernel and the spectral batches
``block_coat``  the float64 block kernel of the coated families (roughplastic, leaf)
``f32``         float32 twins of the scalar helpers (warps, beam, bin guess, frame)
``branchfree32`` the float32 GGX survival step, Phong's float32 lobe cosine
``block32``     the float32 block kernel (as many lanes as the machine's vectors hold), the default fast path
``block32_coat`` the float32 block kernel of the coated families
``refine``      the float32 kernels' rays in doubt, decided again in float64 with 53-bit uniforms
``spectral32``  the float32 spectral batches
``vector_width`` the vector width each block kernel family is compiled for (a declared table,
                not the CPU's tuning)
``ray_loop``    the ray-by-ray counting kernels (a scene's per-ray effects by flag; none: the bare
                kernels), and the spectrophotometer on given disk points; the effect vector's indices

The floating-point policy (:data:`FASTMATH`): the same seed gives the same counts on every
x86-64 CPU. numba's ``fastmath=True`` lets LLVM replace a division or square root by the
vector unit's reciprocal estimates (12 bits on AVX2, 14 on AVX-512, refined differently), fuse
multiply-adds only where the CPU has FMA, and reassociate sums by the vector width: each of
these changes a direction in its last bits on one CPU and not another, and a ray near a patch
edge or a survival threshold then counts elsewhere. Kernels therefore get only the flags that
cannot change a finite result (no NaN or infinity is assumed); every operation is IEEE-rounded
the same way whatever the vector width. ``jit`` refuses
``fastmath=True``.

The cache policy: decorate with :func:`jit` (never ``numba.njit(cache=True)``). numba's own
on-disk cache checks only the source file of the decorated function, so after an edit of a
kernel it *calls* (inlined or linked from another file) it would load machine code of the old
source. :func:`jit` marks the function, and :class:`KernelSourceLocator` -- registered first
among numba's cache locators -- gives every marked function a source stamp that is the hash of
its own file and of every project module that file imports, directly or through others (the
kernels of ``tests/`` and ``benchmarks/`` included): a kernel can call only what its module
imports, so an edit of a file it cannot reach leaves its cache valid, and an edit of one it can
makes the cached index stale -- numba then recompiles and overwrites it: no file is ever deleted.
Importing the package registers the locator and writes the generated law code that is missing
or stale (:func:`virtual.kernels.lawcode.ensure_built`: nothing when current); nothing else. Where the cache lives is numba's
usual choice (``NUMBA_CACHE_DIR`` if set, else ``__pycache__`` beside the source, else the
user-wide cache directory).

The inlining policy: the per-ray helpers (warps, the beam, each law, the bin guess) are
``@jit(inline="llvm")``: numba compiles each once per signature and marks it ``alwaysinline``,
and LLVM inlines it into every kernel before it vectorizes the kernel's loops. numba's own
``inline="always"`` would instead copy the helper's IR into every call site and re-run its
passes there, nested helpers included: that front-end work was most of each kernel's compile
(float64 block kernel: 30 s cold with it, 10 s with LLVM inlining, on a Zen 5). The machine code is the
same kind: the same operations on the same values, vectorized the same way, so the counts are
bit for bit the same (``tests/test_same_bits.py``). ``inline="always"`` is kept for the few
block helpers whose loops must be inlined as IR to vectorize (see :func:`jit`).
"""

from __future__ import annotations

import ast
import functools
import hashlib
from pathlib import Path
from typing import Any, Callable

import numba
from numba.core import caching

from virtual.kernels import lawcode, vector_width

__all__ = ["jit", "FASTMATH", "KernelSourceLocator", "kernel_dependencies", "dependency_digest"]

#: Attribute set on the Python function of every kernel compiled by :func:`jit`.
MARK = "__goniobench_kernel__"
KERNELS_DIR = Path(__file__).resolve().parent

_CacheImpl = getattr(caching, "CacheImpl", None) or caching._CacheImpl


#: The fastmath flags every kernel is compiled with: those that cannot change a finite result
#: (see the module docstring). No ``arcp``/``afn`` (reciprocal and square-root estimates), no
#: ``contract`` (FMA only where the CPU has it), no ``reassoc`` (sums by vector width), no ``nsz``
#: (a zero's sign decides atan2's branch).
FASTMATH = frozenset({"nnan", "ninf"})

#: The folder holding the project's packages (``virtual``, ``bench``...): imports resolve here.
PROJECT_ROOT = KERNELS_DIR.parent.parent


def _module_file(name: str, root: Path) -> Path | None:
    """The file of module ``name`` under ``root`` (``a/b.py`` or ``a/b/__init__.py``), else None."""
    base = root.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


@functools.lru_cache(maxsize=None)
def _imports_of(path: Path) -> frozenset[Path]:
    """Project files that ``path`` imports directly: modules, and submodules named in a
    ``from package import name``; modules outside the project (numpy, numba) are left out.
    Parsed once per process: the kernels' closures share most of their files."""
    try:
        tree = ast.parse(path.read_bytes(), filename=str(path))
    except (OSError, SyntaxError, ValueError):
        return frozenset()
    roots = (PROJECT_ROOT, path.parent)
    found: set[Path] = set()

    def add(name: str, where: tuple[Path, ...] = roots) -> None:
        for root in where:
            f = _module_file(name, root) if name else None
            if f is not None:
                found.add(f.resolve())
                return

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the package folder up
                base = path.parent
                for _ in range(node.level - 1):
                    base = base.parent
                where: tuple[Path, ...] = (base,)
            else:
                where = roots
            module = node.module or ""
            init = where[0] / "__init__.py"
            if module:
                add(module, where)
            elif init.is_file():  # "from . import name": the package itself
                found.add(init.resolve())
            for alias in node.names:  # "from package import submodule"
                add(f"{module}.{alias.name}" if module else alias.name, where)
    return frozenset(found)


@functools.lru_cache(maxsize=None)
def kernel_dependencies(py_file: str) -> tuple[Path, ...]:
    """``py_file`` and every project file it imports, directly or through others, sorted."""
    start = Path(py_file).resolve()
    seen = {start}
    todo = [start]
    while todo:
        for dep in _imports_of(todo.pop()):
            if dep not in seen:
                seen.add(dep)
                todo.append(dep)
    return tuple(sorted(seen))


@functools.lru_cache(maxsize=None)
def dependency_digest(py_file: str) -> str:
    """SHA-256 of the names and contents of :func:`kernel_dependencies` of ``py_file`` ("" for a
    file that cannot be read: frozen or interactive code)."""
    h = hashlib.sha256()
    try:
        for dep in kernel_dependencies(py_file):
            h.update(dep.name.encode())
            h.update(b"\0")
            h.update(dep.read_bytes())
            h.update(b"\0")
    except OSError:
        return ""
    return h.hexdigest()


class DeferredDigest:
    """:func:`dependency_digest` of a file, computed when numba first compares or stores it.

    numba asks every cached dispatcher for its source stamp when the dispatcher is made, that is
    when a kernel module is imported; walking the imports then would cost every command that
    imports a kernel module and never calls it (the certified fast path, ``bench --help``) a
    parse of the kernels' whole closure. numba only compares the stamp with the one pickled in the
    cache index and pickles it: both work on this object, which pickles as the plain digest string.
    """

    __slots__ = ("py_file",)

    def __init__(self, py_file: str) -> None:
        self.py_file = py_file

    def value(self) -> str:
        return dependency_digest(self.py_file) + ";" + vector_width.stamp()

    def __eq__(self, other: object) -> bool:
        return self.value() == (other.value() if isinstance(other, DeferredDigest) else other)

    def __ne__(self, other: object) -> bool:
        return not self == other

    def __hash__(self) -> int:
        return hash(self.value())

    def __reduce__(self) -> tuple[type, tuple[str]]:
        return str, (self.value(),)

    def __repr__(self) -> str:
        return f"DeferredDigest({self.py_file!r})"


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

    def get_source_stamp(self) -> DeferredDigest:
        """The hash of the decorated function's file and of every project file it imports
        (computed when numba first needs it: :class:`DeferredDigest`)."""
        return DeferredDigest(str(self._py_file))

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
    """``numba.njit`` with the package's floating-point, cache and inlining policies (module
    docstring).

    Use as ``@jit``, ``@jit(inline="llvm")``, ``@jit(inline="always")``,
    ``@jit(nogil=True, error_model="numpy")``...; ``cache`` is not an option (every kernel is
    cached under the policy), nor is ``fastmath`` (every kernel gets :data:`FASTMATH`).

    ``family="block32"`` (a key of :data:`virtual.kernels.vector_width.FAMILY_WIDTH`) compiles
    the function for that family's declared vector width instead of the CPU tuning's choice.

    Inlining (see "The inlining policy" in the module docstring):

    * ``inline="llvm"`` -- a per-ray helper: compiled once per signature (and cached), marked
      ``alwaysinline`` so that LLVM inlines it into every caller before vectorizing; compiled
      with ``error_model="numpy"`` whoever calls it first, so its code never depends on a caller.
    * ``inline="always"`` -- numba inlines the function's IR into its caller: only for block
      helpers whose loops must see the caller's arrays (and constants) to vectorize without
      runtime alias checks, and for functions taking another function as an argument.
    * anything else is a call: never inlined, and not inheriting a caller's ``alwaysinline``.
    """
    if "cache" in options:
        raise TypeError("jit() sets the cache itself; do not pass cache=")
    if "fastmath" in options:
        raise TypeError("jit() sets fastmath itself (FASTMATH: flags that cannot change a finite result on any CPU)")
    if "forceinline" in options:
        raise TypeError('jit() sets forceinline itself: use inline="llvm"')
    if options.get("inline") == "llvm":
        del options["inline"]
        options.update(forceinline=True, error_model=options.get("error_model", "numpy"))
    elif options.get("inline", "never") == "never":
        options["forceinline"] = False  # numba would otherwise inherit it from the caller compiling it

    family = options.pop("family", None)

    def compile_(f: Callable) -> Any:
        setattr(f, MARK, True)
        chosen = family or vector_width.MODULE_FAMILY.get(f.__module__)
        if chosen is not None:
            vector_width.register(f.__module__, f.__qualname__, chosen)
        return numba.njit(cache=True, fastmath=set(FASTMATH), **options)(f)

    return compile_ if fn is None else compile_(fn)


# The float32 twins (laws, ggx) and the dispatch are build products (not checked in): written here,
# after jit exists (the laws import it), when a fresh checkout lacks them or a source changed since.
lawcode.ensure_built()
