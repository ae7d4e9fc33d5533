"""Cornea fits (Sec. 2.2): the cornea centre, radius and lighting pose from glints.

Modules: ``problem`` (:class:`FitProblem`, :class:`CorneaFit`, reason codes), ``fit``
(:func:`fit_cornea`, :func:`fit_covariance`), ``solve`` (the batched Levenberg-Marquardt and
the paper's TRF), ``small`` (:func:`fit_small`: one band's warm-started fit, compiled where
Numba is), ``replica`` (:func:`fit_replica`: the batched fit's rules for one sample, compiled),
``conic`` (:func:`fit_cornea_conic`: the same unknowns on a conic cornea about the optical axis),
``wire`` (:func:`fit_cornea_wire`: the same unknowns with a wire mirror's moving virtual sources).
"""

from .fit import fit_cornea, fit_covariance
from .small import SmallFit, fit_small
from .replica import fit_replica
from .conic import (
    ASPHERICITY_RANGE,
    CORNEA_MODELS,
    check_conic,
    conic_glints,
    fit_cornea_conic,
)
from .wire import fit_cornea_wire, refit_on_wire
from .problem import MODELS, NON_FINITE, NOT_CONVERGED, OK, TOO_FEW_GLINTS, CorneaFit, FitProblem

__all__ = [
    "fit_cornea", "fit_covariance", "MODELS", "OK", "TOO_FEW_GLINTS", "NOT_CONVERGED",
    "NON_FINITE", "CorneaFit", "FitProblem", "fit_small", "SmallFit", "fit_replica",
    "ASPHERICITY_RANGE", "CORNEA_MODELS", "check_conic", "conic_glints",
    "fit_cornea_conic", "fit_cornea_wire", "refit_on_wire"
]
