"""The one fitting core (:mod:`accelcal.fitting.core`) and the campaign model built on the
one forward model (:mod:`accelcal.fitting.model`)."""
from .core import (ALPHA, RCOND, FitResult, GaussNewton, LackOfFit, LinearSolution, Parameter,  # noqa: F401
                   ParameterSet, birge_ratio, finish_fit, gauss_newton, lack_of_fit, linear_fit,
                   lstsq_svd, normalised_error, separable_columns)
