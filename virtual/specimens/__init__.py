"""Specimens: black boxes that scatter rays, one declaration per model family.

A device never looks inside a specimen. It hands the specimen an incoming direction and a
wavelength and gets back an outgoing direction, or absorption. Two faces of the same thing:

* the kernel face, :func:`~virtual.kernels.scatter.scatter` (``@jit``, in
  :mod:`virtual.kernels.scatter`): dispatches on the specimen's integer ``model`` id and reads
  the parameter vector :meth:`Specimen.params` returns for a wavelength;
* :meth:`Specimen.bsdf` (optional, ``has_density``): the BSDF value for arrays of directions,
  used by the exact fast path and by the quadrature references.

Modules: :mod:`~virtual.specimens.declare` (parameters declared once, the open registry,
:func:`register_specimen`, the README table), :mod:`~virtual.specimens.diffuse` (lambert,
oren-nayar, phong), :mod:`~virtual.specimens.microfacet` (ggx, aniso-ggx, plastic, dielectric),
:mod:`~virtual.specimens.leaf` (leaf: PROSPECT-D under a wax cuticle),
:mod:`~virtual.specimens.physics` (numpy Fresnel and GGX densities),
:mod:`~virtual.specimens.strings` (``name:key=value,...``). The class docs state each model's
formula, its sampling argument and its parameter vector; :func:`specimen_table_markdown`
renders every family's parameters (range, unit, default); a parameter out of range, unknown or
ignored raises :class:`~bench.core.errors.SpecimenError` naming it.

Adding a kernel model: write its law (:mod:`virtual.kernels.laws`: its id, its sampling, once for
every kernel path; ``make kernels`` generates the rest) and declare its class in the module the
law names as its ``SPECIMEN`` (imported here from :data:`virtual.law_table.LAW_SPECIMENS`). A lab's model
without a kernel declares ``model = MODEL_PYTHON`` (exported here) and a ``sample`` method. The
native families' ids are in :mod:`virtual.model_ids`, the kernel face in :mod:`virtual.kernels`.
"""

from __future__ import annotations

import importlib

from virtual.law_table import LAW_SPECIMENS
from virtual.model_ids import MODEL_PYTHON
from virtual.specimens.declare import (SPECIMENS, DeclaredSpecimen, Param, Specimen, Spectral, register_specimen,
                                       specimen_families, specimen_family, specimen_table_markdown,
                                       weighted_spectrum)
from virtual.specimens.diffuse import Lambertian, OrenNayar, Phong
from virtual.specimens.leaf import Leaf
from virtual.specimens.microfacet import ALPHA_MAX, ALPHA_MIN, GGX, AnisoGGX, RoughDielectric, RoughPlastic
from virtual.specimens.roughplastic import MitsubaRoughPlastic
from virtual.specimens.strings import known_specimen_names, parse_specimen

__all__ = [
    "Spectral", "Param", "Specimen", "DeclaredSpecimen", "register_specimen", "specimen_family",
    "specimen_families", "specimen_table_markdown", "known_specimen_names", "parse_specimen", "SPECIMENS",
    "MODEL_PYTHON", "weighted_spectrum",
    "Lambertian", "OrenNayar", "Phong", "GGX", "AnisoGGX", "RoughPlastic", "RoughDielectric", "Leaf",
    "MitsubaRoughPlastic",
    "ALPHA_MIN", "ALPHA_MAX",
]

for _module in LAW_SPECIMENS:  # the families of the laws of virtual.kernels.laws: importing registers them
    importlib.import_module(_module)
