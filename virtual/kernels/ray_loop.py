"""The ray-by-ray counting kernels, with a scene's per-ray effects (bit flags, see
:mod:`virtual.effects` for what each effect does; with none set they are the bare kernels, which
:func:`virtual.engine.spectro_counts` and the ``ray`` shape of :func:`virtual.engine.gonio_counts`
run), and the spectrophotometer fed with given disk points. They reuse :func:`~virtual.kernels.emit.emit`,
:func:`~virtual.kernels.scatter.scatter` and :func:`~virtual.kernels.patch_lookup.patch_of`.
"""

from __future__ import annotations

import math

import numpy as np

from virtual.kernels import jit
from virtual.kernels.emit import (B_AXIS_X, B_AXIS_Y, B_AXIS_Z, B_DISTANCE, B_SPECIMEN_RADIUS, BEAM_COLLIMATED, emit,
                                  toward_source)
from virtual.kernels.patch_lookup import patch_of
from virtual.kernels.xoshiro import next_double
from virtual.kernels.warps import sample_cosine_hemisphere, warp_square
from virtual.kernels.scatter import scatter

__all__ = ["N_EFFECT_ARGS", "E_STRAY_FRACTION", "E_WALL_REFLECTANCE", "E_DETECTOR_PORT", "E_SPECIMEN_PORT",
           "E_PORT_FRACTION", "E_PATTERN_PERIOD", "E_PATTERN_CONTRAST", "E_SPOT_RADIUS", "E_NEAR_DISTANCE",
           "E_NEAR_RADIUS", "FX_STRAY", "FX_BANDPASS", "FX_SPHERE", "FX_PATTERN", "FX_DETECTORS", "FX_NEAR", "FX_POSITIONS",
           "spectro_fx_chunk", "gonio_fx_chunk", "spectro_points_chunk"]

from virtual.kernel_codes import (FX_BANDPASS, FX_DETECTORS, FX_NEAR, FX_PATTERN, FX_POSITIONS, FX_SPHERE,
                                  FX_STRAY, N_EFFECT_ARGS)
# Indices into the effect vector ``e`` (see :mod:`virtual.effects`; numba compiles them as constants)
E_STRAY_FRACTION = 0
E_WALL_REFLECTANCE = 1
E_DETECTOR_PORT = 2
E_SPECIMEN_PORT = 3
E_PORT_FRACTION = 4
E_PATTERN_PERIOD = 5
E_PATTERN_CONTRAST = 6
E_SPOT_RADIUS = 7
E_NEAR_DISTANCE = 8
E_NEAR_RADIUS = 9

_TWO_PI = 2.0 * math.pi


@jit(inline="llvm")
def _spot(r, s):
    """A uniform point of the disk of radius r (eq. 3.3 with rejection)."""
    while True:
        x, y = warp_square(next_double(s), next_double(s), r)
        if x * x + y * y < r * r:
            return x, y



@jit(inline="llvm")
def _emit_at(kind, disk, b, bp, spot_r, s):
    """emit() plus the point (x, y) where the ray meets the specimen plane."""
    if kind == BEAM_COLLIMATED:
        wx, wy, wz, hit = emit(kind, disk, b, s)
        x, y = _spot(spot_r, s)
        return wx, wy, wz, hit, x, y
    x, y = _spot(b[B_SPECIMEN_RADIUS], s)
    ux, uy, uz, _ = emit(kind, disk, bp, s)  # toward the emitter point seen from the centre
    # the emitter point O satisfies O . axis = D, so O = u D / (u . axis)
    t = bp[B_DISTANCE] / (ux * b[B_AXIS_X] + uy * b[B_AXIS_Y] + uz * b[B_AXIS_Z])
    ox = ux * t - x
    oy = uy * t - y
    oz = uz * t
    inv = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    wx, wy, wz = ox * inv, oy * inv, oz * inv
    return wx, wy, wz, wz * b[B_AXIS_Z] > 0.0, x, y



@jit(inline="llvm")
def _pick(cdf, s):
    u = next_double(s)
    k = 0
    n = cdf.shape[0]
    while k < n - 1 and u >= cdf[k]:
        k += 1
    return k



