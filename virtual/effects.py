"""Effects: counting with a scene's declared effects (the kernels are :mod:`virtual.kernels.ray_loop`).

A scene (:mod:`virtual.scene`) that declares no per-ray effect never comes here: it runs the
bare kernels of :mod:`virtual.engine` at their full speed. A scene that declares some runs
:func:`spectro_effect_counts` / :func:`gonio_effect_counts`, whose loop is the bare loop --
:func:`~virtual.beam.emit`, :func:`~virtual.kernels.scatter.scatter`, :func:`~virtual.kernels.patch_lookup.patch_of`,
reused, not copied -- plus one predictable branch per *declared* effect (an undeclared effect
costs a bit test per ray and draws no random number). Effects handled per ray (bit flags; the
parameter vector ``e`` is read through the named indices ``E_*`` of :mod:`virtual.kernels.ray_loop`):

``FX_STRAY``       stray light: with probability ``e[0]`` a ray reaches the detector without
                   meeting the specimen (spectro: counted in the ``stray`` column; gonio: a
                   cosine-distributed direction into the upper hemisphere, so it adds
                   ``e[0] / pi`` to every BRDF value).
``FX_BANDPASS``    spectral bandpass: each ray's wavelength is drawn from the discretised slit
                   function (``cdf``) and the specimen's parameters are that node's row of
                   ``ptab``.
``FX_SPHERE``      integrating sphere (spectro): a ray reflected into the sphere random-walks
                   over the sphere surface -- detector port (``e[2]``, detected), specimen port
                   (``e[3]``, diffuse re-illumination of the specimen, scattered by the black
                   box again), other ports (lost), wall (``1 - e[4]`` of the area, reflectance
                   ``e[1]``). One uniform per strike.
``FX_PATTERN``     spatially non-uniform specimen: a ray hitting (x, y) survives with
                   probability ``m(x) = 1 - c (1 + cos(2 pi x / P)) / 2`` (``e[6] = c``,
                   ``e[5] = P``) before the specimen scatters it. Needs positions.
``FX_DETECTORS``   finite detector apertures (gonio): detector ``k`` of ``det`` (rows
                   ``ax, ay, az, cos_half_angle``) counts rays whose direction lies within its
                   cone (far field).
``FX_NEAR``        the detectors are disks of radius ``e[9]`` at distance ``e[8]`` (near field):
                   a ray leaving the specimen at (x, y, 0) is counted when its line meets the
                   disk. Needs positions.

Positions are sampled only when an effect needs them (``FX_PATTERN`` or ``FX_NEAR``): a uniform
specimen seen by far-field detectors draws exactly the random numbers of the bare kernel (the
counts are then bit-identical to it for the same seed). The position of a collimated ray is
uniform on the illuminated spot of radius ``e[7]``; for a conical beam the target point is
drawn on the specimen disk and the origin comes from :func:`~virtual.beam.emit` itself (called
with a pin-point specimen disk, the origin is ``w D / (w . axis)``), so the beam's geometry is
never re-implemented.

Also here: :func:`spectro_point_counts`, the spectrophotometer kernel fed with precomputed disk
points (jittered or Sobol strategies).
"""

from __future__ import annotations

import math

import numpy as np
from bench.core.errors import InputError

from virtual.engine import chunking, measurement_params
from virtual.chunked import gonio_fx_kernel, spectro_fx_kernel, spectro_points_kernel
from virtual.kernel_codes import B_SPECIMEN_RADIUS, BEAM_CONICAL
from virtual.kernels.ray_loop import (E_NEAR_DISTANCE, E_NEAR_RADIUS, E_PATTERN_PERIOD, E_SPOT_RADIUS, N_EFFECT_ARGS,
                                     FX_BANDPASS, FX_DETECTORS, FX_NEAR, FX_PATTERN, FX_POSITIONS, FX_SPHERE, FX_STRAY)
from virtual.rng import stream_states

__all__ = [
    "FX_STRAY", "FX_BANDPASS", "FX_SPHERE", "FX_PATTERN", "FX_DETECTORS", "FX_NEAR", "FX_POSITIONS",
    "N_EFFECT_ARGS", "SPECTRO_FX_COLUMNS", "spectro_effect_counts", "gonio_effect_counts",
    "spectro_point_counts", "pinpoint_beam_args",
]

SPECTRO_FX_COLUMNS = ("reflected", "transmitted", "absorbed", "missed", "cone", "detected", "stray")

def pinpoint_beam_args(beam_args: np.ndarray) -> np.ndarray:
    """Beam arguments whose specimen disk is a point (radius 1e-150): :func:`emit` then returns
    the unit vector toward the emitter point itself (its target is the origin to ~1e-150 mm)."""
    b = np.array(beam_args, dtype=np.float64, copy=True)
    b[B_SPECIMEN_RADIUS] = 1e-150
    return b


