"""Running the goniophotometer kernels directly from tests: counts of one kernel for a specimen
string, a kernel's agreement with the ray kernel, and a run on one numba thread and on all of them."""

from __future__ import annotations

import numba

from tests.helpers.stats import two_sample_p
from virtual.engine import gonio_counts, measurement_seed
from virtual.specimens import parse_specimen


def kernel_counts(spec, beam, col, n, seed, kernel, theta=35.0, phi=20.0):
    """Counts per collector patch (then absorbed and missed) of ``n`` rays of ``kernel`` ("ray",
    "block", "block32", "auto") on the specimen string ``spec`` at 550 nm."""
    sp = parse_specimen(spec)
    return gonio_counts(sp.model, sp.params(550.0), beam.code, beam.disk_code, beam.kernel_args(theta, phi),
                        col.kernel_args(), n, measurement_seed(seed), kernel=kernel)


def agreement_with_rays(spec, beam, col, n, seed, kernel, theta):
    """The two-sample p-value of ``n`` rays of ``kernel`` (seeded ``seed``) against ``n`` of the
    ray kernel (``seed + 1``): the chance of counts this far apart from one distribution."""
    a = kernel_counts(spec, beam, col, n, seed, kernel, theta=theta)
    b = kernel_counts(spec, beam, col, n, seed + 1, "ray", theta=theta)
    assert a.sum() == b.sum() == n
    return two_sample_p(a, b)


def on_one_and_all_threads(run):
    """``run()`` on one numba thread, then on all of them: both results (the thread count is
    restored). A result that depends on the thread count differs between the two."""
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = run()
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = run()
    finally:
        numba.set_num_threads(before)
    return one, many
