"""The ray-counting engine: chunking, seeding and the choice of kernel (the kernels themselves are
:mod:`virtual.kernels.block64`); int64 counts, one random stream per chunk.

A measurement of ``N`` rays is split into a number of chunks that depends only on ``N``; chunk
``c`` draws from its own xoshiro stream(s), children of the measurement's ``SeedSequence``. Chunks
run side by side (:mod:`virtual.chunked`: threads, a single chunk in the caller's) and each writes
only its own row of counts, so the result is
identical for a given seed whatever the thread count, and memory does not grow with ``N``.

Two kernel shapes:

* ray by ray (``spectro_fx_kernel``, ``gonio_fx_kernel`` of :mod:`virtual.kernels.ray_loop`, with
  no effect flag): each ray is emitted, scattered and counted before the next; any specimen, any
  disk sampling; a scene's per-ray effects (:mod:`virtual.effects`) set flags in the same kernels;
* block (``gonio_block_kernel``), the goniophotometer's fast path: rays go through in blocks of
  :data:`BLOCK_RAYS`. The block's uniforms are drawn first, 64 xoshiro lanes side by side
  (:func:`~virtual.kernels.xoshiro.fill_uniforms`); then one branch-free loop emits (polar disks), scatters
  (:func:`~virtual.kernels.scatter.scatter_given`) and bins (:func:`~virtual.kernels.patch_lookup.guess_bin`)
  every ray, which LLVM compiles to AVX-512/AVX2 code; then a short scalar loop adds the bins
  to the histogram, settling the rare uncertain bin with the exact
  :func:`~virtual.kernels.patch_lookup.patch_of`. Only the surviving rays are binned (compacted first).
  It serves the :data:`~virtual.kernels.block64.BLOCK_MODELS` (Lambertian, GGX, anisotropic GGX
  with three uniforms per ray; Phong, Oren-Nayar, rough dielectric with four; the rough plastic
  with seven and one attempt of its diffuse rejection loop, the rare rejected ray finishing
  the loop on a scalar stream), 2-5x the ray-by-ray kernel's throughput; Mitsuba's
  roughplastic and the leaf run the same shape in a chunk of their own
  (``gonio_coat_kernel``, :mod:`virtual.kernels.block_coat`; in float32 ``gonio_coat32_kernel``,
  :mod:`virtual.kernels.block32_coat`, where ``block32`` suits them). The roughplastic's parameter
  vector gets its coat's specular albedo over the beam's cosines appended per measurement
  (:func:`measurement_params`).

Both count the same physics with the same distribution (tested by two-sample chi-square); their
random streams differ, so equal seeds give equal counts only within one kernel shape.
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from virtual.collector import guess_margins, guess_margins32
from virtual.kernel_codes import (B_AXIS_Z, BEAM_CONICAL, BLOCK_MODELS, BLOCK_PARAMS, COAT_MODELS,
                                  DISK_REJECTION, FRESNEL_CELLS, FRESNEL_SAMPLES, N_EFFECT_ARGS)
from virtual.model_ids import MODEL_ANISO_GGX, MODEL_GGX, MODEL_LAMBERT, MODEL_ROUGHPLASTIC
from virtual.rng import lane_states, lane_states32, stream_states
from virtual.routing import FLOAT32_MODELS, within_float32_limits
from virtual.specimens.roughplastic import incidence_params

# The compiled kernels (virtual.chunked, which loads numba) are imported where rays are counted,
# not here: routing, seeding and the certified fast path's multinomial draw never need them.

__all__ = [
    "chunking",
    "measurement_seed",
    "specimen_description",
    "specimen_stream_key",
    "spectro_counts",
    "SPECTRO_BINS",
    "SpectroTally",
    "gonio_counts",
    "GONIO_KERNELS",
    "gonio_kernel_for",
    "float32_suits",
    "multinomial_counts",
    "gonio_counts_spectral",
    "SPECTRAL_BATCH_MODELS",
    "shares_angular_part",
    "measurement_params",
]

#: Rays per chunk aimed at; enough to amortise a chunk's set-up, small enough to balance 2 cores.
CHUNK_RAYS = 1 << 20
MAX_CHUNKS = 1024

# spectrophotometer bins
BIN_REFLECTED, BIN_TRANSMITTED, BIN_ABSORBED, BIN_MISSED, BIN_CONE = range(5)
SPECTRO_BINS = ("reflected", "transmitted", "absorbed", "missed", "cone")


def chunking(n_rays: int) -> np.ndarray:
    """Rays per chunk (int64), a function of ``n_rays`` only, never of the thread count."""
    if n_rays < 0:
        raise ValueError(f"n_rays must be >= 0, got {n_rays}")
    n_chunks = max(1, min(MAX_CHUNKS, -(-n_rays // CHUNK_RAYS)))
    sizes = np.full(n_chunks, n_rays // n_chunks, dtype=np.int64)
    sizes[: n_rays % n_chunks] += 1
    return sizes


def measurement_seed(seed: int, *key: int) -> np.random.SeedSequence:
    """The SeedSequence of one measurement: the root seed and an integer key (e.g. the
    wavelength in pm, the incidence in millidegrees, a sweep task's key). Equal keys give equal
    streams, so the same wavelength measured in two runs draws the same rays."""
    return np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key))


def specimen_description(specimen: Any) -> str:
    """The full, canonical description of a specimen: its family name and every declared
    parameter's value (spectral tables in full, floats by ``repr``), or its label for a specimen
    without declared parameters. Two specimens that scatter alike describe alike, however their
    strings were written (``ggx:alpha=0.20`` and ``ggx:alpha=.2``)."""
    params = getattr(specimen, "parameters", None)
    if not params:
        return f"{type(specimen).__module__}.{type(specimen).__qualname__}:{getattr(specimen, 'label', '') or repr(specimen)}"
    parts = []
    for p in params:
        v = getattr(specimen, p.name)
        wl = getattr(v, "wavelengths", None)
        vals = ",".join(repr(float(x)) for x in np.atleast_1d(getattr(v, "values", v)))
        parts.append(f"{p.name}={vals}" if wl is None else
                     f"{p.name}=({','.join(repr(float(x)) for x in wl)};{vals})")
    return f"{getattr(specimen, 'name', type(specimen).__name__)}:{';'.join(parts)}"


def specimen_stream_key(specimen: Any) -> int:
    """A stable 63-bit hash (blake2b) of :func:`specimen_description`: the spawn-key entry
    that gives each specimen its own random stream under one seed (independent streams by
    default; a parameter scan that wants common random numbers leaves it out)."""
    digest = hashlib.blake2b(specimen_description(specimen).encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big") >> 1


@dataclass(frozen=True)
class SpectroTally:
    """Counts of one spectrophotometric measurement at one wavelength."""

    N: int
    reflected: int
    transmitted: int
    absorbed: int
    missed: int
    cone: int

    @property
    def hits(self) -> int:
        """Rays that reached the specimen's front face (the estimates' denominator)."""
        return self.N - self.missed


NO_CONE = np.array([0.0, 0.0, 1.0, 2.0])  # cos >= 2 never happens: no cone tally
_NO_FLAGS = np.int64(0)  # the ray-by-ray kernels with no scene effect: the bare kernels


def _no_effects(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The effect kernels' arguments that no flag reads: a one-row parameter table, its cdf,
    the effect vector and an empty detector table (the types the effect path passes, so both
    share one compiled kernel)."""
    return (np.ascontiguousarray(np.atleast_2d(params), dtype=np.float64), np.ones(1), np.zeros(N_EFFECT_ARGS),
            np.zeros((0, 4)))