@jit(nogil=True)
def spectro_fx_chunk(model, ptab, cdf, beam_kind, disk, b, bp, cone, flags, e, n_rays, s, out):
    """One chunk of the ray-by-ray spectrophotometer: ``n_rays`` rays from the stream ``s``
    (advanced in place), tallies added to ``out`` (:data:`virtual.effects.SPECTRO_FX_COLUMNS`).
    Without the GIL: :mod:`virtual.chunked` runs chunks on threads."""
    positions = (flags & FX_POSITIONS) != 0
    refl = np.int64(0)
    trans = np.int64(0)
    absorbed = np.int64(0)
    missed = np.int64(0)
    in_cone = np.int64(0)
    detected = np.int64(0)
    stray = np.int64(0)
    for _ in range(n_rays):
        if (flags & FX_STRAY) != 0 and next_double(s) < e[E_STRAY_FRACTION]:
            stray += 1
            continue
        if positions:
            wx, wy, wz, hit, px, py = _emit_at(beam_kind, disk, b, bp, e[E_SPOT_RADIUS], s)
        else:
            wx, wy, wz, hit = emit(beam_kind, disk, b, s)
            px = 0.0
        if not hit:
            missed += 1
            continue
        if (flags & FX_PATTERN) != 0:
            m = 1.0 - e[E_PATTERN_CONTRAST] * 0.5 * (1.0 + math.cos(_TWO_PI * px / e[E_PATTERN_PERIOD]))
            if next_double(s) >= m:
                absorbed += 1
                continue
        k = _pick(cdf, s) if (flags & FX_BANDPASS) != 0 else 0
        p = ptab[k]
        ox, oy, oz, alive = scatter(model, p, wx, wy, wz, s)
        if not alive:
            absorbed += 1
            continue
        up = oz * wz > 0.0
        if up:
            refl += 1
        else:
            trans += 1
        if ox * cone[0] + oy * cone[1] + oz * cone[2] >= cone[3]:
            in_cone += 1
        if (flags & FX_SPHERE) != 0 and up:
            side = 1.0 if wz > 0.0 else -1.0
            while True:  # strikes on the sphere surface; ends w.p. 1 (wall reflectance < 1)
                u = next_double(s)
                if u < e[E_DETECTOR_PORT]:
                    detected += 1
                    break
                u -= e[E_DETECTOR_PORT]
                if u < e[E_SPECIMEN_PORT]:  # back on the specimen: diffuse illumination from the sphere
                    dx, dy, dz = sample_cosine_hemisphere(s)
                    dz = dz * side
                    qx, qy, qz, ok = scatter(model, p, dx, dy, dz, s)
                    if not ok or qz * dz <= 0.0:
                        break
                    continue
                u -= e[E_SPECIMEN_PORT]
                if u < e[E_PORT_FRACTION] - e[E_DETECTOR_PORT] - e[E_SPECIMEN_PORT]:  # another port: lost
                    break
                u -= e[E_PORT_FRACTION] - e[E_DETECTOR_PORT] - e[E_SPECIMEN_PORT]
                if u >= (1.0 - e[E_PORT_FRACTION]) * e[E_WALL_REFLECTANCE]:  # absorbed by the wall
                    break
    out[0] += refl
    out[1] += trans
    out[2] += absorbed
    out[3] += missed
    out[4] += in_cone
    out[5] += detected
    out[6] += stray


@jit(nogil=True)
def gonio_fx_chunk(model, ptab, cdf, beam_kind, disk, b, bp, cargs, n_bins, flags, e, det, n_rays, s, hist):
    """One chunk of the ray-by-ray goniophotometer: ``n_rays`` rays from the stream ``s`` counted
    in ``hist`` (patches, absorbed, missed, then one count per detector row of ``det``)."""
    n_det = det.shape[0]
    positions = (flags & FX_POSITIONS) != 0
    near = (flags & FX_NEAR) != 0
    for _ in range(n_rays):
        px = 0.0
        py = 0.0
        if (flags & FX_STRAY) != 0 and next_double(s) < e[E_STRAY_FRACTION]:
            ox, oy, oz = sample_cosine_hemisphere(s)
        else:
            if positions:
                wx, wy, wz, hit, px, py = _emit_at(beam_kind, disk, b, bp, e[E_SPOT_RADIUS], s)
            else:
                wx, wy, wz, hit = emit(beam_kind, disk, b, s)
            if not hit:
                hist[n_bins + 1] += 1
                continue
            if (flags & FX_PATTERN) != 0:
                m = 1.0 - e[E_PATTERN_CONTRAST] * 0.5 * (1.0 + math.cos(_TWO_PI * px / e[E_PATTERN_PERIOD]))
                if next_double(s) >= m:
                    hist[n_bins] += 1
                    continue
            k = _pick(cdf, s) if (flags & FX_BANDPASS) != 0 else 0
            ox, oy, oz, alive = scatter(model, ptab[k], wx, wy, wz, s)
            if not alive:
                hist[n_bins] += 1
                continue
        hist[patch_of(ox, oy, oz, cargs[0], cargs[1], cargs[2], cargs[3], cargs[4])] += 1
        if (flags & FX_DETECTORS) != 0:
            for j in range(n_det):
                cv = ox * det[j, 0] + oy * det[j, 1] + oz * det[j, 2]
                if near:
                    if cv > 0.0:
                        t = (e[E_NEAR_DISTANCE] - (px * det[j, 0] + py * det[j, 1])) / cv
                        hx = px + t * ox - e[E_NEAR_DISTANCE] * det[j, 0]
                        hy = py + t * oy - e[E_NEAR_DISTANCE] * det[j, 1]
                        hz = t * oz - e[E_NEAR_DISTANCE] * det[j, 2]
                        if hx * hx + hy * hy + hz * hz <= e[E_NEAR_RADIUS] * e[E_NEAR_RADIUS]:
                            hist[n_bins + 2 + j] += 1
                elif cv >= det[j, 3]:
                    hist[n_bins + 2 + j] += 1


@jit(nogil=True)
def spectro_points_chunk(model, params, b, pts, start, stop, s, out):
    """One chunk of the spectrophotometer on given points: rays ``pts[start:stop]`` (emitter x, y,
    specimen x, y), scattering from the stream ``s``; tallies (reflected, transmitted, absorbed,
    missed) added to ``out``."""
    refl = np.int64(0)
    trans = np.int64(0)
    absorbed = np.int64(0)
    missed = np.int64(0)
    for i in range(start, stop):
        x1 = pts[i, 0]
        y1 = pts[i, 1]
        x2 = pts[i, 2]
        y2 = pts[i, 3]
        wx, wy, wz, hit = toward_source(b, x1, y1, x2, y2)  # the beam's one direction formula
        if not hit:
            missed += 1
            continue
        qx, qy, qz, alive = scatter(model, params, wx, wy, wz, s)
        if not alive:
            absorbed += 1
            continue
        if qz * wz > 0.0:
            refl += 1
        else:
            trans += 1
    out[0] += refl
    out[1] += trans
    out[2] += absorbed
    out[3] += missed
