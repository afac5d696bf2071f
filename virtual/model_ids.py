"""The specimen model ids: which branch of :func:`virtual.kernels.scatter.scatter` a specimen runs.

Plain integers in a module that imports only the generated :mod:`virtual.law_table` (which imports
nothing; the laws of :mod:`virtual.kernels.laws` declare their ids there), so that declaring,
parsing and listing specimens (``bench specimens``) does not load numba; :mod:`virtual.kernels.scatter` re-exports them and
dispatches on them. Keep them stable (records and caches name them). Every kernel that imports
them (through :mod:`virtual.kernels.scatter`) has this file in its cache stamp
(:func:`virtual.kernels.dependency_digest`): the kernels compile these values in as constants, so
editing one recompiles them.
"""

__all__ = ["MODEL_LAMBERT", "MODEL_OREN_NAYAR", "MODEL_PHONG", "MODEL_GGX", "MODEL_ANISO_GGX",
           "MODEL_PLASTIC", "MODEL_DIELECTRIC", "MODEL_LEAF", "MODEL_ROUGHPLASTIC", "MODEL_PYTHON"]

from virtual.law_table import MODEL_LAMBERT, MODEL_OREN_NAYAR, MODEL_PHONG  # declared by their laws (virtual.kernels.laws)
MODEL_GGX = 3
MODEL_ANISO_GGX = 4
MODEL_PLASTIC = 5
MODEL_DIELECTRIC = 6
MODEL_LEAF = 7  # virtual.specimens.leaf: PROSPECT-D body under a GGX cuticle
MODEL_ROUGHPLASTIC = 8  # virtual.specimens.roughplastic: Mitsuba 3's roughplastic (tabulated coat)
#: Specimens without a kernel (e.g. :class:`virtual.specimens.mitsuba.MitsubaSpecimen`, or a lab's own
#: model registered with :func:`virtual.specimens.register_specimen`): the devices count their
#: rays with :mod:`virtual.python_engine`, which calls the specimen's ``sample`` method.
MODEL_PYTHON = -1