def _ptab(ptab: np.ndarray, cdf: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    t = np.ascontiguousarray(np.atleast_2d(np.asarray(ptab, dtype=np.float64)))
    c = np.ones(1) if cdf is None else np.ascontiguousarray(np.asarray(cdf, dtype=np.float64))
    if c.shape[0] != t.shape[0]:
        raise InputError("bandpass cdf and parameter table must have as many rows")
    return t, c


def _effect_vector(e: np.ndarray | None, flags: int) -> np.ndarray:
    out = np.zeros(N_EFFECT_ARGS)
    if e is not None:
        out[: len(e)] = np.asarray(e, dtype=np.float64)
    out[E_PATTERN_PERIOD] = out[E_PATTERN_PERIOD] if out[E_PATTERN_PERIOD] > 0 else 1.0
    spot = out[E_SPOT_RADIUS]
    if flags & FX_POSITIONS and not (math.isfinite(spot) and spot > 0):
        raise InputError(f"effects that sample positions need a spot radius e[7] > 0, got {spot!r}")
    if flags & FX_NEAR and not (out[E_NEAR_DISTANCE] > 0 and out[E_NEAR_RADIUS] > 0):
        raise InputError("near-field detectors need a distance e[8] > 0 and a radius e[9] > 0")
    return out


def spectro_effect_counts(model: int, ptab: np.ndarray, cdf: np.ndarray | None, beam_kind: int, disk: int,
                          beam_args: np.ndarray, cone: np.ndarray, flags: int, e: np.ndarray | None,
                          n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """Counts (:data:`SPECTRO_FX_COLUMNS`) of ``n_rays`` rays with the effects ``flags``.

    ``ptab`` is one parameter vector per bandpass node (a single row without ``FX_BANDPASS``),
    ``cdf`` the cumulative node weights; ``e`` the effect parameters (see the module docstring).
    """
    sizes = chunking(n_rays)
    states = stream_states(seq, sizes.shape[0])
    t, c = _ptab(measurement_params(model, np.atleast_2d(ptab), beam_kind, beam_args, bool(flags & FX_SPHERE)), cdf)
    b = np.ascontiguousarray(beam_args, dtype=np.float64)
    out = spectro_fx_kernel(np.int64(model), t, c, np.int64(beam_kind), np.int64(disk), b,
                             pinpoint_beam_args(b), np.ascontiguousarray(cone, dtype=np.float64),
                             np.int64(flags), _effect_vector(e, flags), sizes, states)
    return out.sum(axis=0)


def gonio_effect_counts(model: int, ptab: np.ndarray, cdf: np.ndarray | None, beam_kind: int, disk: int,
                        beam_args: np.ndarray, collector_args: tuple, flags: int, e: np.ndarray | None,
                        detectors: np.ndarray | None, n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """Counts per collector bin (as :func:`virtual.engine.gonio_counts`: patches, absorbed,
    missed), then one count per detector row of ``detectors`` (``ax, ay, az, cos_half``)."""
    n_bins = 2 * int(collector_args[1]) * int(collector_args[2])
    det = np.zeros((0, 4)) if detectors is None else np.ascontiguousarray(detectors, dtype=np.float64)
    sizes = chunking(n_rays)
    states = stream_states(seq, sizes.shape[0])
    t, c = _ptab(measurement_params(model, np.atleast_2d(ptab), beam_kind, beam_args, bool(flags & FX_SPHERE)), cdf)
    b = np.ascontiguousarray(beam_args, dtype=np.float64)
    out = gonio_fx_kernel(np.int64(model), t, c, np.int64(beam_kind), np.int64(disk), b, pinpoint_beam_args(b),
                           tuple(collector_args), np.int64(n_bins), np.int64(flags), _effect_vector(e, flags), det,
                           sizes, states)
    return out.sum(axis=0)


# --- spectrophotometer fed with precomputed disk points ------------------------------------------

def spectro_point_counts(model: int, params: np.ndarray, beam_args: np.ndarray, points: np.ndarray,
                         seq: np.random.SeedSequence) -> np.ndarray:
    """Spectrophotometer counts (reflected, transmitted, absorbed, missed, 0) for a conical beam
    whose rays join given emitter points ``points[:, :2]`` (on the emitter disk, before the
    rotation to the incidence) to specimen points ``points[:, 2:]``: the jittered and Sobol
    strategies of the accuracy-versus-time study. Memory O(N) (the points); scattering draws
    from per-chunk xoshiro streams as in the bare kernel. The direction is
    :func:`virtual.kernels.emit.toward_source`, the formula :func:`~virtual.kernels.emit.emit` uses
    (emit draws its own points).
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 4:
        raise InputError(f"points must have shape (n, 4), got {pts.shape}")
    sizes = chunking(len(pts))
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    states = stream_states(seq, sizes.shape[0])
    params = measurement_params(model, params, BEAM_CONICAL, beam_args)
    out = spectro_points_kernel(np.int64(model), np.ascontiguousarray(params, dtype=np.float64),
                                 np.ascontiguousarray(beam_args, dtype=np.float64), pts, starts, states)
    tot = out.sum(axis=0)
    tot[4] = 0
    return tot
