"""Alignment of virtual and actual records, discrepancy statistics, physical checks, reports.

Entry points (imported lazily, so ``import compare`` stays cheap for the CLI):

* :func:`compare.report.compare_records` -- actual vs named candidates -> HTML/Markdown/JSON report
  and a summary dict with stable keys (what ``bench compare`` calls);
* :func:`compare.stats.compare` -- one candidate -> :class:`compare.stats.Comparison`;
* :func:`compare.align.align` -- point-by-point matching -> :class:`compare.align.Aligned`;
* :func:`compare.checks.run_checks` -- reciprocity, energy conservation, isotropy of a BSDF record;
* :class:`compare.verdict.Criterion` -- the acceptance criterion; :mod:`compare.verdict` gives a
  verdict per model and per incidence/wavelength (or spectrum) group;
* :mod:`compare.covariance` -- the full covariance of the differences when the actual record
  carries GUM budgets (the shared white standard counted once), and chi-square with it;
* :mod:`compare.records` -- what a record is (BSDF table, spectrum, set of spectra) and its keys;
* :mod:`compare.figures`, :mod:`compare.grid` -- every figure (spectra, polar maps, in-plane
  curves, report figures, small multiples of every incidence).

``compare`` takes records only (:mod:`bench.core.records`, :mod:`bench.core.roles`): it reads no
file (the application's :mod:`bench.io` does) and imports nothing but ``bench.core``.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__all__ = ["compare_records", "compare", "rank", "align", "run_checks",
           "reciprocity", "energy_conservation", "isotropy", "Criterion"]

_WHERE = {"compare_records": "compare.report",
          "compare": "compare.stats", "rank": "compare.stats", "align": "compare.align",
          "run_checks": "compare.checks", "reciprocity": "compare.checks",
          "energy_conservation": "compare.checks", "isotropy": "compare.checks", "Criterion": "compare.verdict"}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'compare' has no attribute {name!r}")