def measurement_params(model: int, params: np.ndarray, beam_kind: int, beam_args: np.ndarray,
                       hemisphere: bool = False) -> np.ndarray:
    """The parameter vector (or table of rows) the kernels read for one measurement: the
    specimen's, with Mitsuba's roughplastic's specular albedo over the beam's cosines appended
    (:func:`virtual.specimens.roughplastic.incidence_params`; over every cosine when
    ``hemisphere``: the light comes from all directions too, e.g. an integrating sphere's
    wall); every other model's unchanged."""
    if int(model) == MODEL_ROUGHPLASTIC:
        return incidence_params(params, beam_kind, beam_args, hemisphere)
    return params


def spectro_counts(model: int, params: np.ndarray, beam_kind: int, disk: int, beam_args: np.ndarray,
                   n_rays: int, seq: np.random.SeedSequence, cone: np.ndarray = NO_CONE) -> SpectroTally:
    """Shoot ``n_rays`` rays at a specimen and count where they go.

    ``cone`` = (cx, cy, cz, cos_half_angle): rays leaving within that cone are also counted
    (a bidirectional detector's field of view, or a gloss trap).
    """
    from virtual.chunked import spectro_fx_kernel

    sizes = chunking(n_rays)
    states = stream_states(seq, sizes.shape[0])
    ptab, cdf, e, _ = _no_effects(measurement_params(model, params, beam_kind, beam_args))
    b = np.ascontiguousarray(beam_args, dtype=np.float64)
    out = spectro_fx_kernel(np.int64(model), ptab, cdf, np.int64(beam_kind), np.int64(disk), b, b,
                            np.ascontiguousarray(cone, dtype=np.float64), _NO_FLAGS, e, sizes, states)
    tot = out[:, :len(SPECTRO_BINS)].sum(axis=0)
    return SpectroTally(int(n_rays), *(int(v) for v in tot))


