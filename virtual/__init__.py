"""Virtual devices: Monte Carlo spectrophotometer and goniophotometer behind the bench interface.

The names a user imports are exported here (``from virtual import VirtualGoniophotometer,
parse_specimen``), each loaded on first use (:mod:`bench.core.exports`): declaring or parsing a
specimen loads no numba. Every numba kernel lives in :mod:`virtual.kernels`, compiled by its
:func:`~virtual.kernels.jit` decorator, whose on-disk cache is keyed by a hash of all kernel
sources (nothing is deleted at import time). ``virtual`` imports only :mod:`bench.core` from the
bench application's package. Any module not exported here is an implementation detail.
"""

from bench.core.exports import lazy_exports

#: each public name and the module that defines it
_WHERE = {
    # the virtual instruments and what they are made of
    "VirtualGoniophotometer": "virtual.goniophotometer",
    "VirtualSpectrophotometer": "virtual.spectrophotometer",
    **dict.fromkeys(["Collector", "parse_collector"], "virtual.collector"),
    "Beam": "virtual.beam",
    # specimens: one declaration per family, an open registry
    **dict.fromkeys(["Specimen", "DeclaredSpecimen", "Param", "Spectral", "register_specimen", "parse_specimen",
                     "specimen_family", "specimen_families", "known_specimen_names", "MODEL_PYTHON"],
                    "virtual.specimens"),
    # scenes: the instrument effects a measurement declares
    **dict.fromkeys(["Scene", "SceneResult", "load_scene", "scene_from_dict"], "virtual.scene"),
    # ray budgets
    **dict.fromkeys(["hoeffding_rays", "budget_report", "binomial_ci"], "virtual.bounds"),
}

__all__ = list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
