"""Mitsuba 3 BSDFs as specimens (optional extra ``goniobench[mitsuba]``).

Any Mitsuba BSDF dictionary, e.g. ``{"type": "roughconductor", "distribution": "ggx",
"alpha": 0.2}``, becomes a black-box specimen: Mitsuba samples the scattering, our devices
count the rays. Specimen string: ``mitsuba:{json dict}``.

Frames. Mitsuba's BSDF local frame is the specimen frame (z the normal, the specimen plane
z = 0). ``si.wi`` points from the surface toward where the light comes from, as our ``wi``
does; ``bs.wo`` is where the light goes (oz > 0 reflected, oz < 0 transmitted), as our outgoing
directions. The context is ``TransportMode.Importance`` (light tracing: flux is carried from the
source), so a refracting BSDF's weight has no 1/eta^2 radiance factor and ``bsdf`` is the flux
BTDF that ray counting measures.

Weights -> analog sampling. ``bsdf.sample`` returns a direction drawn with density ``pdf`` and
a weight ``w = f |cos theta_o| / pdf``. We keep the direction and let the ray survive with
probability ``clip(w, 0, 1)`` (Russian roulette), so surviving rays have density
``pdf * w = f |cos theta_o|``: counting them estimates ``f`` without weights, like the kernel
specimens. The scalar weight ``w`` is the mean of the R, G, B channels in RGB variants (the
specimen is then the grey mean of the colour BSDF, and ``wavelength_nm`` is ignored), and the
channel at ``wavelength_nm`` in spectral variants (all of ``si.wavelengths`` are set to it).
A weight above 1 cannot be reproduced by an analog ray (Mitsuba's multi-lobe BSDFs such as
``plastic`` may return ``F / P(lobe) > 1``): it is clamped to 1, which biases the result low;
such samples are counted (:attr:`MitsubaSpecimen.clamped`) and a ``RuntimeWarning`` is issued
once per specimen.

Incidence from below the surface (wi_z < 0): Mitsuba's one-sided BSDFs (``diffuse``,
``roughconductor``, ...) return a zero weight, so every such ray is absorbed; wrap them in
Mitsuba's ``twosided`` BSDF for a two-sided specimen.

Only ``scalar_*`` variants (not polarized) are supported. When the variant's LLVM twin runs
here (:mod:`virtual.mitsuba_llvm`: a libLLVM is found), ``sample`` hands each batch to it as one
wavefront -- the same uniforms, the same single-precision arithmetic, >= 1e7 rays/s; otherwise
(or with ``wavefront=False``) it is a Python loop, one ``bsdf.sample`` call per ray (about 1e6
rays/s). ``mitsuba.set_variant`` is global: every call here switches to the specimen's variant
first.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from bench.core.errors import SpecimenError
from bench.core.parsing import json_problem
from virtual.model_ids import MODEL_PYTHON
from virtual.mitsuba_llvm import WavefrontSampler, llvm_status, llvm_variant
from virtual.specimens.declare import Specimen

__all__ = ["MitsubaSpecimen", "parse_mitsuba", "SPECTRAL_RANGE_NM"]

#: Wavelengths Mitsuba's spectral variants cover (its CIE tables).
SPECTRAL_RANGE_NM = (360.0, 830.0)


def _mitsuba(variant: str) -> Any:
    """The mitsuba module switched to ``variant``; a :class:`SpecimenError` when not usable."""
    try:
        import mitsuba as mi
    except ImportError:
        raise SpecimenError("Mitsuba specimens need the optional extra: pip install 'goniobench[mitsuba]'") from None
    if not variant.startswith("scalar_") or "polarized" in variant:
        raise SpecimenError(f"Mitsuba variant {variant!r}: only scalar, unpolarized variants are supported "
                            f"(e.g. scalar_rgb, scalar_spectral)")
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as exc:  # mitsuba raises plain errors
            raise SpecimenError(f"Mitsuba variant {variant!r} is not available: {exc}") from None
    return mi


def _rebuild(definition: dict, variant: str, label: str, wavefront: bool = True) -> "MitsubaSpecimen":
    return MitsubaSpecimen(definition, variant, label=label, wavefront=wavefront)


@dataclass(frozen=True)
class MitsubaSpecimen(Specimen):
    """A Mitsuba 3 BSDF as a specimen (see the module docstring for the conversion).

    Parameters
    ----------
    definition : dict
        A Mitsuba BSDF dictionary (what ``mitsuba.load_dict`` takes).
    variant : str
        A scalar Mitsuba variant, ``"scalar_rgb"`` (default) or ``"scalar_spectral"``.
    wavefront : bool
        Sample through the variant's LLVM twin when it runs here (default); False keeps the
        scalar loop.

    It has no numba kernel (``model = MODEL_PYTHON``); the devices count its rays with
    :mod:`virtual.python_engine`, which calls :meth:`sample`.
    """

    model: ClassVar[int] = MODEL_PYTHON
    definition: dict = field(compare=False)
    variant: str = "scalar_rgb"
    wavefront: bool = field(default=True, compare=False)
    key: str = field(init=False, repr=False)
    _bsdf: Any = field(init=False, repr=False, compare=False)
    _stats: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.definition, dict) or "type" not in self.definition:
            raise SpecimenError("a Mitsuba BSDF definition must be a dict with a 'type' key, "
                                f"got {self.definition!r}")
        mi = _mitsuba(self.variant)
        try:
            obj = mi.load_dict(self.definition)
        except Exception as exc:  # mitsuba raises RuntimeError with its message
            raise SpecimenError(f"Mitsuba could not load {self.definition!r}: {exc}") from None
        if not isinstance(obj, mi.BSDF):
            raise SpecimenError(f"Mitsuba object of type {self.definition['type']!r} is not a BSDF")
        key = json.dumps(self.definition, sort_keys=True, separators=(",", ":"), default=repr)
        object.__setattr__(self, "key", key)
        object.__setattr__(self, "_bsdf", obj)
        object.__setattr__(self, "_stats", {"samples": 0, "clamped": 0, "warned": False})
        if not self.label:
            suffix = "" if self.variant == "scalar_rgb" else f" ({self.variant})"
            object.__setattr__(self, "label", f"mitsuba:{key}{suffix}")

    def __reduce__(self) -> tuple:  # the Mitsuba object does not pickle: rebuild it
        return _rebuild, (self.definition, self.variant, self.label, self.wavefront)

    # -- Specimen face ---------------------------------------------------------------------
    @property
    def has_density(self) -> bool:  # type: ignore[override]
        """True unless the BSDF has a delta (Dirac) component, which ``eval`` cannot express."""
        mi = _mitsuba(self.variant)
        return not self._has(mi.BSDFFlags.Delta)

    @property
    def spectral(self) -> bool:
        return "spectral" in self.variant

    @property
    def clamped(self) -> int:
        """How many sampled weights exceeded 1 and were clamped (see the module docstring)."""
        return int(self._stats["clamped"])

    @property
    def sampler(self) -> Any:
        """The :class:`~virtual.mitsuba_llvm.WavefrontSampler` ``sample`` uses, or None (scalar
        loop): ``wavefront`` is False or the LLVM variant does not run here."""
        if "sampler" not in self._stats:
            ok = self.wavefront and not llvm_status(llvm_variant(self.variant))
            self._stats["sampler"] = WavefrontSampler(self.definition, self.variant) if ok else None
        return self._stats["sampler"]

    def _has(self, flag: Any) -> bool:
        return bool(int(self._bsdf.flags()) & int(flag))

    def params(self, wavelength_nm: float) -> np.ndarray:
        """No kernel parameters; checks the wavelength (spectral variants: 360..830 nm)."""
        wl = float(wavelength_nm)
        if self.spectral and not SPECTRAL_RANGE_NM[0] <= wl <= SPECTRAL_RANGE_NM[1]:
            lo, hi = SPECTRAL_RANGE_NM
            raise SpecimenError(f"{self.label}: wavelength {wl:g} nm is outside Mitsuba's spectral range "
                                f"({lo:g}..{hi:g} nm)")
        return np.empty(0, dtype=np.float64)

    def wavelength_range(self) -> tuple[float, float] | None:
        return SPECTRAL_RANGE_NM if self.spectral else None

    def transmits(self, wavelength_nm: float) -> bool:
        mi = _mitsuba(self.variant)
        return self._has(mi.BSDFFlags.Transmission)

    def lobes(self, wi: np.ndarray, wavelength_nm: float) -> list[tuple[np.ndarray, float]]:
        """A mirror-direction hint of width 2 alpha when the dict states a numeric roughness."""
        d = self.definition
        alphas = [d[k] for k in ("alpha", "alpha_u", "alpha_v") if isinstance(d.get(k), (int, float))]
        if not alphas:
            return []
        w = np.asarray(wi, dtype=float).reshape(3)
        m = np.array([-w[0], -w[1], w[2]]) / np.linalg.norm(w)
        return [(m, 2.0 * float(min(alphas)))]

    def _context(self, mi: Any, wavelength_nm: float) -> tuple[Any, Any]:
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        si = mi.SurfaceInteraction3f()
        if self.spectral:
            si.wavelengths = mi.Spectrum(float(wavelength_nm))
        return ctx, si

    def bsdf(self, wi: np.ndarray, wo: np.ndarray, wavelength_nm: float) -> np.ndarray:
        """BSDF (1/sr): Mitsuba's ``eval`` (which includes |cos theta_o|) divided by |cos theta_o|.

        ``wi`` (3,) toward the source, ``wo`` (n, 3). Zero where ``wo`` is in the specimen plane.
        """
        self.params(wavelength_nm)
        mi = _mitsuba(self.variant)
        ctx, si = self._context(mi, wavelength_nm)
        wi = np.asarray(wi, dtype=np.float64).reshape(3)
        wo = np.atleast_2d(np.asarray(wo, dtype=np.float64))
        si.wi = mi.Vector3f(*(float(c) for c in wi / np.linalg.norm(wi)))
        ev, vec = self._bsdf.eval, mi.Vector3f
        vals = np.array([tuple(ev(ctx, si, vec(x, y, z))) for x, y, z in wo.tolist()],
                        dtype=np.float64).reshape(len(wo), -1)
        f = vals[:, 0] if self.spectral else vals.mean(axis=1)
        z = np.abs(wo[:, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.where(z > 0.0, f / np.where(z > 0.0, z, 1.0), 0.0)
        return np.nan_to_num(np.maximum(out, 0.0), nan=0.0, posinf=0.0)

    def sample(self, wi: np.ndarray, n: int, wavelength_nm: float,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Scatter ``n`` rays: Mitsuba samples the direction, Russian roulette the survival.

        Parameters
        ----------
        wi : (3,) or (n, 3) array
            Unit vector(s) from the specimen toward the source (one for all rays, or one each).
        n : int
            Number of rays.
        wavelength_nm : float
            Wavelength (spectral variants); ignored by RGB variants.
        rng : numpy.random.Generator
            Source of all uniforms (Mitsuba's sample1, sample2 and the roulette).

        Returns
        -------
        dirs : (n, 3) float64
            Unit outgoing directions (rows of absorbed rays are zero).
        alive : (n,) bool
            False where the ray was absorbed.
        """
        self.params(wavelength_nm)
        mi = _mitsuba(self.variant)
        ctx, si = self._context(mi, wavelength_nm)
        n = int(n)
        w_in = np.asarray(wi, dtype=np.float64)
        per_ray = w_in.ndim == 2
        if per_ray and w_in.shape != (n, 3):
            raise SpecimenError(f"wi must have shape (3,) or ({n}, 3), got {w_in.shape}")
        if self.sampler is not None:
            wo, weight = self.sampler.sample(w_in, rng.random((n, 3)), float(wavelength_nm))
            return self._survive(wo, weight, n, rng)
        u = rng.random((n, 3)).tolist()
        sample, vec, pt = self._bsdf.sample, mi.Vector3f, mi.Point2f
        wos: list[tuple[float, ...]] = []
        ws: list[tuple[float, ...]] = []
        if not per_ray:
            si.wi = vec(*(float(c) for c in w_in.reshape(3)))
            for a, b, c in u:
                bs, w = sample(ctx, si, a, pt(b, c))
                wos.append(tuple(bs.wo))  # tuples convert ~3x faster than Mitsuba vectors
                ws.append(tuple(w))
        else:
            for (a, b, c), (x, y, z) in zip(u, w_in.tolist()):
                si.wi = vec(x, y, z)
                bs, w = sample(ctx, si, a, pt(b, c))
                wos.append(tuple(bs.wo))
                ws.append(tuple(w))
        wo = np.array(wos, dtype=np.float64).reshape(n, 3)
        wt = np.array(ws, dtype=np.float64).reshape(n, -1)
        weight = wt[:, 0] if self.spectral else wt.mean(axis=1)
        return self._survive(wo, weight, n, rng)

    def _survive(self, wo: np.ndarray, weight: np.ndarray, n: int,
                 rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Russian roulette on the sampled weights (clamped to 1, counted and warned once)."""
        weight = np.nan_to_num(weight, nan=0.0, posinf=0.0, neginf=0.0)
        over = int(np.count_nonzero(weight > 1.0))
        self._stats["samples"] += n
        if over:
            self._stats["clamped"] += over
            if not self._stats["warned"]:
                self._stats["warned"] = True
                warnings.warn(f"{self.label}: {over} of {n} Mitsuba sample weights exceed 1 and were clamped "
                              f"(analog sampling cannot reproduce them; the measurement is biased low)",
                              RuntimeWarning, stacklevel=3)
        norm = np.sqrt(np.einsum("ij,ij->i", wo, wo))
        alive = (rng.random(n) < np.clip(weight, 0.0, 1.0)) & (norm > 0.0)
        inv = 1.0 / np.where(alive, norm, 1.0)  # no boolean gathers: ~3x faster at 1e6 rays
        dirs = np.where(alive[:, None], wo * inv[:, None], 0.0)
        return dirs, alive


def parse_mitsuba(text: str, spec: str | None = None, variant: str = "scalar_rgb") -> MitsubaSpecimen:
    """A :class:`MitsubaSpecimen` from the JSON text after ``mitsuba:`` in a specimen string."""
    spec = spec if spec is not None else f"mitsuba:{text}"
    body = text.strip()
    if not body:
        raise SpecimenError(f"specimen {spec!r}: expected mitsuba:{{json dict}}, e.g. "
                            'mitsuba:{"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}')
    try:
        definition = json.loads(body)
    except ValueError as exc:  # JSONDecodeError, or an integer longer than int() takes
        raise SpecimenError(f"specimen {spec!r}: invalid JSON ({json_problem(exc, at=True)})") from None
    if not isinstance(definition, dict):
        raise SpecimenError(f"specimen {spec!r}: the JSON must be an object (a Mitsuba BSDF dict), "
                            f"got {type(definition).__name__}")
    return MitsubaSpecimen(definition, variant, label=spec)