# --- goniophotometer: counts per collector patch ------------------------------------------------

#: The goniophotometer's kernel shapes (see the module docstring).
GONIO_KERNELS = ("auto", "block32", "block", "ray")


def float32_suits(model: int, params: np.ndarray) -> bool:
    """Whether float32 resolves this specimen (:mod:`virtual.kernels.f32`): a model with a
    float32 form and parameters within its :data:`~virtual.routing.FLOAT32_LIMITS` (roughness
    >= ``MIN_ALPHA``, a Phong exponent <= ``MAX_PHONG_EXPONENT``, a dielectric or plastic coat's
    index within ``1/MAX_ETA <= eta <= MAX_ETA``, every other parameter of moderate size: no
    float32 overflow in the Fresnel terms), all finite. The README's routing table states it
    (:func:`virtual.routing.routing_table`)."""
    return within_float32_limits(model, params)


def gonio_kernel_for(model: int, disk: int, kernel: str = "auto", params: np.ndarray | None = None) -> str:
    """The kernel shape ``gonio_counts`` runs. ``"auto"``: ``"block32"`` when the model's
    float32 form suits ``params`` (:func:`float32_suits`; never without ``params``), else
    ``"block"`` for the models with a branch-free float64 form, else ``"ray"``; rejection-sampled
    disks always run ``"ray"``."""
    if kernel not in GONIO_KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(GONIO_KERNELS)}, got {kernel!r}")
    can_block = int(model) in BLOCK_MODELS and int(disk) != DISK_REJECTION
    can32 = can_block and int(model) in FLOAT32_MODELS
    if kernel == "block" and not can_block:
        raise ValueError(f"the block kernel runs models {BLOCK_MODELS} with polar or auto disk sampling, "
                         f"not model {model} with disk code {disk}")
    if kernel == "block32" and not can32:
        raise ValueError(f"the block32 kernel runs models {FLOAT32_MODELS} with polar or auto disk sampling, "
                         f"not model {model} with disk code {disk}")
    if kernel == "auto":
        if can32 and params is not None and float32_suits(model, params):
            return "block32"
        return "block" if can_block else "ray"
    return kernel


