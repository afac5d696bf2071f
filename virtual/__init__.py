"""Virtual devices: Monte Carlo spectrophotometer and goniophotometer behind the bench interface.

The names a user imports are exported here (``from virtual import VirtualGoniophotometer,
parse_specimen``), each loaded on first use (:mod:`bench.core.exports`): declaring or parsing a
specimen loads no numba. Every numba kernel lives in :mod:`virtual.kernels`, compiled by its
:func:`~virtual.kernels.jit` decorator, whose on-disk cache is keyed by a hash of all kernel
sources (nothing is deleted at import time). ``virtual`` imports only :mod:`bench.core` from the
bench application's package. Any module not exported here is an implementation detail.
"""

from typing import TYPE_CHECKING

from bench.core.exports import lazy_exports, type_checking_imports

if TYPE_CHECKING:  # the public names; at run time each loads on first use (lazy_exports)
    from virtual.goniophotometer import VirtualGoniophotometer as VirtualGoniophotometer
    from virtual.spectrophotometer import VirtualSpectrophotometer as VirtualSpectrophotometer
    from virtual.collector import (Collector as Collector, parse_collector as parse_collector)
    from virtual.beam import Beam as Beam
    from virtual.specimens import (Specimen as Specimen, DeclaredSpecimen as DeclaredSpecimen, Param as Param,
                                   Spectral as Spectral, register_specimen as register_specimen,
                                   parse_specimen as parse_specimen, specimen_family as specimen_family,
                                   specimen_families as specimen_families,
                                   known_specimen_names as known_specimen_names, MODEL_PYTHON as MODEL_PYTHON)
    from virtual.scene import (Scene as Scene, SceneResult as SceneResult, load_scene as load_scene,
                               scene_from_dict as scene_from_dict)
    from virtual.bounds import (hoeffding_rays as hoeffding_rays, budget_report as budget_report,
                                binomial_ci as binomial_ci)

#: each public name and the module that defines it: the imports above, read from this file
_WHERE = type_checking_imports(__file__)

__all__ = list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
