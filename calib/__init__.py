"""Estimation of camera spectral sensitivity: pure numpy/scipy, no hardware imports.

See :mod:`calib.spectra` for spectra and grids, :mod:`calib.observations` for the estimators' input
and :func:`calib.estimate` (the front function over every registered method) for the estimate.
"""

from calib.methods import estimate, register_method

__all__ = ["estimate", "register_method"]
