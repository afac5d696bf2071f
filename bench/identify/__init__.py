"""Identification: which parameters of a model explain a record, and how well they are determined.

:func:`~bench.identify.fit.fit_record` fits a model string
(:mod:`~bench.identify.model_spec`) to a record by maximum likelihood
(:mod:`~bench.identify.likelihood`: multinomial on virtual counts, Gaussian on calibrated
readings) with profile-likelihood or Hessian intervals and a goodness of fit. The package loads
scipy only inside the functions that fit.
"""

from bench.identify.fit import INTERVALS, FitResult, ParameterEstimate, fit_record
from bench.identify.model_spec import FreeParameter, ModelSpec, parse_model_spec

__all__ = ["fit_record", "FitResult", "ParameterEstimate", "INTERVALS", "parse_model_spec", "ModelSpec",
           "FreeParameter"]
