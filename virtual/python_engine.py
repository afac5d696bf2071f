"""Ray counting for specimens without a kernel (``model == MODEL_PYTHON``), in numpy.

The same measurements as :mod:`virtual.engine`, with the same result layouts, for specimens
that scatter in Python (e.g. :class:`virtual.specimens.mitsuba.MitsubaSpecimen`). Such a specimen has a
method ``sample(wi, n, wavelength_nm, rng) -> (dirs (n, 3), alive (n,))`` where ``wi`` is one
direction (3,) toward the source or one per ray (n, 3).

Incidence follows :class:`virtual.beam.Beam` exactly as the kernels' ``emit`` does: collimated,
every ray comes from the beam axis; conical, origins uniform on the emitter disk (radius r1,
distance D, rotated to the incidence by :func:`virtual.beam.rotation_to` -- read from
:meth:`Beam.kernel_args`) and targets uniform on the specimen disk (radius r2), both drawn by
:func:`virtual.sampling.sample_disk` with the beam's disk strategy; a ray from below the
specimen's plane (relative to the beam axis) is *missed*.

Rays are split by :func:`virtual.engine.chunking` (a function of ``n_rays`` only) and each
chunk draws from its own ``numpy.random.Generator``, a child of the measurement's
``SeedSequence``: results are reproducible for a seed and memory is bounded by the chunk size.
The random streams differ from the kernels' (another generator), not the distributions.
"""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np

from virtual.beam import Beam
from virtual.collector import Collector
from virtual.engine import NO_CONE, SpectroTally, chunking
from virtual.kernel_codes import B_AXIS_X, B_AXIS_Y, B_AXIS_Z, B_DISTANCE, B_EMITTER_RADIUS, B_SPECIMEN_RADIUS

__all__ = ["gonio_counts_python", "spectro_counts_python", "incidence"]

#: Rays per sub-batch inside a chunk (bounds the temporary arrays to a few MB).
BATCH_RAYS = 1 << 16


def incidence(beam: Beam, theta_i: float, phi_i: float, n: int,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` incident rays: unit vectors toward their sources, shape (3,) for a collimated beam
    (the axis, shared by all rays) or (n, 3) for a conical beam, and ``hit`` (n,) bool."""
    b = beam.kernel_args(theta_i, phi_i)  # validates the incidence; rotation (9), r1, r2, D, axis (3)
    axis = b[[B_AXIS_X, B_AXIS_Y, B_AXIS_Z]]
    if beam.kind == "collimated":
        return axis.copy(), np.ones(n, dtype=bool)
    from virtual.sampling import sample_disk  # its warps are kernels: numba only for conical rays

    rot = b[:9].reshape(3, 3)
    r1, r2, d = b[B_EMITTER_RADIUS], b[B_SPECIMEN_RADIUS], b[B_DISTANCE]
    strategy = "rejection" if beam.disk_sampling == "auto" else beam.disk_sampling
    p1 = sample_disk(n, r1, strategy, rng)
    p2 = sample_disk(n, r2, strategy, rng)
    origin = np.column_stack([p1, np.full(n, d)]) @ rot.T
    w = origin - np.column_stack([p2, np.zeros(n)])
    w /= np.sqrt(np.einsum("ij,ij->i", w, w))[:, None]
    return w, w[:, 2] * axis[2] > 0.0


def _batches(n_rays: int, seq: np.random.SeedSequence) -> Iterator[tuple[int, np.random.Generator]]:
    """(size, generator) per batch: chunks from :func:`chunking`, each with its child stream,
    cut into batches of at most :data:`BATCH_RAYS` rays."""
    sizes = chunking(n_rays)
    for size, child in zip(sizes, seq.spawn(len(sizes))):
        rng = np.random.default_rng(child)
        left = int(size)
        while left > 0:
            m = min(left, BATCH_RAYS)
            yield m, rng
            left -= m


def _scatter(specimen: Any, wavelength_nm: float, beam: Beam, theta_i: float, phi_i: float, m: int,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One batch: (wi (3,) or (k, 3) of the hits, hit (m,), dirs (k, 3), alive (k,))."""
    wi, hit = incidence(beam, theta_i, phi_i, m, rng)
    k = int(hit.sum())
    if wi.ndim == 2:
        wi = wi[hit]
    if k == 0:
        return wi, hit, np.zeros((0, 3)), np.zeros(0, dtype=bool)
    dirs, alive = specimen.sample(wi, k, float(wavelength_nm), rng)
    return wi, hit, np.asarray(dirs, dtype=np.float64), np.asarray(alive, dtype=bool)


def gonio_counts_python(specimen: Any, wavelength_nm: float, beam: Beam, theta_i: float, phi_i: float,
                        collector: Collector, n_rays: int, seq: np.random.SeedSequence) -> np.ndarray:
    """Counts per collector bin (upper patches, lower patches), then absorbed, then missed:
    the layout of :func:`virtual.engine.gonio_counts` (int64, ``2 n_patches + 2`` entries)."""
    n_bins = 2 * collector.n_patches
    counts = np.zeros(n_bins + 2, dtype=np.int64)
    for m, rng in _batches(int(n_rays), seq):
        _, hit, dirs, alive = _scatter(specimen, wavelength_nm, beam, theta_i, phi_i, m, rng)
        counts[n_bins + 1] += m - int(hit.sum())
        counts[n_bins] += int((~alive).sum())
        if alive.any():
            counts[:n_bins] += np.bincount(collector.index(dirs[alive]), minlength=n_bins)[:n_bins]
    return counts


def spectro_counts_python(specimen: Any, wavelength_nm: float, beam: Beam, theta_i: float, phi_i: float,
                          n_rays: int, seq: np.random.SeedSequence, cone: np.ndarray = NO_CONE) -> SpectroTally:
    """The tally of :func:`virtual.engine.spectro_counts` (reflected, transmitted, absorbed,
    missed, in ``cone`` = (cx, cy, cz, cos_half_angle)) for a specimen without a kernel."""
    cone = np.asarray(cone, dtype=np.float64)
    refl = trans = absorbed = missed = in_cone = 0
    for m, rng in _batches(int(n_rays), seq):
        wi, hit, dirs, alive = _scatter(specimen, wavelength_nm, beam, theta_i, phi_i, m, rng)
        missed += m - int(hit.sum())
        absorbed += int((~alive).sum())
        d = dirs[alive]
        wz = wi[2] if wi.ndim == 1 else wi[alive, 2]
        up = d[:, 2] * wz > 0.0
        refl += int(up.sum())
        trans += int((~up).sum())
        in_cone += int((d @ cone[:3] >= cone[3]).sum())
    return SpectroTally(int(n_rays), refl, trans, absorbed, missed, in_cone)
