"""The scattering laws written once: one module per law, the float64 source of every kernel path.

A law module states, as module constants and functions:

``MODEL``           its specimen model id (an int, stable: records and caches name it; the
                    generated :mod:`virtual.law_table` names it ``MODEL_<NAME>``)
``TITLE``           the routing table's name of the model ("Oren-Nayar")
``SPECIMEN``        the module declaring its specimen family (:mod:`virtual.specimens` imports it,
                    which registers the family)
``UNIFORMS``        how many uniforms ``given`` takes per ray (u0, u1, ...)
``FLOAT32_LIMITS``  the parameter ranges its float32 form takes, ``((index, name, lo, hi), ...)``
                    inclusive (every other parameter within +-``MAX_FLOAT32_PARAM``), or None
                    for a law without a float32 form
``given(p, wx, wy, wz, u0, ..., u{UNIFORMS-1})``  ``@jit(inline="llvm")``, branch-free:
                    ``(ox, oy, oz, alive, doubt)`` for the unit vector w toward the source
                    (either side) and the law's uniforms; ``doubt`` is whether a decision lies
                    within the float32 grid's reach of its threshold (``in_doubt``; always
                    False in float64)
``SIDE_ONLY``       optional, True: ``given`` reads only the sign of wz (the float32 block
                    kernel then emits only the beam's side, in the law's loop)
``LOBE_ROW``, ``lobe64``, ``lobe32``  optional: a value computed from the uniform row ``LOBE_ROW``
                    in a loop of its own before the block's main loop (a ``pow`` does not
                    vectorize), passed to ``given`` as its last argument: ``lobe64(p, u0, u)`` per
                    ray in float64, ``lobe32(p, row, int32 scratch, out)`` over the block's row in
                    float32 (Phong's lobe angle)
``ray(p, wx, wy, wz, s)``  optional: the ray-by-ray sampler drawing from the xoshiro stream
                    ``s``, ``(ox, oy, oz, alive)``; without it the ray-by-ray kernel calls
                    ``given`` with ``UNIFORMS`` draws of ``s``

and computes only with the names of its ``precision64`` import line (constants, warps,
``in_doubt``) besides ``math``. :mod:`virtual.kernels.lawcode` writes from these modules (on
import of :mod:`virtual.kernels` when missing or stale, and by ``make install`` / ``make kernels``)
the float32 twins (:mod:`virtual.kernels.laws32`: the same source importing
:mod:`virtual.kernels.precision32`), the dispatch every kernel path calls
(:mod:`virtual.kernels.law_dispatch`: ray by ray, float64 block, float32 block, the float32
kernel's float64 second look) and the numba-free table of ids, names, uniforms and float32
limits (:mod:`virtual.law_table`) that routing and the specimens read. The twins and the
dispatch are build products, not checked in (a copy per precision is not a second source); the
table is checked in.
"""
