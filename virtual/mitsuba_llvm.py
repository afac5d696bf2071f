"""Mitsuba specimens sampled in wavefronts on Dr.Jit's LLVM back end.

:class:`virtual.specimens.mitsuba.MitsubaSpecimen` calls ``bsdf.sample`` once per ray in a scalar variant
(about 1e6 rays/s). When an LLVM variant can run -- ``mitsuba`` installed and a libLLVM shared
object found (:func:`llvm_library`: ``DRJIT_LIBLLVM_PATH``, else Debian's ``libllvm19``) --
:class:`WavefrontSampler` hands the whole batch to the LLVM twin of the scalar variant
(``scalar_rgb`` -> ``llvm_ad_rgb``, ``scalar_spectral`` -> ``llvm_ad_spectral``) as one call.
It consumes the *same* uniforms as the scalar loop (sample1 and sample2 per ray, from the
caller's numpy generator) and both variants compute in single precision, so the two paths give
the same directions and weights to rounding: the counts keep the scalar path's distribution
(tested in ``tests/test_mitsuba_llvm.py``). The scalar loop stays the fallback.

The LLVM variant is entered for each call and left after, so the global variant the rest of the
program sees does not change.
"""

from __future__ import annotations

import contextlib
import functools
import os
from pathlib import Path
from typing import Any, Iterator

import numpy as np

__all__ = ["LIBLLVM_CANDIDATES", "llvm_library", "llvm_variant", "llvm_status", "WavefrontSampler"]

#: Where Debian/Ubuntu put libLLVM (the newest first), of the versions whose x86 back end lowers
#: every operation Mitsuba's samplers emit. Dr.Jit itself accepts LLVM 15 or newer, but LLVM 15
#: aborts the whole process ("LLVM ERROR: Cannot select: f32 = fmaximum") on the first BSDF
#: sample -- an abort no probe in the process can catch -- and 14 is refused by Dr.Jit. A
#: library of another version is used only when named by ``DRJIT_LIBLLVM_PATH``.
LIBLLVM_VERSIONS = (21, 20, 19, 18)
LIBLLVM_CANDIDATES = tuple(f"/usr/lib/x86_64-linux-gnu/libLLVM-{v}.so" for v in LIBLLVM_VERSIONS) + tuple(
    f"/usr/lib/x86_64-linux-gnu/libLLVM.so.{v}.1" for v in LIBLLVM_VERSIONS)
#: Set to "0" to keep Mitsuba specimens on the scalar loop.
ENV_SWITCH = "GONIOBENCH_MITSUBA_LLVM"


def llvm_library() -> str | None:
    """The libLLVM Dr.Jit will load: ``DRJIT_LIBLLVM_PATH`` when set (None if that file does not
    exist), else the first existing :data:`LIBLLVM_CANDIDATES` entry, which is then exported as
    ``DRJIT_LIBLLVM_PATH`` (read when Dr.Jit first starts its LLVM back end)."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env if Path(env).exists() else None
    for c in LIBLLVM_CANDIDATES:
        if Path(c).exists():
            os.environ["DRJIT_LIBLLVM_PATH"] = c
            return c
    return None


@contextlib.contextmanager
def _in_variant(variant: str) -> Iterator[Any]:
    """``mitsuba`` switched to ``variant`` inside the block, back to the previous one after
    (``mitsuba.util.scoped_set_variant`` fails when no variant was set before)."""
    import mitsuba as mi

    old = mi.variant()
    mi.set_variant(variant)
    try:
        yield mi
    finally:
        if old is not None and old != variant:
            mi.set_variant(old)


def llvm_variant(scalar_variant: str) -> str:
    """The LLVM twin of a scalar variant: ``scalar_rgb`` -> ``llvm_ad_rgb``."""
    return "llvm_ad_" + scalar_variant.removeprefix("scalar_")


@functools.lru_cache(maxsize=None)
def llvm_status(variant: str = "llvm_ad_rgb") -> str:
    """``""`` when ``variant`` runs here, else why not (one line)."""
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return f"disabled by {ENV_SWITCH}=0"
    if llvm_library() is None:
        return (f"no libLLVM {min(LIBLLVM_VERSIONS)} or newer found (apt-get install libllvm19, or set "
                "DRJIT_LIBLLVM_PATH)")
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        return "mitsuba is not installed (pip install 'goniobench[mitsuba]')"
    if variant not in mi.variants():
        return f"this mitsuba build has no {variant} variant"
    try:
        with _in_variant(variant):
            dr.eval(dr.arange(mi.Float, 4) + 1)  # starts the LLVM back end
    except Exception as exc:  # any failure of the back end means "not usable"
        return f"{variant} failed: {type(exc).__name__}: {exc}"
    return ""


class WavefrontSampler:
    """One Mitsuba BSDF loaded in an LLVM variant, sampled a batch at a time.

    Parameters
    ----------
    definition : dict
        The Mitsuba BSDF dictionary.
    scalar_variant : str
        The specimen's scalar variant; the LLVM twin (:func:`llvm_variant`) is used.

    The BSDF is loaded with the LLVM variant switched on (once); sampling then uses that
    variant's module directly (``mitsuba.llvm_ad_rgb``), since switching variants reloads
    Python modules (~0.1 s). Dr.Jit compiles the sampling kernel on first use and caches it
    (in memory and on disk).
    """

    def __init__(self, definition: dict, scalar_variant: str) -> None:
        import mitsuba

        self.variant = llvm_variant(scalar_variant)
        self.spectral = "spectral" in self.variant
        with _in_variant(self.variant) as mi:
            self._bsdf = mi.load_dict(definition)
            self._ctx = mi.BSDFContext(mi.TransportMode.Importance)
        self._m = getattr(mitsuba, self.variant)

    def sample(self, wi: np.ndarray, u: np.ndarray, wavelength_nm: float) -> tuple[np.ndarray, np.ndarray]:
        """``bsdf.sample`` of every ray at once.

        ``wi`` (3,) or (n, 3) toward the source; ``u`` (n, 3): sample1, then sample2. Returns
        the sampled directions (n, 3) and the weights (n,) (the first channel in spectral
        variants, the channels' mean in RGB ones), both float64 -- what the scalar loop returns.
        """
        import drjit as dr

        m, n = self._m, u.shape[0]
        uf = np.asarray(u, dtype=np.float32).T.copy()  # (3, n), rows contiguous
        w = np.asarray(wi, dtype=np.float32)
        si = dr.zeros(m.SurfaceInteraction3f, n)
        if w.ndim == 1:
            si.wi = m.Vector3f(float(w[0]), float(w[1]), float(w[2]))
        else:
            wt_ = w.T.copy()
            si.wi = m.Vector3f(wt_[0], wt_[1], wt_[2])
        if self.spectral:
            si.wavelengths = m.Spectrum(float(wavelength_nm))
        bs, weight = self._bsdf.sample(self._ctx, si, m.Float(uf[0]), m.Point2f(uf[1], uf[2]))
        dr.eval(bs.wo, weight)
        wo = np.stack([bs.wo.x.numpy(), bs.wo.y.numpy(), bs.wo.z.numpy()], axis=1).astype(np.float64)
        wt = np.asarray(weight.numpy(), dtype=np.float64).reshape(-1, n)
        return wo, (wt[0] if self.spectral else wt.mean(axis=0))