def gonio_counts(model: int, params: np.ndarray, beam_kind: int, disk: int, beam_args: np.ndarray,
                 collector_args: tuple, n_rays: int, seq: np.random.SeedSequence, kernel: str = "auto") -> np.ndarray:
    """Counts per collector bin (upper patches, lower patches), then absorbed, then missed.

    ``collector_args`` is :meth:`virtual.collector.Collector.kernel_args`. Memory is
    O(chunks x bins), independent of ``n_rays``. ``kernel`` picks the kernel shape
    (:func:`gonio_kernel_for`); the counts' distribution is the same either way.
    """
    from virtual.chunked import (gonio_block32_kernel, gonio_block_kernel, gonio_coat32_kernel, gonio_coat_kernel,
                                 gonio_fx_kernel)

    shape = gonio_kernel_for(model, disk, kernel, params)
    n_theta, n_phi = int(collector_args[1]), int(collector_args[2])  # (scheme, n_theta, n_phi, ...)
    n_bins = 2 * n_theta * n_phi
    sizes = chunking(n_rays)
    p = np.ascontiguousarray(measurement_params(model, params, beam_kind, beam_args), dtype=np.float64)
    b = np.ascontiguousarray(beam_args, dtype=np.float64)
    if shape == "block32":
        p6 = np.zeros(max(BLOCK_PARAMS, p.size))
        p6[:p.size] = p
        run32 = gonio_coat32_kernel if int(model) in COAT_MODELS else gonio_block32_kernel
        out = run32(np.int64(model), p6, int(beam_kind) == BEAM_CONICAL, b, tuple(collector_args),
                    guess_margins32(n_theta, n_phi), np.int64(n_bins), sizes, lane_states32(seq, sizes.shape[0]),
                    stream_states(seq, sizes.shape[0]))
    elif shape == "block":
        p4 = np.zeros(max(BLOCK_PARAMS, p.size))  # the block kernel reads six parameters whatever the model
        p4[:p.size] = p
        run = gonio_coat_kernel if int(model) in COAT_MODELS else gonio_block_kernel
        out = run(np.int64(model), p4, np.int64(beam_kind), b, tuple(collector_args), guess_margins(n_theta, n_phi),
                  np.int64(n_bins), sizes, lane_states(seq, sizes.shape[0]), stream_states(seq, sizes.shape[0]))
    else:
        ptab, cdf, e, det = _no_effects(p)
        out = gonio_fx_kernel(np.int64(model), ptab, cdf, np.int64(beam_kind), np.int64(disk), b, b,
                              tuple(collector_args), np.int64(n_bins), _NO_FLAGS, e, det, sizes,
                              stream_states(seq, sizes.shape[0]))
    return out.sum(axis=0)


#: Chunks per call of the spectral kernel: bounds its per-chunk tables (cells x patches) in memory.
SPECTRAL_CHUNK_GROUP = 16


