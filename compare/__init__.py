"""Alignment of virtual and actual records, discrepancy statistics, physical checks, reports.

The public names, exported here (``from compare import compare_records``) and imported on first
use (:mod:`bench.core.exports`), so ``import compare`` stays cheap for the CLI:

* :func:`compare.report.compare_records` -- actual vs named candidates -> HTML/Markdown/JSON report
  and a summary dict with stable keys (what ``bench compare`` calls);
* :func:`compare.stats.compare` -- one candidate -> :class:`compare.stats.Comparison`;
* :func:`compare.align.align` -- point-by-point matching -> :class:`compare.align.Aligned` (not
  exported: a name of the package would be shadowed by its submodule ``compare.align``);
* :func:`compare.checks.run_checks` -- reciprocity, energy conservation, isotropy of a BSDF record;
* :class:`compare.verdict.Criterion` -- the acceptance criterion; :mod:`compare.verdict` gives a
  verdict per model and per incidence/wavelength (or spectrum) group;
* :mod:`compare._covariance` -- the full covariance of the differences when the actual record
  carries GUM budgets (the shared white standard counted once), and chi-square with it;
* :mod:`compare.records` -- what a record is (BSDF table, spectrum, set of spectra) and its keys;
* :mod:`compare.figures` (and its helper :mod:`compare._grid`) -- every figure (spectra, polar maps, in-plane
  curves, report figures, small multiples of every incidence).

``compare`` takes records only (:mod:`bench.core.records`, :mod:`bench.core.roles`): it reads no
file (the application's :mod:`bench.io` does) and imports nothing but ``bench.core``.
"""

from typing import TYPE_CHECKING

from bench.core.exports import lazy_exports, type_checking_imports

if TYPE_CHECKING:  # the public names; at run time each loads on first use (lazy_exports)
    from compare.report import compare_records as compare_records
    from compare.stats import (compare as compare, rank as rank, Comparison as Comparison)
    from compare.checks import (run_checks as run_checks, reciprocity as reciprocity,
                                energy_conservation as energy_conservation, isotropy as isotropy)
    from compare.verdict import Criterion as Criterion

#: each public name and the module that defines it: the imports above, read from this file
_WHERE = type_checking_imports(__file__)

__all__ = list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
