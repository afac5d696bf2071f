"""Virtual devices: Monte Carlo spectrophotometer and goniophotometer behind the bench interface.

Every numba kernel lives in :mod:`virtual.kernels`, compiled by its :func:`~virtual.kernels.jit`
decorator, whose on-disk cache is keyed by a hash of all kernel sources (nothing is deleted at
import time). ``virtual`` imports only :mod:`bench.core` from the bench application's package.
"""
