"""What every likelihood of a fit is: residuals ``r(specimen)`` whose sum of squares is
``-2 log L`` up to a constant (:mod:`bench.identify.likelihood`), with the groups the residual
figure draws, and what a fit takes (:data:`FitInput`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, TypeAlias

import numpy as np

from bench.core.records import BSDFRecord
from bench.core.roles import Spectrum
from virtual.specimens import Specimen

__all__ = ["FitInput", "Group", "Likelihood", "spectra_of"]

#: what a fit takes: a BSDF record, or one or several spectra
FitInput: TypeAlias = "BSDFRecord | Spectrum | Sequence[Spectrum]"


def spectra_of(record: Spectrum | Sequence[Spectrum]) -> tuple[Spectrum, ...]:
    """One spectrum or several, as a tuple."""
    return (record,) if isinstance(record, Spectrum) else tuple(record)


@dataclass(frozen=True)
class Group:
    """One block of residuals for the residual figure: its label, slice and x coordinates."""

    label: str
    start: int
    stop: int
    x: np.ndarray


class Likelihood:
    """Base: ``residuals(specimen)`` (see the module docstring), ``n_data`` independent data,
    ``groups`` for the figure, ``kind`` ("multinomial" or "gaussian") and ``xlabel``."""

    kind = ""
    xlabel = ""
    groups: tuple[Group, ...] = ()
    #: evaluate without the fast path's certificate, to be checked at the optimum (:meth:`certify`)
    defer_certification = False
    #: set once an evaluation counted rays: the likelihood is then a step function of the
    #: parameters at the scale of single rays (the fit differentiates over wider steps)
    counted_rays = False

    def certify(self, specimen: Specimen) -> bool:
        """Whether what was evaluated with :attr:`defer_certification` is certified at ``specimen``."""
        return True

    def residuals(self, specimen: Specimen) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def n_data(self, specimen: Specimen) -> int:  # pragma: no cover - abstract
        """Independent data at ``specimen`` (the goodness of fit's dof is this less the free parameters)."""
        raise NotImplementedError