def gonio_counts_spectral(model: int, params: list[np.ndarray] | np.ndarray, beam_kind: int, disk: int,
                          beam_args: np.ndarray, collector_args: tuple, n_rays: int,
                          seq: np.random.SeedSequence) -> np.ndarray:
    """:func:`gonio_counts` at W wavelengths at once: ``params`` holds one parameter vector per
    wavelength; returns int64 counts ``(W, n_bins + 2)``, each row distributed exactly as
    :func:`gonio_counts` with that row's parameters.

    Spectral batching. A Lambertian's direction (cosine-weighted, drawn from u1, u2)
    does not depend on the wavelength; only its fate does: with one survival uniform u0, the ray
    leaves on the source's side when u0 < R, on the far side when R <= u0 < R + T, and is
    absorbed otherwise. The block kernel therefore draws each ray's direction and u0 once and
    locates u0 among the sorted thresholds {R_w, R_w + T_w} of all wavelengths (the "cell" of
    u0); within a cell every wavelength's fate is fixed, so counting rays by (cell, patch) and
    then adding each cell's counts to each wavelength's bins reproduces, for every wavelength,
    exactly the single-wavelength kernel's law (for that wavelength alone it is the same
    computation: u0 uniform, independent of the direction). Wavelengths share the rays, so their
    counts are correlated (common random numbers): each row is exact, the rows are not
    independent. Cost: one direction, one patch lookup and one count per ray, whatever W.

    GGX and anisotropic GGX whose roughness and masking convention are the same at every
    wavelength (eta and k may vary) batch too: the sampled direction (a visible normal,
    mirrored) does not depend on eta or k, only the survival probability F_w(w.m) G2/G1 does. The kernel draws each ray's normal
    and survival uniform u once and tests u < F_w G2/G1 per wavelength -- for each wavelength
    alone exactly the single-wavelength kernel's test on the same kind of draw. Its thresholds
    vary per ray, so it costs one Fresnel factor and one count per wavelength and surviving ray.

    When :func:`float32_suits` every wavelength's parameters (so that ``gonio_counts`` would run
    the float32 block kernel), both batches run in float32 (:mod:`virtual.kernels.spectral32`):
    the Lambertian's u0 located among the float64 thresholds (refined to 53 bits in a threshold's
    grid cell), the GGX's Fresnel
    factors bracketed by a per-wavelength table of bounds over cos(theta_m) and computed exactly
    only between them -- the same decisions, at a fraction of the cost per wavelength.

    Every row depends only on its own parameters and the rays: the counts of a wavelength are
    the same whichever other wavelengths share the batch (so W separate calls with one row each
    and the same ``seq`` give exactly the rows of one call with all W), provided the batch runs
    in the same precision -- float32 when every row suits it (for the declared Lambertian and GGX
    families that depends on the roughness alone). :func:`shares_angular_part` says which
    specimens take this path.

    Other models (or a roughness or masking varying with the wavelength: the direction would
    depend on it) fall back to one :func:`gonio_counts` per wavelength with the same ``seq``
    (the same rays where the kernels allow).
    """
    rows = [np.ascontiguousarray(p, dtype=np.float64) for p in params]
    if not rows:
        raise ValueError("gonio_counts_spectral needs at least one wavelength's parameters")
    n_theta, n_phi = int(collector_args[1]), int(collector_args[2])
    n_patches = n_theta * n_phi
    n_bins = 2 * n_patches
    ggx = int(model) in (MODEL_GGX, MODEL_ANISO_GGX) and all(
        p[0] == rows[0][0] and p[1] == rows[0][1] and p[4:5].tolist() == rows[0][4:5].tolist() for p in rows)
    f32 = all(float32_suits(model, p) for p in rows)  # the float32 batch where gonio_counts runs block32
    if ggx and gonio_kernel_for(model, disk) == "block":
        return _ggx_spectral(rows, beam_kind, beam_args, collector_args, n_rays, seq, f32)
    if int(model) != MODEL_LAMBERT or gonio_kernel_for(model, disk) != "block":
        def same(q: np.random.SeedSequence) -> np.random.SeedSequence:  # spawning advances a SeedSequence
            return np.random.SeedSequence(q.entropy, spawn_key=q.spawn_key, pool_size=q.pool_size,
                                          n_children_spawned=q.n_children_spawned)

        return np.stack([gonio_counts(model, p, beam_kind, disk, beam_args, collector_args, n_rays, same(seq))
                         for p in rows])
    r = np.array([p[0] for p in rows])
    rt = np.minimum(r + np.array([p[1] for p in rows]), 1.0)
    from virtual.chunked import lambert_spectral32_kernel, lambert_spectral_kernel
    thr = np.unique(np.concatenate([r, rt]))
    sizes = chunking(n_rays)
    b = np.ascontiguousarray(beam_args, dtype=np.float64)
    cells = np.zeros((thr.size + 1, n_patches), dtype=np.int64)
    missed = 0
    if f32:
        lanes = lane_states32(seq, sizes.shape[0])
        margins = guess_margins32(n_theta, n_phi)
    else:
        lanes = lane_states(seq, sizes.shape[0])
        margins = guess_margins(n_theta, n_phi)
    for g in range(0, sizes.shape[0], SPECTRAL_CHUNK_GROUP):
        sl = slice(g, g + SPECTRAL_CHUNK_GROUP)
        if f32:
            c, m = lambert_spectral32_kernel(thr, int(beam_kind) == BEAM_CONICAL,
                                             b.astype(np.float32), tuple(collector_args), margins,
                                             np.int64(n_patches), np.ascontiguousarray(sizes[sl]),
                                             np.ascontiguousarray(lanes[sl]))
        else:
            c, m = lambert_spectral_kernel(thr, np.int64(beam_kind), b, tuple(collector_args), margins,
                                           np.int64(n_patches), np.ascontiguousarray(sizes[sl]),
                                           np.ascontiguousarray(lanes[sl]))
        cells += c
        missed += int(m)
    # each cell's fate per wavelength, judged at the cell's lower end (a value u0 takes in it)
    lower = np.concatenate([[0.0], thr])
    source_above = b[B_AXIS_Z] > 0.0  # every hit ray comes from the axis' side (collimated: the axis)
    out = np.zeros((len(rows), n_bins + 2), dtype=np.int64)
    per_cell = cells.sum(axis=1)
    for w in range(len(rows)):
        near = lower < r[w]
        far = (lower >= r[w]) & (lower < rt[w])
        upper = np.where(source_above, near, far)
        lower_side = np.where(source_above, far, near)
        out[w, :n_patches] = cells[upper].sum(axis=0)
        out[w, n_patches:n_bins] = cells[lower_side].sum(axis=0)
        out[w, n_bins] = per_cell[~(near | far)].sum()
        out[w, n_bins + 1] = missed
    return out


#: The models :func:`gonio_counts_spectral` batches (one direction per ray, a survival test per
#: wavelength), and the kernel parameters that decide a ray's direction (equal at every wavelength
#: for the batch): none for the Lambertian, roughness and masking convention for GGX.
SPECTRAL_BATCH_MODELS = {MODEL_LAMBERT: (), MODEL_GGX: (0, 1, 4), MODEL_ANISO_GGX: (0, 1, 4)}


def shares_angular_part(specimen: Any, disk: int) -> bool:
    """Whether :func:`gonio_counts_spectral` batches this specimen's wavelengths: a model of
    :data:`SPECTRAL_BATCH_MODELS` whose direction parameters are the same at every wavelength the
    specimen declares (its spectral tables' wavelengths; a constant is the same everywhere), under
    a beam whose disks the block kernels sample (not ``disk_sampling = "rejection"``). A property
    of the specimen and the beam only, never of which wavelengths a measurement asks for."""
    angular = SPECTRAL_BATCH_MODELS.get(int(getattr(specimen, "model", -1)))
    if angular is None or gonio_kernel_for(specimen.model, disk) != "block":
        return False
    if not angular:
        return True
    tables = [getattr(getattr(specimen, p.name), "wavelengths", None) for p in getattr(specimen, "parameters", ())]
    grid = sorted({float(w) for t in tables if t is not None for w in t})
    lo, hi = specimen.wavelength_range() or (-np.inf, np.inf)
    grid = [w for w in grid if lo <= w <= hi] or [550.0]
    first = specimen.params(grid[0])
    return all(specimen.params(w)[list(angular)].tolist() == first[list(angular)].tolist() for w in grid[1:])


@functools.lru_cache(maxsize=1)
def float32_lanes() -> int:
    """float32 lanes of this CPU's widest vector (16 with AVX-512, 8 with AVX/AVX2, else 4): a
    choice of speed only -- no count depends on it."""
    try:
        from llvmlite import binding

        features = binding.get_host_cpu_features()
    except Exception:  # an unknown CPU: the narrowest vector
        return 4
    return 16 if features.get("avx512f") else (8 if features.get("avx") else 4)


def _padded_wavelengths(w: int) -> int:
    """Wavelengths of the float32 GGX batch's table per ray: ``w`` itself when fewer than a
    vector's lanes (one wavelength costs one), else whole vectors. The padding wavelengths have
    empty bounds (never counted), so the counts do not depend on it, only the speed."""
    lanes = float32_lanes()
    return w if w < lanes else -(-w // lanes) * lanes


def _ggx_spectral(rows: list[np.ndarray], beam_kind: int, beam_args: np.ndarray, collector_args: tuple,
                  n_rays: int, seq: np.random.SeedSequence, f32: bool) -> np.ndarray:
    """:func:`gonio_counts_spectral` for GGX with one roughness (see there): the float64 batch
    (:func:`~virtual.kernels.block64.ggx_spectral_kernel`) or, for specimens :func:`float32_suits`
    at every wavelength, the float32 one (:func:`~virtual.kernels.spectral32.ggx_spectral32_kernel`,
    the law of ``gonio_counts``'s block32)."""
    from virtual.chunked import ggx_spectral32_kernel, ggx_spectral_kernel
    from virtual.kernels.spectral32 import fresnel_bounds

    n_theta, n_phi = int(collector_args[1]), int(collector_args[2])
    n_bins = 2 * n_theta * n_phi
    separable = float(rows[0][4]) if len(rows[0]) > 4 else 0.0  # masking convention (one per specimen)
    etas = np.array([p[2] for p in rows])
    ks = np.array([p[3] for p in rows])
    sizes = chunking(n_rays)
    cargs = tuple(collector_args)
    if f32:
        wp = _padded_wavelengths(len(rows))
        e32, k32 = etas.astype(np.float32), ks.astype(np.float32)  # the bounds are of the kernel's float32 eta, k
        lo, hi = fresnel_bounds(e32.astype(np.float64), k32.astype(np.float64), FRESNEL_CELLS, FRESNEL_SAMPLES, wp)
        p = np.array([rows[0][0], rows[0][1], separable], dtype=np.float32)
        lanes, b, margins = lane_states32(seq, sizes.shape[0]), beam_args.astype(np.float32), guess_margins32(n_theta, n_phi)

        def batch(sz: np.ndarray, ln: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            h, t = ggx_spectral32_kernel(p, e32, k32, lo, hi, int(beam_kind) == BEAM_CONICAL, b, cargs, margins,
                                         np.int64(n_bins), sz, ln)
            return h[:, :len(rows)], t
    else:
        lanes, margins = lane_states(seq, sizes.shape[0]), guess_margins(n_theta, n_phi)
        b = np.ascontiguousarray(beam_args, dtype=np.float64)

        def batch(sz: np.ndarray, ln: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return ggx_spectral_kernel(float(rows[0][0]), float(rows[0][1]), separable, etas, ks, np.int64(beam_kind),
                                       b, cargs, margins, np.int64(n_bins), sz, ln)
    out = np.zeros((len(rows), n_bins + 2), dtype=np.int64)
    hits = 0
    for g in range(0, sizes.shape[0], SPECTRAL_CHUNK_GROUP):
        sl = slice(g, g + SPECTRAL_CHUNK_GROUP)
        h, t = batch(np.ascontiguousarray(sizes[sl]), np.ascontiguousarray(lanes[sl]))
        out[:, :n_bins] += h.T
        hits += int(t[0])
    out[:, n_bins] = hits - out[:, :n_bins].sum(axis=1)
    out[:, n_bins + 1] = int(n_rays) - hits
    return out


def multinomial_counts(probabilities: np.ndarray, n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """The exact fast path: ``n_rays`` rays' counts over bins with known probabilities, drawn as
    one multinomial -- the same distribution as counting the rays one by one, at O(bins) cost.

    ``probabilities`` must be finite, >= 0 and sum to 1 within 1e-9 (renormalised exactly).
    """
    p = np.asarray(probabilities, dtype=np.float64)
    total = p.sum()
    if not np.all(np.isfinite(p)) or np.any(p < 0) or abs(total - 1.0) > 1e-9:
        raise ValueError(f"bin probabilities must be >= 0 and sum to 1 (sum = {total!r})")
    return np.random.default_rng(seq).multinomial(int(n_rays), p / total).astype(np.int64)
